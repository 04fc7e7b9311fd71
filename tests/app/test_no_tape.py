"""A capture with no tape in view: `track` fails with one plain line and its own exit status,
`batch` records the trial as failed with that reason and its report counts it failed."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spinemocap.camera import Camera, Rig
from spinemocap.capture import Capture
from spinemocap.cli import main
from spinemocap.tape import TapeSpec

N_FRAMES = 4
LEVELS = '[levels]\nS1 = 1\n"T12/L1" = 3\nT9 = 5\n'


def blank_capture(root, n_frames: int = N_FRAMES):
    """A capture of three cameras whose images hold a plain grey wall (no tape anywhere)."""
    import cv2

    rig = Rig([Camera.look_at(f"cam{i}", (i * 600.0 - 600, -2500, 1200), (0, 0, 1100), (96, 72), 60)
               for i in range(3)])
    capture = Capture(root=root, name=root.name, fps=50.0, n_frames=n_frames, rig=rig, tape=TapeSpec(n_rows=5))
    capture.save()
    rng = np.random.default_rng(1)
    for name in rig.names:
        for frame in range(n_frames):
            path = root / capture.image_pattern.format(camera=name, frame=frame)
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), rng.integers(120, 136, (72, 96, 3), dtype=np.uint8))
    return root


def test_track_without_tape_exits_with_one_plain_line_and_writes_no_markers(tmp_path, capsys):
    capture = blank_capture(tmp_path / "wall")
    out = tmp_path / "out"
    code = main(["track", str(capture), "--out", str(out), "--detector", "classical", "--no-progress"])
    assert code == 3
    captured = capsys.readouterr()
    lines = [line for line in captured.err.splitlines() if line.strip()]
    assert len(lines) == 1, captured.err
    assert f"no tape found in {N_FRAMES} of {N_FRAMES} frames: check the detector with `spinemocap detector run" \
        in lines[0]
    assert "tape spacing" not in captured.out and "flagged" not in captured.out
    assert not (out / "markers.csv").exists()  # nothing written that looks like a result
    log = (out / "tracking.log").read_text().splitlines()
    assert [line.split(":")[0] for line in log] == [f"frame {f}" for f in range(N_FRAMES)]
    assert all("tape not found" in line for line in log)


def test_batch_records_a_trial_without_tape_as_failed_and_the_report_counts_it(tmp_path):
    study = tmp_path / "study"
    blank_capture(study / "S01" / "pre" / "trial01")
    (study / "S01" / "levels.toml").write_text(LEVELS)
    out = tmp_path / "out"
    code = main(["batch", str(study), "--out", str(out), "--workers", "1", "--detector", "classical", "--report",
                 "-q"])
    assert code == 1
    summary = json.loads((out / "S01" / "pre" / "trial01" / "summary.json").read_text())
    assert summary["status"] == "failed"
    assert f"no tape found in {N_FRAMES} of {N_FRAMES} frames" in summary["reason"]
    html = (out / "report.html").read_text()
    assert "1 trials, 0 analysed, 1 failed" in html


def test_batch_checks_every_trial_before_tracking_any(tmp_path):
    """Trials whose inputs are wrong (no level map, a mistyped key) fail at once, untracked,
    with the reason; the others are tracked."""
    study = tmp_path / "study"
    blank_capture(study / "S01" / "pre" / "trial01", n_frames=2)
    (study / "S01" / "levels.toml").write_text(LEVELS)
    blank_capture(study / "S02" / "pre" / "trial01", n_frames=2)  # no level map anywhere
    typo = blank_capture(study / "S01" / "pre" / "trial02", n_frames=2)
    manifest = typo / "capture.toml"
    manifest.write_text(manifest.read_text().replace("[capture]\n", "[capture]\nvidoe_pattern = 'v/{camera}.mp4'\n"))
    out = tmp_path / "out"
    from spinemocap.app.batch import run_batch

    result = run_batch(study, out, workers=1, detector="classical", progress=False)
    by_key = {t.summary.key: t.summary for t in result.trials}
    assert "no row-to-level map" in by_key["S02/pre/trial01"].reason
    assert "unknown key 'vidoe_pattern' in [capture] (valid keys: name, fps" in by_key["S01/pre/trial02"].reason
    for key in ("S02/pre/trial01", "S01/pre/trial02"):  # refused before tracking: nothing tracked
        assert not (out / key / "tracking.log").exists() and by_key[key].elapsed_s == 0.0
    assert (out / "S01/pre/trial01/tracking.log").is_file()  # the good trial was tracked
    assert "no tape found" in by_key["S01/pre/trial01"].reason
    json.loads((out / "batch.json").read_text(), parse_constant=lambda name: pytest.fail(f"bare {name} in JSON"))


@pytest.mark.parametrize("flag_first", [True, False])
def test_global_flags_are_accepted_after_the_command(tmp_path, capsys, flag_first):
    capture = blank_capture(tmp_path / "wall", n_frames=1)
    args = ["track", str(capture), "--out", str(tmp_path / "o"), "--detector", "classical", "--no-progress"]
    code = main(["-q", *args] if flag_first else [*args, "-q"])
    assert code == 3
    import logging

    assert logging.getLogger().level == logging.WARNING


def test_frame_conditions_print_one_line_per_kind_with_frame_ranges():
    from spinemocap.app.run import TrackResult, frame_ranges
    from spinemocap.markers import MarkerTable
    from spinemocap.track.pipeline import FrameResult

    assert frame_ranges([7, 0, 1, 2, 5, 8]) == "frames 0-2, 5, 7-8" and frame_ranges([4]) == "frame 4"
    n_dots = 4

    def solved(flags):
        return FrameResult(np.zeros((n_dots, 3)), np.full(n_dots, "observed", dtype=object), np.full(n_dots, 2),
                           np.zeros(n_dots), flags=flags)

    frames = [solved([]), FrameResult.missing(n_dots, {}, "no tape-like edge set"),
              FrameResult.missing(n_dots, {}, "no tape-like edge set"), solved(["identity_unsure"]),
              solved(["lp_relaxed"]), solved(["identity_unsure"])]
    positions = np.stack([f.positions for f in frames])
    table = MarkerTable.from_arrays(["R01L", "R01R", "R02L", "R02C"], positions, 100.0, first_frame=10)
    result = TrackResult(table, frames)
    assert result.no_tape() is None  # 2 of 6 frames: a result, flagged
    assert result.condition_lines() == ["tape not found: 2 of 6 frames (frames 11-12)",
                                        "identity_unsure: 2 of 6 frames (frames 13, 15)",
                                        "lp_relaxed: 1 of 6 frames (frame 14)"]
    summary = result.summary()
    assert "WARNING 4 of 6 frames flagged" in summary and "  tape not found: 2 of 6 frames (frames 11-12)" in summary
    assert "tape spacing" not in summary  # no frame measured it
    assert result.frame_log().splitlines()[0] == "frame 11: tape not found (no tape-like edge set)"
    many = TrackResult(table, [FrameResult.missing(n_dots, {}, "x")] * 4 + frames[:2])
    assert many.no_tape() == "no tape found in 5 of 6 frames"
