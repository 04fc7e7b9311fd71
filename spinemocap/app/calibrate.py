"""Board calibration of a rig from what a lab records: one board video (any codec or rate, read
through PyAV) or image folder per camera, frames paired across cameras by index or by the
containers' timestamps, the board found in each frame (its printed variant found once for the
session), every other frame's reason for being left out, intrinsics from the same recordings when
none are given, then :func:`calibration.extrinsics.calibrate_extrinsics`.

Frame keys: with ``pairing="index"`` frame k of every camera is key k; with ``pairing="time"``
a camera's frame takes the key of the first camera's frame nearest in time (within half of that
camera's frame interval), so cameras started at different moments or recording at different
rates still pair. ``--floor-frames`` name these keys.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field, replace
from fractions import Fraction
from pathlib import Path
from typing import Hashable, Iterator, Literal, Sequence

import cv2
import numpy as np
from tqdm import tqdm

from calibration.boards import MAX_BLUR_SIGMA_PX, BoardDetection, BoardSpec, Facing, detect_board, view_problem
from calibration.check import plot_residuals, save_residuals
from calibration.extrinsics import ExtrinsicsResult, calibrate_extrinsics
from calibration.formats import read_rig, write_rig
from calibration.intrinsics import calibrate_from_detections
from calibration.wand import WandSpec, detect_wand_views, synchronized_frames
from calibration.wandwave import WandWaveResult, calibrate_wand_wave, plot_length_error
from spinemocap.camera import Rig
from spinemocap.fileio import InputError, atomic_path
from spinemocap.media import IMAGE_SUFFIXES, VIDEO_SUFFIXES
from spinemocap.rig_adjust import Backend

FramePairing = Literal["index", "time"]
PAIRINGS: tuple[FramePairing, ...] = ("index", "time")
NOT_FOUND = "board not found"
#: A view whose edges are this much blurrier than the median of its camera's views is left out
#: (motion blur: the hand moved during that exposure; the cameras' exposures differ in time too).
RELATIVE_BLUR = 1.35
#: A camera whose reprojection RMS after the adjustment reaches this is flagged.
MAX_RMS_PX = 1.0


# ---------------------------------------------------------------------- recordings
@dataclass
class Recording:
    """One camera's board recording: a video or a folder of images (sorted by name).
    ``times_s``: each frame's presentation time from the container (videos), else None;
    ``size``: (width, height) px."""

    name: str
    path: Path
    n_frames: int
    size: tuple[int, int]
    times_s: np.ndarray | None = None
    files: list[Path] = field(default_factory=list, repr=False)

    @property
    def is_video(self) -> bool:
        return not self.files

    def frames(self, wanted: set[int]) -> Iterator[tuple[int, np.ndarray]]:
        """(frame index, BGR image) of the ``wanted`` frames, in order."""
        if not self.is_video:
            for k in sorted(wanted):
                image = cv2.imread(str(self.files[k]), cv2.IMREAD_COLOR)
                if image is None:
                    raise InputError(self.files[k], "cannot be read as an image")
                yield k, image
            return
        import av

        with av.open(str(self.path)) as container:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            last, index = max(wanted, default=-1), -1
            try:
                for index, decoded in enumerate(container.decode(stream)):
                    if index in wanted:
                        yield index, decoded.to_ndarray(format="bgr24")
                    if index >= last:
                        break
            except av.error.FFmpegError as exc:
                raise InputError(self.path, f"video cannot be decoded past frame {index} ({exc})") from None


def open_recording(path: str | os.PathLike, name: str | None = None) -> Recording:
    """Scan one camera's recording: a video (frame count and timestamps from its packets, no
    decoding) or a folder of images. Raises :class:`InputError` for anything else."""
    path = Path(path)
    name = name or path.stem
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(path, "folder holds no images (.png/.jpg/...); give one folder or video per camera")
        first = cv2.imread(str(files[0]), cv2.IMREAD_COLOR)
        if first is None:
            raise InputError(files[0], "cannot be read as an image")
        return Recording(name, path, len(files), (first.shape[1], first.shape[0]), None, files)
    if not path.is_file():
        raise InputError(path, "no such video or image folder")
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(path, f"not a video ({', '.join(sorted(VIDEO_SUFFIXES))}) or image folder")
    return _scan_video(path, name)


def _scan_video(path: Path, name: str) -> Recording:
    import av

    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            time_base = Fraction(stream.time_base) if stream.time_base else None
            pts = [p.pts for p in container.demux(stream) if p.pts is not None and p.size]
            size = (stream.codec_context.width, stream.codec_context.height)
    except (av.error.FFmpegError, IndexError) as exc:
        raise InputError(path, f"video cannot be opened (corrupt or unsupported: {exc})") from None
    if not pts or time_base is None or not size[0]:
        raise InputError(path, "video has no frames with timestamps")
    # presentation times on the container's clock: a camera that started later has later times
    times = np.sort(np.asarray(pts, dtype=np.int64)).astype(float) * float(time_base)
    return Recording(name, path, len(times), size, times)


def pair_frames(recordings: Sequence[Recording], pairing: FramePairing, max_frames: int) -> list[dict[int, int]]:
    """Per camera, frame index -> frame key for the frames to read: at most ``max_frames`` keys,
    spread evenly over the first camera's frames (see the module doc for the two pairings)."""
    if pairing not in PAIRINGS:
        raise InputError("pairing", f"unknown frame pairing {pairing!r}; choose one of {PAIRINGS}")
    first = recordings[0]
    step = max(1, int(np.ceil(first.n_frames / max(max_frames, 1))))
    keys = set(range(0, first.n_frames, step))
    if pairing == "index":
        return [{k: k for k in keys if k < rec.n_frames} for rec in recordings]
    untimed = [str(rec.path) for rec in recordings if rec.times_s is None]
    if untimed:
        raise InputError(untimed[0], "image folders have no timestamps; pair frames by index")
    assert first.times_s is not None
    paired = []
    for rec in recordings:
        assert rec.times_s is not None
        interval = float(np.median(np.diff(rec.times_s))) if rec.n_frames > 1 else np.inf
        after = np.clip(np.searchsorted(first.times_s, rec.times_s), 0, first.n_frames - 1)
        before = np.clip(after - 1, 0, first.n_frames - 1)
        closer = np.abs(first.times_s[before] - rec.times_s) < np.abs(first.times_s[after] - rec.times_s)
        pick = np.where(closer, before, after)
        gap = np.abs(first.times_s[pick] - rec.times_s)
        nearest: dict[int, int] = {}  # key -> this camera's nearest frame
        for i in np.argsort(gap):
            if gap[i] <= 0.5 * interval and int(pick[i]) in keys:
                nearest.setdefault(int(pick[i]), int(i))
        paired.append({i: key for key, i in nearest.items()})
    return paired


# ---------------------------------------------------------------------- detection
@dataclass
class CameraViews:
    """One camera's frames: ``usable[key]`` detections and ``rejected[key]`` reasons."""

    name: str
    source: Path
    size: tuple[int, int]
    n_read: int
    usable: dict[Hashable, BoardDetection]
    rejected: dict[Hashable, str]

    @property
    def n_with_board(self) -> int:
        return self.n_read - sum(why == NOT_FOUND for why in self.rejected.values())

    def reasons(self) -> Counter:
        """Rejection reasons, the numbers in them dropped (so that alike reasons count together)."""
        return Counter(why.split(" (")[0] for why in self.rejected.values())


@dataclass
class BoardSession:
    """The board found in every camera's frames: ``board`` as asked, ``read_as`` the variant that
    read it (polarity and layout for the session, facing per camera in ``facing``)."""

    board: BoardSpec
    read_as: BoardSpec | None
    facing: dict[str, Facing]
    cameras: list[CameraViews]

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def detections(self) -> dict[str, dict[Hashable, BoardDetection]]:
        return {c.name: dict(c.usable) for c in self.cameras}

    def summary(self) -> str:
        lines = []
        if self.read_as is None:
            lines.append(f"board {self.board}: not read in any frame")
        else:
            asked = {"polarity": self.board.polarity, "layout": self.board.layout}
            found = f"{self.read_as.polarity} colours" + (f", {self.read_as.layout} layout"
                                                          if self.read_as.layout_matters else "")
            auto = [k for k, v in asked.items() if v == "auto" and (k == "polarity" or self.board.layout_matters)]
            if self.board.kind == "checkerboard" and auto:
                note = " (assumed: a checkerboard reads the same in both; add :inverted if it is)"
            else:
                note = f" (found: {', '.join(auto)})" if auto else ""
            lines.append(f"board {self.board}: read as {found}{note}")
            mirrored = [n for n, f in self.facing.items() if f == "mirrored"]
            if mirrored:
                lines.append(f"  seen mirrored (from behind) by {', '.join(mirrored)}")
        lines.append(f"{'camera':<12}{'frames':>7}{'board':>7}{'usable':>7}  left out")
        for cam in self.cameras:
            why = "; ".join(f"{reason} {n}" for reason, n in cam.reasons().most_common())
            lines.append(f"{cam.name:<12}{cam.n_read:>7}{cam.n_with_board:>7}{len(cam.usable):>7}  {why or '-'}")
        return "\n".join(lines)


def detect_session(recordings: Sequence[Recording], board: BoardSpec, pairing: FramePairing = "index",
                   max_frames: int = 200, max_blur_px: float = MAX_BLUR_SIGMA_PX,
                   progress: bool = True) -> BoardSession:
    """Find the board in every camera's paired frames (:func:`pair_frames`), check each view
    (:func:`calibration.boards.view_problem`: blur, too few corners, layout, obliqueness, size),
    then keep the variant that read most views (polarity and layout over the session, facing
    per camera) and leave out views read as another, with the reason."""
    pairs = pair_frames(recordings, pairing, max_frames)
    cameras = []
    for rec, keys in zip(recordings, pairs):
        usable: dict[Hashable, BoardDetection] = {}
        rejected: dict[Hashable, str] = {}
        frames = tqdm(rec.frames(set(keys)), total=len(keys), desc=f"board in {rec.name}", unit=" frames",
                      disable=not progress, leave=False)
        for index, image in frames:
            if (image.shape[1], image.shape[0]) != rec.size:
                raise InputError(rec.path, f"frame {index} is {image.shape[1]}x{image.shape[0]} px, not "
                                 f"{rec.size[0]}x{rec.size[1]} like the others")
            det = detect_board(image, board)
            problem = view_problem(det, board, rec.size, max_blur_px=max_blur_px)
            if problem or det is None:
                rejected[keys[index]] = problem or NOT_FOUND
            else:
                usable[keys[index]] = det
        _leave_out_blurrier(usable, rejected)
        cameras.append(CameraViews(rec.name, rec.path, rec.size, len(keys), usable, rejected))
    return _keep_consistent_variant(board, cameras)


def _leave_out_blurrier(usable: dict[Hashable, BoardDetection], rejected: dict[Hashable, str],
                        min_views: int = 5) -> None:
    """Move views blurrier than :data:`RELATIVE_BLUR` times the median of the camera's views
    from ``usable`` to ``rejected`` (with at least ``min_views`` views to judge by)."""
    if len(usable) < min_views:
        return
    typical = float(np.median([det.blur_px for det in usable.values()]))
    for key, det in list(usable.items()):
        if det.blur_px > RELATIVE_BLUR * typical:
            rejected[key] = (f"blurred beside this camera's other views (edge sigma {det.blur_px:.1f} px, "
                             f"median {typical:.1f}): motion blur")
            del usable[key]


def _keep_consistent_variant(board: BoardSpec, cameras: list[CameraViews]) -> BoardSession:
    printed = Counter(d.variant.board_variant for c in cameras for d in c.usable.values() if d.variant)
    if not printed:
        return BoardSession(board, None, {}, cameras)
    polarity, layout = printed.most_common(1)[0][0]
    facing: dict[str, Facing] = {}
    for cam in cameras:
        sides = Counter(d.variant.facing for d in cam.usable.values()
                        if d.variant and d.variant.board_variant == (polarity, layout))
        facing[cam.name] = sides.most_common(1)[0][0] if sides else "front"
        for key, det in list(cam.usable.items()):
            v = det.variant
            if v is not None and (v.board_variant != (polarity, layout) or v.facing != facing[cam.name]):
                cam.rejected[key] = (f"read as {v.polarity}/{v.layout}/{v.facing}, unlike the other views "
                                     f"({polarity}/{layout}/{facing[cam.name]}): a stray read")
                del cam.usable[key]
    read_as = replace(board, polarity=polarity, layout=layout, facing="auto")
    return BoardSession(board, read_as, facing, cameras)


# ---------------------------------------------------------------------- calibration
def read_cameras(paths: Sequence[str | os.PathLike]) -> Rig:
    """The cameras of one or more calibration files (any supported format), in order."""
    return Rig([cam for path in paths for cam in read_rig(path)])


def intrinsics_from_session(session: BoardSession, board: BoardSpec, fix_k3: bool = True) -> tuple[Rig, str]:
    """Each camera's intrinsics from its own usable board views in the session (OpenCV
    ``calibrateCamera``, outlier views dropped); returns the cameras and a text report."""
    cameras, lines = [], []
    for cam in session.cameras:
        result = calibrate_from_detections(cam.usable, [], cam.size, board, cam.name, str(cam.source), fix_k3)
        cameras.append(result.camera)
        k = result.camera.K
        lines.append(f"intrinsics {cam.name} from {len(result.views)} of its views: fx {k[0, 0]:.1f} fy {k[1, 1]:.1f} "
                     f"cx {k[0, 2]:.1f} cy {k[1, 2]:.1f} px, k1 {result.camera.dist[0]:+.4f}, RMS {result.rms_px:.3f} px")
    return Rig(cameras), "\n".join(lines)


@dataclass
class SessionCalibration:
    """A rig calibrated from board recordings: the detection report, where the intrinsics came
    from, and the extrinsics result (rig, per-camera RMS, pose graph, board poses)."""

    session: BoardSession
    intrinsics_report: str
    result: ExtrinsicsResult
    floor_frames: list | None = None  # frame keys of the board on the floor; None: the first camera's frame

    def summary(self) -> str:
        parts = [self.session.summary()]
        if self.intrinsics_report:
            parts.append(self.intrinsics_report)
        parts.append(self.result.summary())
        high = [name for name, rms in self.result.rms_px.items() if not rms < MAX_RMS_PX]
        if high:
            parts.append(f"! reprojection RMS of {', '.join(high)} is {MAX_RMS_PX:g} px or more: check the board "
                         "spec (square and marker sizes), the frame pairing and the left-out reasons above")
        return "\n".join(parts)


def calibrate_recordings(views: Sequence[str | os.PathLike], board: BoardSpec, intrinsics: Rig | None = None,
                         pairing: FramePairing = "index", max_frames: int = 200, floor_frames: list | None = None,
                         refine_intrinsics: bool = True, backend: Backend = "ceres",
                         max_blur_px: float = MAX_BLUR_SIGMA_PX, progress: bool = True) -> SessionCalibration:
    """The whole board calibration from one recording per camera (in ``intrinsics``' camera
    order when given; camera names from the file names otherwise, intrinsics then from the same
    recordings). ``floor_frames``: frame keys where the board lies face up on the floor (world Z
    up), None: the first camera's frame is the world."""
    names = intrinsics.names if intrinsics is not None else [None] * len(views)
    if intrinsics is not None and len(views) != len(intrinsics):
        raise InputError("views", f"{len(views)} recordings for {len(intrinsics)} cameras; give one per camera, "
                         "in the calibration files' order")
    recordings = [open_recording(path, name) for path, name in zip(views, names)]
    if len({r.name for r in recordings}) < len(recordings):
        raise InputError("views", f"two recordings share a camera name ({[r.name for r in recordings]}); "
                         "name the files or folders after their cameras")
    if intrinsics is not None:
        for rec, cam in zip(recordings, intrinsics):
            if rec.size != tuple(cam.size):
                raise InputError(rec.path, f"images are {rec.size[0]}x{rec.size[1]} px but camera {cam.name!r} was "
                                 f"calibrated at {cam.size[0]}x{cam.size[1]}; use the same resolution for "
                                 "intrinsics and extrinsics")
    session = detect_session(recordings, board, pairing, max_frames, max_blur_px, progress)
    used = session.read_as or board
    report = ""
    if intrinsics is None:
        intrinsics, report = intrinsics_from_session(session, used)
    result = calibrate_extrinsics(intrinsics, used, session.detections(), floor_frame=floor_frames,
                                  refine_intrinsics=refine_intrinsics, progress=progress, backend=backend)
    return SessionCalibration(session, report, result, floor_frames)


@dataclass(frozen=True)
class CalibrationFiles:
    """The files :func:`write_calibration` wrote, paths as given: the rig, its reprojection
    residuals (``RIG.residuals.npz``, read back by ``calibrate check``), the residual plot (PNG)
    and the picture of the cameras and board poses in 3D (``RIG.rig3d.png``)."""

    rig: str
    residuals: str
    residual_plot: str
    rig_3d: str


def write_calibration(calibrated: SessionCalibration, out: str | os.PathLike, rig_format: str | None = None,
                      residual_plot: str | os.PathLike | None = None) -> CalibrationFiles:
    """Write a board calibration's rig to ``out`` (``.toml``, ``rig_format`` "spinemocap" or
    "pose2sim", or ``.xcp``), its residuals beside it, the residual plot (default
    ``OUT.residuals.png``) and the 3D picture (``OUT.rig3d.png``; drawn with the world's Z up
    when the board lay on the floor, else with the first camera's image up)."""
    result, rig_path = calibrated.result, os.fspath(out)
    write_rig(result.rig, rig_path, rig_format)
    residuals = save_residuals(rig_path, result.residuals)
    plot = os.fspath(residual_plot) if residual_plot else f"{rig_path}.residuals.png"
    plot_residuals(result.rig, result.residuals, plot)
    up = None if calibrated.floor_frames is not None else -result.rig[0].R[1]
    board = calibrated.session.read_as or calibrated.session.board
    plot_rig_3d(result.rig, board, result.board_poses, f"{rig_path}.rig3d.png", up=up)
    return CalibrationFiles(rig_path, str(residuals), plot, f"{rig_path}.rig3d.png")


@dataclass(frozen=True)
class WandWaveFiles:
    """The files :func:`write_wand_wave` wrote, paths as given: the rig, its reprojection
    residuals (``RIG.residuals.npz``), the residual plot and the wand-length error plot (PNG)."""

    rig: str
    residuals: str
    residual_plot: str
    length_plot: str


def calibrate_wand_wave_videos(videos: Sequence[str | os.PathLike], intrinsics: Rig, wand: WandSpec,
                               floor_frames: list[int] | None = None, backend: Backend = "ceres",
                               refine_intrinsics: bool = True) -> WandWaveResult:
    """A rig from one wand-wave video (or image folder) per ``intrinsics`` camera, in rig order:
    frames streamed in step (the shortest recording decides the length), the wand's markers
    found in each, then :func:`calibration.wandwave.calibrate_wand_wave` (``floor_frames``:
    frames where the wand lies on the floor; None: the first camera's frame is the world)."""
    frames, _ = synchronized_frames(videos, len(intrinsics))
    views = detect_wand_views(frames, wand)
    return calibrate_wand_wave(intrinsics, views, wand, floor_frames, backend=backend,
                               refine_intrinsics=refine_intrinsics)


def write_wand_wave(result: WandWaveResult, out: str | os.PathLike, rig_format: str | None = None,
                    length_plot: str | os.PathLike | None = None) -> WandWaveFiles:
    """Write a wand wave's rig to ``out`` (format as :func:`write_calibration`), its residuals
    beside it, the residual plot (``OUT.residuals.png``) and the wand-length error plot (default
    ``OUT.wand_length.png``)."""
    rig_path = os.fspath(out)
    write_rig(result.rig, rig_path, rig_format)
    residuals = save_residuals(rig_path, result.residuals)
    plot_residuals(result.rig, result.residuals, f"{rig_path}.residuals.png")
    length = os.fspath(length_plot) if length_plot else f"{rig_path}.wand_length.png"
    plot_length_error(result, length)
    return WandWaveFiles(rig_path, str(residuals), f"{rig_path}.residuals.png", length)


def load_view_detections(folders: Sequence[str | os.PathLike], rig: Rig, board: BoardSpec,
                         pairing: FramePairing = "index") -> dict[str, dict[Hashable, BoardDetection]]:
    """The usable board views of one recording per ``rig`` camera (frame key -> detection)."""
    if len(folders) != len(rig):
        raise InputError("views", f"{len(folders)} recordings for {len(rig)} cameras; give one per camera")
    recordings = [open_recording(path, cam.name) for path, cam in zip(folders, rig)]
    for rec, cam in zip(recordings, rig):
        if rec.size != tuple(cam.size):
            raise InputError(rec.path, f"images are {rec.size[0]}x{rec.size[1]} px but camera {cam.name!r} was "
                             f"calibrated at {cam.size[0]}x{cam.size[1]}; use the same resolution")
    return detect_session(recordings, board, pairing, max_frames=100_000).detections()


# ---------------------------------------------------------------------- picture
def plot_rig_3d(rig: Rig, board: BoardSpec, board_poses: dict, path: str | os.PathLike, title: str = "",
                up: np.ndarray | None = None) -> None:
    """PNG of the cameras (viewing pyramids, 1/4 of the mean camera distance deep, with names)
    and every board pose (outline of the printed pattern) in the rig's world frame (mm), drawn
    with ``up`` (a world direction; default the world's Z) pointing up."""
    import matplotlib

    if up is not None:  # turn the world so that ``up`` becomes Z
        z = np.asarray(up, float) / np.linalg.norm(up)
        x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
        x /= np.linalg.norm(x)
        turn = np.stack([x, np.cross(z, x), z])
        rig = rig.transformed(turn, np.zeros(3))
        board_poses = {f: (turn @ R, turn @ t) for f, (R, t) in board_poses.items()}

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(7.5, 6.5))
    ax = fig.add_subplot(projection="3d")
    w_mm, h_mm = board.size_mm
    outline = np.array([[0, 0, 0], [w_mm, 0, 0], [w_mm, h_mm, 0], [0, h_mm, 0], [0, 0, 0]], float)
    points = [cam.center for cam in rig]
    for R, t in board_poses.values():
        corners = outline @ np.asarray(R).T + t
        ax.plot(*corners.T, color="tab:orange", lw=0.8, alpha=0.7)
        points.append(corners.mean(axis=0))
    cloud = np.asarray(points)
    depth = 0.25 * float(np.mean(np.linalg.norm(cloud[: len(rig)] - cloud.mean(axis=0), axis=1)) or 100.0)
    for cam in rig:
        w, h = cam.size
        rays = cam.undistort_points(np.array([[0, 0], [w, 0], [w, h], [0, h]], float), normalized=True)
        tips = (np.column_stack([rays, np.ones(4)]) * depth) @ cam.R + cam.center  # camera -> world
        for tip in tips:
            ax.plot(*np.column_stack([cam.center, tip]), color="tab:blue", lw=0.8)
        ax.plot(*np.vstack([tips, tips[:1]]).T, color="tab:blue", lw=0.8)
        ax.text(*cam.center, f" {cam.name}", fontsize=8)
    everything = np.vstack([cloud, *[outline @ np.asarray(R).T + t for R, t in board_poses.values()]])
    span = np.ptp(everything, axis=0).max() / 2 or 1.0
    mid = (everything.max(axis=0) + everything.min(axis=0)) / 2
    ax.set_xlim(mid[0] - span, mid[0] + span)
    ax.set_ylim(mid[1] - span, mid[1] + span)
    ax.set_zlim(mid[2] - span, mid[2] + span)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Y (mm)")
    ax.set_zlabel("Z (mm)")
    ax.set_title(title or f"{len(rig)} cameras and {len(board_poses)} board poses", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
