"""Seeded fuzzing of every text/table format the project reads (C3D: test_c3d_fuzz.py).

Each case damages a valid seed file (bit flips, truncation, line deletion/duplication, numbers
replaced by nan/inf/huge/nothing, TOML values and XML attributes of the wrong type, invalid
UTF-8) and must end in the project's InputError naming the file or in data that passes an
independent validation (tests/fuzzing.py). ``make fuzz`` runs >= 10,000 cases per format
(``SPINEMOCAP_FUZZ_CASES``)."""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import pytest
from fuzzing import (
    BINARY_MUTATORS,
    TABLE_TEXT_MUTATORS,
    TOML_MUTATORS,
    XML_MUTATORS,
    camera_rig_problems,
    capture_problems,
    case_count,
    cases,
    level_map_problems,
    marker_table_problems,
    run_fuzz,
)
from repo_paths import SHARED

import exporters
from calibration.formats import read_rig, write_rig
from calibration.formats.qualisys import read_qca
from exporters import ExportWarning
from spinemocap.analysis.levels import LevelMap
from spinemocap.camera import Camera, Rig
from spinemocap.capture import Capture, VideoSource, VideoWriter
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec

QCA = SHARED / "data" / "calibration" / "pose2sim_demo" / "Calib.qca.txt"
DEFAULT_CASES = 300
N_ROWS = 9


def rig() -> Rig:
    return Rig([Camera.look_at(f"cam{i}", (1500 * np.cos(a), -2500 + 300 * i, 1300), (0, 0, 1100), (640, 480),
                               800.0 + 10 * i, dist=(-0.1, 0.02, 0.001 * i, 0, 0.0))
                for i, a in enumerate((0.3, 1.2, 2.0))])


def marker_table() -> MarkerTable:
    rng = np.random.default_rng(3)
    pos = rng.normal(0, 200, size=(8, 4, 3)) + [0, 0, 1000]
    pos[2, 1] = np.nan
    status = np.full((8, 4), "observed", dtype=object)
    status[5] = "inferred"
    return MarkerTable.from_arrays(["R01L", "R01R", "R02L", "R02C"], pos, fps=100.0, status=status,
                                   n_views=rng.integers(0, 5, size=(8, 4)), residual=rng.random((8, 4)),
                                   first_frame=3)


QCA_CAMERA = """    <camera active="1" avg-residual="0.4" model="none" point-count="9" serial="{name}" viewrotation="0">
      <fov_video bottom="479" left="0" right="639" top="0"/>
      <fov_video_max bottom="479" left="0" right="639" top="0"/>
      <transform r11="{r[0][0]!r}" r12="{r[0][1]!r}" r13="{r[0][2]!r}" r21="{r[1][0]!r}" r22="{r[1][1]!r}" r23="{r[1][2]!r}" r31="{r[2][0]!r}" r32="{r[2][1]!r}" r33="{r[2][2]!r}" x="{c[0]!r}" y="{c[1]!r}" z="{c[2]!r}"/>
      <intrinsic centerPointU="20448.0" centerPointV="15328.0" focalLengthU="51200.0" focalLengthV="51264.0" radialDistortion1="-0.046" radialDistortion2="0.14" radialDistortion3="0.0" sensorMaxU="40960" sensorMaxV="30720" sensorMinU="0" sensorMinV="0" skew="0" tangentalDistortion1="0.0006" tangentalDistortion2="0.0007"/>
    </camera>
"""


def qca_text() -> bytes:
    cams = "".join(QCA_CAMERA.format(name=c.name, r=(np.diag([1.0, -1, -1]) @ c.R).tolist(), c=c.center.tolist())
                   for c in rig())
    return (f"<?xml version='1.0' encoding='ASCII'?>\n<calibration type=\"regular\">\n  <cameras>\n{cams}"
            "  </cameras>\n</calibration>\n").encode()


def seeds_calibration(folder: Path, suffix: str, fmt: str | None = None) -> dict[str, bytes]:
    out = {}
    for k, r in enumerate((rig(), Rig(rig().cameras[:1]))):
        path = folder / f"seed{k}{suffix}"
        write_rig(r, path, fmt=fmt)
        out[f"seed{k}"] = path.read_bytes()
    return out


def seeds_tables(folder: Path, suffix: str) -> dict[str, bytes]:
    table = marker_table()
    out = {}
    options = [{}] if suffix != ".trc" else [{}, {"units": "m", "opensim_axes": True, "forward": "-y"}]
    for k, opts in enumerate(options):
        out[f"seed{k}"] = exporters.write(table, folder / f"seed{k}{suffix}", **opts).read_bytes()
    return out


def seeds_capture(folder: Path) -> dict[str, bytes]:
    capture = Capture(root=folder, name="t1", fps=100.0, n_frames=12, rig=rig(), tape=TapeSpec(),
                      subject={"id": "S01", "up": [0.0, 0.0, 1.0], "facing": [0.0, -1.0, 0.0]})
    capture.save()
    text = (folder / "capture.toml").read_bytes()
    video = text.replace(b'media = "images"', b'media = "video"')
    return {"images": text, "video": video + b'\n[levels]\nS1 = 1\nL3 = 5\n'}


VIDEO_FRAMES, VIDEO_SIZE = 4, (64, 48)


def seeds_video(folder: Path) -> dict[str, bytes]:
    """A capture's lossless UT Video (as written by default), uncompressed BGR (the writer's other
    codec) and an FFV1 .mkv (older captures)."""
    import cv2

    rng = np.random.default_rng(5)
    frames = [rng.integers(0, 256, (VIDEO_SIZE[1], VIDEO_SIZE[0], 3), dtype=np.uint8) for _ in range(VIDEO_FRAMES)]
    new = VideoWriter(folder / "a.avi", 100.0, VIDEO_SIZE)
    raw = VideoWriter(folder / "c.avi", 100.0, VIDEO_SIZE, codec="rawvideo")
    old = cv2.VideoWriter(str(folder / "b.mkv"), cv2.VideoWriter_fourcc(*"FFV1"), 100.0, VIDEO_SIZE)
    for image in frames:
        new.write(image)
        raw.write(image)
        old.write(image)
    new.close()
    raw.close()
    old.release()
    return {"utvideo": (folder / "a.avi").read_bytes(), "rawvideo": (folder / "c.avi").read_bytes(),
            "ffv1": (folder / "b.mkv").read_bytes()}


def read_video(path: Path) -> list[np.ndarray | None]:
    """Every frame of one camera's video, as tracking reads them (the rig's size checked); a frame
    the damage made unreadable is None, with its reason recorded by the source."""
    source = VideoSource(path.parent, ["cam"], VIDEO_FRAMES, path.name, sizes=[VIDEO_SIZE])
    order = (0, 1, 3, 2)  # a jump back seeks
    try:
        frames = [source.read_camera(0, f) for f in order]
        unexplained = [f for f, image in zip(order, frames) if image is None and f not in source.unreadable["cam"]]
        if unexplained:
            raise AssertionError(f"frames {unexplained} read as None without a recorded reason")
        return frames
    finally:
        source.close()


def video_problems(frames: list[np.ndarray | None]) -> list[str]:
    shape = (VIDEO_SIZE[1], VIDEO_SIZE[0], 3)
    return [f"frame {k}: {f.dtype} {f.shape}" for k, f in enumerate(frames)
            if f is not None and (f.dtype != np.uint8 or f.shape != shape)]


LEVEL_SEEDS = {
    "table": b'[levels]\nS1 = 1\nL3 = 5\n"T12/L1" = 7.5\nT10 = 9\n',
    "top": b'S1 = 1.0\nL1 = 6\nT7 = 9\n',
}


def _table_problems(table) -> list[str]:
    return marker_table_problems(table)


FORMATS = {
    # name: (suffix, seeds(folder), mutators, reader, validation, file name)
    "rig_toml": (".toml", lambda d: seeds_calibration(d, ".toml"), TOML_MUTATORS, read_rig, camera_rig_problems, None),
    "pose2sim_toml": (".toml", lambda d: seeds_calibration(d, ".toml", "pose2sim"), TOML_MUTATORS, read_rig,
                      camera_rig_problems, None),
    "vicon_xcp": (".xcp", lambda d: seeds_calibration(d, ".xcp"), XML_MUTATORS, read_rig, camera_rig_problems, None),
    "qualisys_qca": (".qca.txt", lambda d: {"rig": qca_text(), **({"real": QCA.read_bytes()} if QCA.is_file() else {})},
                     XML_MUTATORS, read_qca, camera_rig_problems, None),
    "capture_toml": (".toml", seeds_capture, TOML_MUTATORS, lambda p: Capture.open(p.parent), capture_problems,
                     "capture.toml"),
    "levels_toml": (".toml", lambda d: LEVEL_SEEDS, TOML_MUTATORS, lambda p: LevelMap.from_toml(p, N_ROWS),
                    lambda m: level_map_problems(m, N_ROWS), None),
    "trc": (".trc", lambda d: seeds_tables(d, ".trc"), TABLE_TEXT_MUTATORS, partial(exporters.read, format="trc"),
            _table_problems, None),
    "csv": (".csv", lambda d: seeds_tables(d, ".csv"), TABLE_TEXT_MUTATORS, partial(exporters.read, format="csv"),
            _table_problems, None),
    "parquet": (".parquet", lambda d: seeds_tables(d, ".parquet"), BINARY_MUTATORS,
                partial(exporters.read, format="parquet"), _table_problems, None),
    # a seed per container: cases are written under the .avi name, which FFmpeg ignores (it probes the content)
    "video": (".avi", seeds_video, BINARY_MUTATORS, read_video, video_problems, None),
}


def fuzz_format(name: str, n: int, seed: int, tmp_path: Path):
    suffix, make_seeds, mutators, read, problems, file_name = FORMATS[name]
    seed_dir, work = tmp_path / "seeds", tmp_path / "cases"
    seed_dir.mkdir()
    work.mkdir()
    seeds = make_seeds(seed_dir)
    if name == "capture_toml":
        rig().to_toml(work / "rig.toml")
    for data in seeds.values():  # each seed itself is valid
        (work / (file_name or f"fuzz{suffix}")).write_bytes(data)
        assert list(problems(read(work / (file_name or f"fuzz{suffix}")))) == []
    report = run_fuzz(cases(seeds, n, seed, mutators), work, suffix, read, problems,
                      allowed_warnings=(ExportWarning,), file_name=file_name)
    report.check()
    return report


@pytest.mark.parametrize("name", sorted(FORMATS))
def test_fuzz_reader(name, tmp_path):
    report = fuzz_format(name, case_count(DEFAULT_CASES), seed=12, tmp_path=tmp_path)
    assert report.refused > 0 and report.accepted > 0  # both outcomes are exercised


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(FORMATS))
def test_fuzz_reader_10000(name, tmp_path):
    n = max(case_count(10_000), 10_000)
    report = fuzz_format(name, n, seed=1012, tmp_path=tmp_path)
    print(f"\nFUZZ {name}: {report.total} cases, {report.accepted} accepted, {report.refused} refused, 0 failures")
