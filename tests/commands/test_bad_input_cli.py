"""Impossible input is refused with exit code 2 and a message naming the file, never a
traceback; damaged marker samples are read as missing with a warning naming the file and how many;
outputs are checked for writing before the work starts."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

import exporters
from calibration.formats import write_rig
from exporters import ExportWarning
from spinemocap.camera import Camera, Rig
from spinemocap.capture import Capture
from spinemocap.cli import main
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec

SIZE = (32, 24)


def _rig() -> Rig:
    return Rig([Camera.look_at(f"cam{i}", (i * 500.0, -2000, 1200), (0, 0, 1100), SIZE, 40.0) for i in range(2)])


def _capture(folder: Path, image_size=SIZE, images=True) -> Path:
    Capture(root=folder, name="t", fps=50.0, n_frames=2, rig=_rig(), tape=TapeSpec(),
            subject={"id": "S01", "up": [0.0, 0.0, 1.0], "facing": [0.0, -1.0, 0.0]}).save()
    for cam in ("cam0", "cam1"):
        (folder / "images" / cam).mkdir(parents=True)
        for frame in range(2):
            image = np.full((image_size[1], image_size[0], 3), 200, np.uint8)
            if images:
                cv2.imwrite(str(folder / "images" / cam / f"{frame:06d}.png"), image)
            else:
                (folder / "images" / cam / f"{frame:06d}.png").write_bytes(b"not a png")
    return folder


def _refused(argv: list[str], capsys, names: Path, pattern: str) -> str:
    """Run the CLI: exit 2, stderr names the file and matches ``pattern``, no traceback."""
    code = main(["-q", *argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert str(names) in err and "Traceback" not in err, err
    assert re.search(pattern, err), err
    return err


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, 1))


# ---------------------------------------------------------------------------------- rig TOML
RIG_CASES = {
    "negative focal": ("fx = 40.0", "fx = -40.0", r"fx = -40 px must be positive"),
    "nan focal": ("fx = 40.0", "fx = nan", r"intrinsics must be finite"),
    "negative size": ("size = [\n    32,\n    24,\n]", "size = [-480, 0]", r"size .* whole numbers of pixels"),
    "one-number size": ("size = [\n    32,\n    24,\n]", "size = [480]", r"size must be \[width, height\]"),
    "string focal": ("fx = 40.0", 'fx = "long"', r"fx must be a number"),
    "duplicate names": ('name = "cam1"', 'name = "cam0"', r"duplicate camera names \['cam0'\]"),
    "not a rotation": ("rotation = [\n    [\n        ", "rotation = [\n    [\n        0.2 + ", None),
}


@pytest.mark.parametrize("case", sorted(RIG_CASES))
def test_track_refuses_an_impossible_rig(case, tmp_path, capsys):
    old, new, pattern = RIG_CASES[case]
    capture = _capture(tmp_path / "cap")
    rig = capture / "rig.toml"
    if case == "not a rotation":  # one entry changed: the camera would be ~30 deg off, never repaired
        text = rig.read_text()
        numbers = list(re.finditer(r"-?\d+\.\d+(e-?\d+)?", text[text.index("rotation"):]))
        at = text.index("rotation") + numbers[1].start()
        end = text.index("rotation") + numbers[1].end()
        rig.write_text(text[:at] + str(float(numbers[1].group()) + 0.5) + text[end:])
        pattern = r"not a proper rotation matrix"
    else:
        _edit(rig, old, new)
    _refused(["track", str(capture), "--out", str(tmp_path / "out"), "--detector", "mask"], capsys, rig, pattern)
    assert not (tmp_path / "out" / "markers.csv").exists()


def test_rig_with_invalid_utf8_is_refused(tmp_path, capsys):
    capture = _capture(tmp_path / "cap")
    (capture / "rig.toml").write_bytes((capture / "rig.toml").read_bytes().replace(b'"cam0"', b'"cam\xe9"'))
    _refused(["track", str(capture), "--out", str(tmp_path / "out")], capsys, capture / "rig.toml",
             r"not valid (UTF-8|TOML)")


# ---------------------------------------------------------------------------------- capture.toml
CAPTURE_CASES = {
    "fps string": ("fps = 50.0", 'fps = "fast"', r"fps must be a number, got 'fast'"),
    "fps nan": ("fps = 50.0", "fps = nan", r"fps = nan must be finite, positive"),
    "n_frames list": ("n_frames = 2", "n_frames = [4]", r"n_frames must be a number, got \[4\]"),
    "n_frames fraction": ("n_frames = 2", "n_frames = 4.7", r"n_frames = 4.7 must be a whole number"),
    "up zero": ("up = [\n    0.0,\n    0.0,\n    1.0,\n]", "up = [0, 0, 0]", r"up = \[0, 0, 0\] must be a finite, non-zero"),
    "up parallel to facing": ("up = [\n    0.0,\n    0.0,\n    1.0,\n]", "up = [0, -2, 0]", r"must not be parallel"),
    "cameras twice": ('cameras = [\n    "cam0",\n    "cam1",\n]', 'cameras = ["cam0", "cam0"]', r"lists a name twice"),
    "bad pattern": ('image_pattern = "images/{camera}/{frame:06d}.png"', 'image_pattern = "images/{0}.png"',
                    r"not a usable file pattern"),
}


@pytest.mark.parametrize("case", sorted(CAPTURE_CASES))
def test_track_refuses_an_impossible_capture_toml(case, tmp_path, capsys):
    old, new, pattern = CAPTURE_CASES[case]
    capture = _capture(tmp_path / "cap")
    _edit(capture / "capture.toml", old, new)
    _refused(["track", str(capture), "--out", str(tmp_path / "out"), "--detector", "mask"], capsys,
             capture / "capture.toml", pattern)


def test_capture_toml_with_invalid_utf8_is_refused(tmp_path, capsys):
    capture = _capture(tmp_path / "cap")
    (capture / "capture.toml").write_bytes(b'[capture]\nname = "\xff\xfe"\n')
    _refused(["track", str(capture), "--out", str(tmp_path / "out")], capsys, capture / "capture.toml",
             r"not valid UTF-8")


def test_images_of_another_size_than_the_rig_are_refused(tmp_path, capsys):
    capture = _capture(tmp_path / "cap", image_size=(40, 30))
    _refused(["track", str(capture), "--out", str(tmp_path / "out"), "--detector", "classical", "--no-progress"],
             capsys, capture / "images" / "cam0" / "000000.png", r"image is 40x30 px but the rig says camera 'cam0' is 32x24")


def test_unwritable_out_fails_before_the_work_starts(tmp_path, capsys):
    capture = _capture(tmp_path / "cap", images=False)  # tracking would fail on the first image
    (tmp_path / "file").write_text("a file, not a folder")
    out = tmp_path / "file" / "out"
    _refused(["track", str(capture), "--out", str(out), "--detector", "classical", "--no-progress"], capsys,
             out, r"cannot write to the output folder")
    _refused(["batch", str(tmp_path / "cap"), "--out", str(out), "--source", "groundtruth"], capsys, out,
             r"cannot write to the output folder")


# ---------------------------------------------------------------------------------- calibrations
def _converted(source: Path, tmp_path: Path, capsys, pattern: str) -> None:
    _refused(["calibrate", "convert", str(source), str(tmp_path / "out.toml")], capsys, source, pattern)
    assert not (tmp_path / "out.toml").exists()


XCP_CASES = {
    "focal -inf": (r'FOCAL_LENGTH="[^"]*"', 'FOCAL_LENGTH="-inf"', r"intrinsics must be finite"),
    "position 1e400": (r'POSITION="[^ "]*', 'POSITION="1e400', r"POSITION .* must be finite"),
    "aspect 0": (r'PIXEL_ASPECT_RATIO="[^"]*"', 'PIXEL_ASPECT_RATIO="0"', r"PIXEL_ASPECT_RATIO = 0.0 must be finite"),
    "not a quaternion": (r'ORIENTATION="[^ "]*', 'ORIENTATION="0.9', r"not a unit quaternion"),
    "unknown encoding": (r"encoding='UTF-8'", "encoding='klingon-8'", r"not a readable Vicon .xcp"),
}


@pytest.mark.parametrize("case", sorted(XCP_CASES))
def test_convert_refuses_an_impossible_vicon_xcp(case, tmp_path, capsys):
    old, new, pattern = XCP_CASES[case]
    path = tmp_path / "rig.xcp"
    write_rig(_rig(), path)
    text = path.read_text()
    assert re.search(old, text), text[:300]
    path.write_text(re.sub(old, new, text, count=1))
    _converted(path, tmp_path, capsys, pattern)


def _qca(tmp_path: Path, **changes: str) -> Path:
    from test_fuzz_readers import qca_text

    text = qca_text().decode()
    for key, value in changes.items():
        text = re.sub(rf'{key}="[^"]*"', f'{key}="{value}"', text, count=1)
    path = tmp_path / "calib.qca.txt"
    path.write_text(text)
    return path


@pytest.mark.parametrize("changes,pattern", [
    ({"focalLengthU": "nan"}, r"intrinsics must be finite"),
    ({"sensorMaxU": "0"}, r"sensorMaxU - sensorMinU = 0.0 must be positive"),
    ({"r12": "0.9"}, r"not a proper rotation matrix"),
    ({"serial": "cam1"}, r"duplicate camera names"),
])
def test_convert_refuses_an_impossible_qualisys_file(changes, pattern, tmp_path, capsys):
    _converted(_qca(tmp_path, **changes), tmp_path, capsys, pattern)


def test_convert_refuses_a_pose2sim_nan_focal(tmp_path, capsys):
    path = tmp_path / "p2s.toml"
    write_rig(_rig(), path, fmt="pose2sim")
    text = path.read_text()
    at = text.index("matrix")
    number = re.search(r"\d+\.\d+", text[at:])
    path.write_text(text[:at + number.start()] + "nan" + text[at + number.end():])
    _converted(path, tmp_path, capsys, r"intrinsics must be finite")


# ---------------------------------------------------------------------------------- marker files
def _table() -> MarkerTable:
    pos = np.random.default_rng(0).normal(0, 100, size=(6, 3, 3))
    return MarkerTable.from_arrays(["R01L", "R01R", "R02L"], pos, fps=100.0)


def _export(source: Path, tmp_path: Path) -> list[str]:
    return ["export", str(source), "--format", "csv", "--out", str(tmp_path / "out.csv")]


@pytest.mark.parametrize("suffix,old,new,pattern", [
    (".trc", "\n3\t", "\ninf\t", r"line \d+: not a number .*Frame# 'inf'"),
    (".trc", "100\t100\t6", "nan\t100\t6", r"finite DataRate > 0"),
    (".trc", "100\t100\t6", "0\t100\t6", r"finite DataRate > 0"),
    (".csv", "\n2,", "\n1e23,", r"frame numbers must be whole numbers"),
    (".csv", "0.02,", "nan,", r"rows have a non-finite time"),
])
def test_export_refuses_a_damaged_marker_file(suffix, old, new, pattern, tmp_path, capsys):
    path = exporters.write(_table(), tmp_path / f"m{suffix}")
    _edit(path, old, new)
    _refused(_export(path, tmp_path), capsys, path, pattern)
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("suffix", [".trc", ".csv"])
@pytest.mark.parametrize("value", ["inf", "-inf", "1e38"])
def test_absurd_samples_are_read_as_missing_with_a_warning_naming_the_file(suffix, value, tmp_path, capsys):
    table = _table()
    path = exporters.write(table, tmp_path / f"m{suffix}")
    x = table.positions()[2, 1, 0]
    text = path.read_text()
    written = f"{x:.3f}" if suffix == ".trc" else repr(float(x))
    assert text.count(written) == 1, written
    path.write_text(text.replace(written, value))
    with pytest.warns(ExportWarning, match=rf"m\{suffix}: 1 of 18 samples have non-finite or absurd"):
        assert main(["-q", *_export(path, tmp_path)]) == 0
    back = exporters.read(tmp_path / "out.csv")
    assert back.to_arrays().status[2, 1] == "missing" and np.isnan(back.positions()[2, 1]).all()
    assert back.problems() == []


@pytest.mark.parametrize("fps", [float("nan"), 0.0, -100.0, "fast"])
def test_parquet_with_an_impossible_frame_rate_is_refused(fps, tmp_path, capsys):
    import json

    import pyarrow.parquet as pq

    path = exporters.write(_table(), tmp_path / "m.parquet")
    arrow = pq.read_table(path)
    meta = json.loads(arrow.schema.metadata[b"spinemocap"])
    meta["fps"] = fps
    pq.write_table(arrow.replace_schema_metadata({b"spinemocap": json.dumps(meta).encode()}), path)
    _refused(_export(path, tmp_path), capsys, path, r"frame rate .* must be a finite positive number")


def test_levels_toml_with_impossible_rows_is_refused(tmp_path, capsys):
    markers = exporters.write(_table(), tmp_path / "m.csv")
    levels = tmp_path / "levels.toml"
    for text, pattern in (('[levels]\nS1 = nan\nL1 = 5\n', r"mapped to row nan"),
                          ('[levels]\nS1 = "one"\nL1 = 5\n', r"row must be a number"),
                          (b'[levels]\nS1 = 1\nL\xff1 = 5\n', r"not valid UTF-8")):
        if isinstance(text, bytes):
            levels.write_bytes(text)
        else:
            levels.write_text(text)
        _refused(["angles", str(markers), "--levels", str(levels)], capsys, levels, pattern)


# ---------------------------------------------------------------------------------- report
def test_report_is_written_when_an_angle_column_is_all_nan(tmp_path, capsys):
    from spinemocap.analysis.bent_tape import write_bent_capture

    study = tmp_path / "study"
    for subject in ("S01", "S02"):
        for condition in ("pre", "post"):
            write_bent_capture(study / subject / condition / "t1", TapeSpec(n_rows=9), 20.0, 12, fps=50.0)
        (study / subject / "levels.toml").write_text('[levels]\nL3 = 1\nT10 = 9\n')  # does not reach S1
    out = tmp_path / "out"
    assert main(["-q", "batch", str(study), "--out", str(out), "--source", "groundtruth", "--workers", "1",
                 "--report"]) == 0
    page = (out / "report.html").read_text()
    assert "flexion_rom_deg NaN" in page and "level S1 lies outside the mapped levels" in page
