"""The board-calibration workflow's recordings and frame pairing; the OpenSim workflow's checks of
what it is given, before any model is built."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from spinemocap.app.calibrate import Recording, open_recording, pair_frames
from spinemocap.app.opensim import opensim_capture
from spinemocap.fileio import InputError


def _folder(path, n: int, size=(64, 48)):
    path.mkdir(parents=True)
    for k in range(n):
        cv2.imwrite(str(path / f"{k:04d}.png"), np.full((size[1], size[0], 3), 10 * k, np.uint8))
    return path


def test_an_image_folder_is_a_recording_read_in_name_order(tmp_path):
    recording = open_recording(_folder(tmp_path / "cam1", 5))
    assert (recording.name, recording.n_frames, recording.size, recording.is_video) == ("cam1", 5, (64, 48), False)
    frames = dict(recording.frames({3, 1}))
    assert sorted(frames) == [1, 3] and frames[3][0, 0, 0] == 30
    with pytest.raises(InputError, match="empty.*holds no images"):
        open_recording((tmp_path / "empty").mkdir() or tmp_path / "empty")
    with pytest.raises(InputError, match="notes.txt.*not a video"):
        (tmp_path / "notes.txt").write_text("x")
        open_recording(tmp_path / "notes.txt")


def test_frames_are_paired_by_index_or_by_time():
    first = Recording("a", Path("a.mp4"), 10, (64, 48), np.arange(10) * 0.1)
    late = Recording("b", Path("b.mp4"), 10, (64, 48), np.arange(10) * 0.1 + 0.2)
    by_index = pair_frames([first, late], "index", max_frames=5)
    assert sorted(by_index[0]) == [0, 2, 4, 6, 8] and by_index[1] == by_index[0]
    by_time = pair_frames([first, late], "time", max_frames=5)
    assert by_time[1] == {0: 2, 2: 4, 4: 6, 6: 8}  # camera b's frame i is a's frame i + 2 (0.2 s later)
    untimed = Recording("c", Path("c"), 10, (64, 48))
    with pytest.raises(InputError, match="no timestamps"):
        pair_frames([first, untimed], "time", 5)
    with pytest.raises(InputError, match="unknown frame pairing 'closest'"):
        pair_frames([first], "closest", 5)


def test_opensim_needs_a_lab_models_file_and_body_map_together(tmp_path):
    pytest.importorskip("opensim")
    with pytest.raises(InputError, match="model: a lab model needs both"):
        opensim_capture(tmp_path, tmp_path, tmp_path / "out", model=tmp_path / "lab.osim")
    assert not (tmp_path / "out").exists()
