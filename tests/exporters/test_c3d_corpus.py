"""Our C3D reader reads every valid file ezc3d reads, point by point the same.

The corpus is written by the project itself (tests/c3d_corpus.py writes the bytes; the ``c3d``
package writes the Intel files it can), one file per variant: integer and float data,
Intel/DEC/SGI processors, analog channels, rotation sections, gaps, > 65535 frames, frame
fields that disagree. Every file is also exported to CSV through the CLI."""

from __future__ import annotations

import warnings
from pathlib import Path

import c3d as c3dlib
import numpy as np
import pandas as pd
import pytest
from c3d_corpus import RawC3d, sample_points

import exporters
from exporters import ExportWarning
from exporters.c3d import C3dLayout, DeclaredFrames, frame_count
from spinemocap.cli import main
from spinemocap.fileio import InputError

ezc3d = pytest.importorskip("ezc3d")


def _raw(n_frames=30, n_points=4, seed=0, **kwargs) -> RawC3d:
    points, invalid = sample_points(n_frames, n_points, seed)
    return RawC3d(points, invalid=invalid, **kwargs)


def _analog(n_frames, per_frame, channels, seed=1):
    return np.random.default_rng(seed).normal(size=(n_frames, per_frame, channels)).round(2)


# name -> (file, regex of the warning the read must give, or None for no warning)
CORPUS = {
    "intel-float": (lambda: _raw(), None),
    "intel-int": (lambda: _raw(integer=True, scale=0.1), None),
    "dec-float": (lambda: _raw(processor="dec"), None),
    "dec-int": (lambda: _raw(processor="dec", integer=True, scale=0.1), None),
    "intel-float-analog": (lambda: _raw(analog=_analog(30, 10, 3), analog_rate=1000.0), None),
    "intel-int-analog": (lambda: _raw(integer=True, scale=0.1, analog=(_analog(30, 4, 2) * 100).round(),
                                      analog_rate=400.0), None),
    "dec-float-analog": (lambda: _raw(processor="dec", analog=_analog(30, 2, 5), analog_rate=200.0), None),
    "rotations": (lambda: _raw(rotations=np.tile(np.eye(4), (30, 2, 1, 1)) * [1, 1, 1, 1]), None),
    "rotations-analog-int": (lambda: _raw(integer=True, scale=0.1, analog=_analog(30, 2, 2) * 0,
                                          analog_rate=200.0, rotations=np.tile(np.eye(4), (30, 1, 1, 1))), None),
    "first-frame-199": (lambda: _raw(first_frame=199, trial=(199, 228)), None),
    "header-0-based": (lambda: _raw(header_first=0, header_last=29), None),
    "unpadded": (lambda: _raw(n_frames=31, pad_data=False), None),
    "no-points-frames": (lambda: _raw(point_frames=None), None),
    # an NDI Optotrak export: 54 points, 29 frames at 30 Hz, TRIAL fields counted otherwise
    "ndi-trial-fields": (lambda: _raw(n_frames=29, n_points=54, rate=30.0, trial=(1, 1149)),
                         r"TRIAL:ACTUAL_START_FIELD/ACTUAL_END_FIELD 1\.\.1149.*do not match.*Read 29 frames"),
    # an NDI Optotrak export: the header claims frames 1..1149, POINT:FRAMES 29, 29 frames stored
    "header-claims-more": (lambda: _raw(n_frames=29, n_points=54, rate=30.0, header_first=1, header_last=1149),
                           r"header first/last frame 1\.\.1149.*do not match.*Read 29 frames from frame 1, as POINT:FRAMES"),
    # the same without POINT:FRAMES: the data's 29 whole frames are read, the header's range is stale
    "header-claims-more-no-point-frames": (lambda: _raw(n_frames=29, n_points=54, rate=30.0, header_first=1,
                                                        header_last=1149, point_frames=None),
                                           r"header first/last frame 1\.\.1149.*do not match.*Read 29 frames "
                                           r"from frame 1, as the file's size says"),
    # a 25 Hz file: 23 points, 670 frames, header 1..670, POINT:FRAMES 670, TRIAL from 0
    "trial-from-0": (lambda: _raw(n_frames=670, n_points=23, rate=25.0, integer=True, scale=0.05,
                                  analog=_analog(670, 40, 2) * 0, analog_rate=1000.0, trial=(0, 670)),
                     r"TRIAL:ACTUAL_START_FIELD/ACTUAL_END_FIELD 0\.\.670.*Read 670 frames from frame 1"),
    # POINT:FRAMES says more than the file holds, the header says what it holds (32 frames fill
    # the blocks exactly, so ezc3d, which reads until the end of the file, reads the same)
    "point-frames-too-many": (lambda: _raw(n_frames=32, point_frames=40),
                              r"POINT:FRAMES = 40.*do not match.*Read 32 frames"),
    "header-too-many": (lambda: _raw(n_frames=30, header_last=50),
                        r"header first/last frame 1\.\.50.*do not match.*Read 30 frames"),
}
# Files ezc3d 1.7 refuses, compared with the c3d package and with what was written: SGI/MIPS
# ("MIPS processor type not supported yet") and a float POINT:FRAMES ("FRAMES parameter is not
# an INT"; the C3D guide allows either).
OTHERS = {"mips-float": lambda: _raw(processor="mips"),
          "mips-int": lambda: _raw(processor="mips", integer=True, scale=0.1),
          "mips-float-analog": lambda: _raw(processor="mips", analog=_analog(30, 5, 2), analog_rate=500.0),
          "point-frames-as-float": lambda: _raw(point_frames=30, point_frames_float=True)}


def _read(path, warning: str | None):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        table = exporters.read(path)
    messages = [str(w.message) for w in caught]
    if warning is None:
        assert messages == []
    else:
        assert any(str(path) in m and pd.Series([m]).str.contains(warning).item() for m in messages), messages
    return table


def _ezc3d(path):
    c = ezc3d.c3d(str(path))
    return c["header"]["points"]["first_frame"], c["data"]["points"][:3].transpose(2, 1, 0)   # (F, D, 3)


@pytest.mark.parametrize("name", sorted(CORPUS))
def test_corpus_reads_like_ezc3d(tmp_path, name):
    build, warning = CORPUS[name]
    raw = build()
    path = raw.write(tmp_path / f"{name}.c3d")
    table = _read(path, warning)
    first, theirs = _ezc3d(path)
    ours = table.positions()
    assert ours.shape == theirs.shape == raw.expected_positions().shape
    assert table.frames[0] == first == raw.first_frame - 1
    assert np.array_equal(ours, theirs, equal_nan=True)                  # identical, gaps included
    assert np.array_equal(ours, raw.expected_positions(), equal_nan=True)
    assert table.fps == raw.rate


@pytest.mark.parametrize("name", sorted(OTHERS))
def test_files_ezc3d_refuses_read_like_the_c3d_package(tmp_path, name):
    raw = OTHERS[name]()
    path = raw.write(tmp_path / f"{name}.c3d")
    table = _read(path, None)
    with open(path, "rb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = np.stack([p for _, p, _ in c3dlib.Reader(handle).read_frames()])
    theirs = np.where(frames[..., 3:4] < 0, np.nan, frames[..., :3])
    assert np.allclose(table.positions(), theirs, rtol=1e-6, equal_nan=True)   # (c3d scales in float32)
    assert np.array_equal(table.positions(), raw.expected_positions(), equal_nan=True)
    assert table.meta["processor"] == ("SGI/MIPS" if raw.processor == "mips" else "Intel")


@pytest.mark.parametrize("integer", [False, True])
def test_files_written_by_the_c3d_package_with_analog_read_like_ezc3d(tmp_path, integer):
    points, invalid = sample_points(25, 3)
    writer = c3dlib.Writer(point_rate=50.0, analog_rate=500.0, point_scale=0.1 if integer else -1.0)
    writer.set_point_labels(["A", "B", "C"])
    writer.set_analog_labels(["F1", "F2"])
    writer.set_analog_scales(np.ones(2))        # (left empty, ezc3d 1.7 reads past its end and crashes)
    writer.set_analog_offsets(np.zeros(2, np.int16))
    frames = []
    for i in range(25):
        block = np.zeros((3, 5), np.float32)
        block[:, :3] = points[i]
        block[:, 3] = np.where(invalid[i], -1.0, 0.1)
        frames.append((block, np.full((2, 10), float(i))))
    writer.add_frames(frames)
    with open(tmp_path / "pkg.c3d", "wb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        writer.write(handle)
    table = _read(tmp_path / "pkg.c3d", None)
    first, theirs = _ezc3d(tmp_path / "pkg.c3d")
    assert table.frames[0] == first and np.array_equal(table.positions(), theirs, equal_nan=True)
    assert np.isnan(table.positions()[3:7, 0]).all()


def _long(n, **kwargs) -> RawC3d:
    points = np.zeros((n, 1, 3))
    points[:, 0, 0] = np.arange(n) % 5000
    points[:, 0, 2] = 1000.0
    invalid = np.zeros((n, 1), bool)
    invalid[70_000:70_010] = True
    return RawC3d(points, rate=500.0, invalid=invalid, **kwargs)


@pytest.mark.parametrize("fields", ["long-frames+trial", "saturated-only"])
def test_more_than_65535_frames(tmp_path, fields):
    n = 70_123
    if fields == "long-frames+trial":        # what Nexus and the c3d package write
        raw = _long(n, long_frames=n, trial=(1, n))
    else:                                    # what ezc3d writes: 16-bit fields at their maximum only
        raw = _long(n, pad_data=False)
    path = raw.write(tmp_path / "long.c3d")
    table = _read(path, None)
    first, theirs = _ezc3d(path)
    assert table.n_frames == n and table.frames[0] == first == 0
    # ezc3d takes the saturated POINT:FRAMES for "read to the end of the file" and so reads the
    # zero padding of the last 512-byte block as frames at the origin; we follow LONG_FRAMES/TRIAL
    assert np.array_equal(table.positions(), theirs[:n], equal_nan=True)
    assert (theirs[n:] == 0).all() and len(theirs) - n < 512 // 16
    assert np.isnan(table.positions()[70_000:70_010]).all()


def test_first_frame_beyond_65535_comes_from_the_trial_fields(tmp_path):
    raw = _raw(first_frame=80_001, trial=(80_001, 80_030))      # header first frame saturates
    table = _read(raw.write(tmp_path / "late.c3d"), None)
    assert table.frames[0] == 80_000 and table.n_frames == 30
    assert np.array_equal(table.positions(), raw.expected_positions(), equal_nan=True)


def test_fields_that_agree_on_more_frames_than_the_file_holds_are_truncation(tmp_path):
    raw = _raw(n_frames=200)
    data = raw.to_bytes()
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(data[: len(data) - 1024])
    with pytest.raises(InputError, match=r"cut\.c3d: truncated C3D: .*declare 200 frames but the file holds 18[0-9]"):
        exporters.read(cut)
    # the TRIAL fields alone cannot make a cut file whole
    trial = tmp_path / "trial.c3d"
    trial.write_bytes(_raw(n_frames=200, trial=(1, 150)).to_bytes()[: len(data) - 1024])
    with pytest.raises(InputError, match=r"trial\.c3d: truncated C3D"):
        exporters.read(trial)


def test_no_3d_points_is_a_clear_error(tmp_path):
    raw = RawC3d(np.zeros((30, 0, 3)), analog=_analog(30, 2, 3), analog_rate=200.0,
                 rotations=np.tile(np.eye(4), (30, 2, 1, 1)))
    path = raw.write(tmp_path / "rotations_only.c3d")
    assert ezc3d.c3d(str(path))["data"]["rotations"].shape == (4, 4, 2, 30)    # a valid file
    with pytest.raises(InputError, match=r"rotations_only\.c3d: C3D file holds no 3D points \(POINT:USED = 0\); "
                                         r"it holds 3 analog channels and 2 rotations only"):
        exporters.read(path)


def test_unknown_processor_and_bad_key_are_input_errors(tmp_path):
    data = bytearray(_raw().to_bytes())
    data[512 + 3] = 99
    (tmp_path / "proc.c3d").write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"proc\.c3d: .*processor type 99"):
        exporters.read(tmp_path / "proc.c3d")
    data = bytearray(_raw().to_bytes())
    data[1] = 0x51
    (tmp_path / "key.c3d").write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"key\.c3d: not a C3D file"):
        exporters.read(tmp_path / "key.c3d")


# ------------------------------------------------------------------------------- CLI
CLI_CASES = sorted(CORPUS) + sorted(OTHERS)


@pytest.mark.parametrize("name", CLI_CASES)
def test_export_to_csv_from_every_corpus_file(tmp_path, name, capsys):
    raw = (CORPUS[name][0] if name in CORPUS else OTHERS[name])()
    path = raw.write(tmp_path / f"{name}.c3d")
    out = tmp_path / "markers.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExportWarning)
        assert main(["-q", "export", str(path), "--format", "csv", "--out", str(out)]) == 0
    back = exporters.read(out)
    assert np.allclose(back.positions(), raw.expected_positions(), rtol=1e-9, atol=1e-9, equal_nan=True)
    assert back.frames[0] == raw.first_frame - 1


def test_export_of_a_file_without_points_exits_2_naming_it(tmp_path, capsys):
    path = RawC3d(np.zeros((10, 0, 3)), analog=_analog(10, 1, 2), analog_rate=100.0).write(tmp_path / "emg.c3d")
    assert main(["-q", "export", str(path), "--format", "csv", "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert "emg.c3d: C3D file holds no 3D points" in err and "Traceback" not in err
    assert not (tmp_path / "x.csv").exists()


# ------------------------------------------------------------------------------- the frame-count rule
def _fields(point_frames=None, header=None, trial=None, saturated=False):
    out = []
    if point_frames is not None:
        out.append(DeclaredFrames("POINT:FRAMES", f"= {point_frames}", count=point_frames))
    if saturated:
        out.append(DeclaredFrames("header first/last frame", "1..65535", first=1, at_least=65535))
    else:
        out.append(DeclaredFrames("header first/last frame", f"1..{header}", first=1, count=header))
    if trial is not None:
        out.append(DeclaredFrames("TRIAL:ACTUAL_START_FIELD/ACTUAL_END_FIELD", f"1..{trial}", first=1, count=trial))
    return out


@pytest.mark.parametrize("fields,frames_in_file,expected", [
    (dict(point_frames=29, header=29, trial=1149), 29, 29),      # header and POINT:FRAMES agree
    (dict(point_frames=40, header=32), 32, 32),                  # the header is what the data fills
    (dict(point_frames=32, header=50), 32, 32),                  # POINT:FRAMES is
    (dict(point_frames=10, header=29), 29, 29),                  # read what the file holds (ezc3d: 10)
    (dict(point_frames=10, header=20, trial=29), 29, 29),        # the TRIAL fields match the data
    (dict(point_frames=None, header=30), 30, 30),
    (dict(saturated=True, trial=70_000), 70_000, 70_000),
    (dict(saturated=True), 70_001, 70_001),                      # nothing but saturated fields: the data
    (dict(point_frames=None, header=1149), 29, 29),              # a stale header range alone: the data
    (dict(point_frames=None, header=1149, trial=1149), 29, 29),
])
def test_frame_count_rule(fields, frames_in_file, expected):
    layout = C3dLayout(points=4, analog_words=0, word_bytes=4, data_start=0, data_end=64 * frames_in_file)
    assert frame_count(_fields(**fields), layout, Path("x.c3d"))[0] == expected


def test_frame_count_rule_refuses_a_stale_header_over_a_partial_frame():
    # the header alone claims more, but the data ends inside a frame: that is a cut file
    layout = C3dLayout(points=40, analog_words=0, word_bytes=4, data_start=0, data_end=640 * 29 + 600)
    with pytest.raises(InputError, match=r"x\.c3d: truncated C3D: header first/last frame 1\.\.1149"):
        frame_count(_fields(header=1149), layout, Path("x.c3d"))


@pytest.mark.parametrize("fields,frames_in_file", [
    (dict(point_frames=200, header=200, trial=150), 150),        # the fields that agree win: cut
    (dict(point_frames=200, header=300), 150),
    (dict(saturated=True), 60_000),
])
def test_frame_count_rule_refuses_cut_data(fields, frames_in_file):
    layout = C3dLayout(points=4, analog_words=0, word_bytes=4, data_start=0, data_end=64 * frames_in_file)
    with pytest.raises(InputError, match=rf"x\.c3d: truncated C3D: .* but the file holds {frames_in_file}"):
        frame_count(_fields(**fields), layout, Path("x.c3d"))
