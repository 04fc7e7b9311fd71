"""``bench view``'s made capture is a capture with tracked results the viewer reads, and one
run times every output."""

from __future__ import annotations

from spinemocap.app.results import read_results
from spinemocap.bench.view import made_capture, run
from spinemocap.capture import Capture


def test_a_made_capture_is_timed_end_to_end(tmp_path):
    capture, results = made_capture(tmp_path, 96, 64, 2, 3)
    opened = Capture.open(capture)
    assert opened.n_frames == 3 and [c.size for c in opened.rig] == [(96, 64), (96, 64)]
    assert read_results(results).n_frames == 3
    numbers = run(capture, results, tmp_path / "view", scale=1.0)
    assert numbers.frames == 3 and numbers.cameras == 2 and numbers.sizes == [(96, 64)]
    assert (tmp_path / "view" / "tape3d.html").is_file() and numbers.video_MiB > 0
    assert numbers.capture == str(capture) and list(numbers.to_dict())[:3] == ["capture", "run", "frames"]
