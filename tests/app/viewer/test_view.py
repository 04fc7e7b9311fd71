"""Labelled camera videos and the 3D viewer (``spinemocap view``) on a small capture made by hand
(a flat tape behind three distorting cameras), its dots written and read back as a real results
folder with some dots inferred, some flagged and one missing."""

from __future__ import annotations

import html.parser
import json
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from spinemocap.app.results import write_markers
from spinemocap.app.viewer.layout import GRID_NAME, VIEWER_NAME, view_outputs
from spinemocap.app.viewer.scene3d import json_for_script, write_viewer
from spinemocap.app.viewer.tracked import CLASS_COLOURS_BGR, DotClass, read_tracked
from spinemocap.app.viewer.video import (
    AUTO_LONG_SIDE,
    GRID_MAX_WIDTH,
    RING_PX,
    OverlayStyle,
    auto_scale,
    grid_layout,
    resize_image,
    scale_pixels,
    selected_frames,
    write_videos,
)
from spinemocap.camera import Camera, Rig
from spinemocap.capture import Capture
from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec

av = pytest.importorskip("av")

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
HOSTILE_CAMERA = "<script>alert(1)</script>"
HOSTILE_SUBJECT = "</script><script>alert(2)</script>"


def _hand_made_capture(root: Path, n_frames: int = 3) -> Path:
    """A capture folder made by hand: three cameras with lens distortion behind a 7-row tape
    laid flat on a back (x across, z up, the subject facing -y), grey images, a level map."""
    cameras = [Camera.look_at(f"cam{k + 1}", position, (0.0, 0.0, 1075.0), (480, 360), 620.0,
                              dist=(-0.12, 0.03, 0.0, 0.0, 0.0))
               for k, position in enumerate([(-450.0, 900.0, 1250.0), (0.0, 950.0, 1100.0), (450.0, 900.0, 950.0)])]
    capture = Capture(root=root, name="hand", fps=50.0, n_frames=n_frames, rig=Rig(cameras), tape=TapeSpec(n_rows=7),
                      subject={"id": "S01", "up": [0.0, 0.0, 1.0], "facing": [0.0, -1.0, 0.0]})
    capture.save()
    rng = np.random.default_rng(0)
    for camera in cameras:
        (root / "images" / camera.name).mkdir(parents=True)
        for frame in range(n_frames):
            grey = np.clip(90 + 40 * np.linspace(0, 1, 480)[None, :] + rng.normal(0, 4, (360, 480)), 0, 255)
            cv2.imwrite(str(root / "images" / camera.name / f"{frame:06d}.png"),
                        np.repeat(grey.astype(np.uint8)[..., None], 3, axis=2))
    (root / "levels.toml").write_text('S1 = 1\nL3 = 4\n"T12/L1" = 7\n')
    return root


def _tape_dots(tape: TapeSpec, n_frames: int) -> np.ndarray:
    """(F, D, 3) mm: the tape's flat layout on the back, sliding sideways 4 mm a frame."""
    uv = tape.graph.uv_mm
    dots = np.stack([-uv[:, 0], np.zeros(len(uv)), 1000.0 + uv[:, 1]], axis=1)  # u: the subject's right (-x)
    return np.stack([dots + [4.0 * f, 0.0, 0.0] for f in range(n_frames)])


@pytest.fixture(scope="module")
def tracked_capture(tmp_path_factory):
    """(capture folder, results folder): 3 frames; dots of row 2 inferred, of row 4 flagged (low
    confidence), dot R01L missing in the last frame; written as a results folder."""
    root = tmp_path_factory.mktemp("view")
    capture_dir = _hand_made_capture(root / "capture")
    capture = Capture.open(capture_dir)
    labels = capture.tape.labels
    positions = _tape_dots(capture.tape, capture.n_frames)
    rows = np.array([int(label[1:3]) for label in labels])
    status = np.where(rows == 2, "inferred", "observed").astype(object)[None].repeat(capture.n_frames, axis=0)
    confidence = np.where(status == "observed", 1.0, 0.6)
    confidence[:, rows == 4] = 0.3  # below 0.6 x its status factor: a label the tracker cannot vouch for
    positions[2, 0] = np.nan  # R01L missing in the last frame
    table = MarkerTable.from_arrays(labels, positions, capture.fps, status=status, confidence=confidence,
                                    n_views=np.full(status.shape, 3))
    results = root / "results"
    write_markers(table, results)
    return capture_dir, results


def test_selected_frames_reads_the_one_frame_syntax(tracked_capture):
    capture_dir, results = tracked_capture
    capture = Capture.open(capture_dir)
    tracked = read_tracked(results, capture.tape)
    assert selected_frames(tracked, None, capture.n_frames) == [0, 1, 2]
    assert selected_frames(tracked, "0:3:2", capture.n_frames) == [0, 2]
    assert selected_frames(tracked, "2,0", capture.n_frames) == [0, 2]
    with pytest.raises(InputError, match="step 0") as caught:
        selected_frames(tracked, "0:3:0", capture.n_frames)
    assert caught.value.source == "frames"  # the parameter; the command line shows --frames


def test_read_tracked_classes(tracked_capture):
    capture_dir, results = tracked_capture
    capture = Capture.open(capture_dir)
    tracked = read_tracked(results, capture.tape)
    rows = tracked.row + 1
    assert (tracked.classes[:, rows == 2] == DotClass.INFERRED).all()
    assert (tracked.classes[:, rows == 4] == DotClass.FLAGGED).all()
    assert (tracked.classes[:, (rows != 2) & (rows != 4)][:2] == DotClass.OBSERVED).all()
    assert tracked.classes[2, 0] == DotClass.MISSING
    assert tracked.frame_flagged.all()  # row 4's doubt flags every frame
    # every row's neighbours are joined, no segment crosses rows
    segments = tracked.row_segments()
    assert (tracked.row[segments[:, 0]] == tracked.row[segments[:, 1]]).all()
    assert len(segments) == sum(len(np.flatnonzero(tracked.row == r)) - 1 for r in np.unique(tracked.row))


def test_results_of_another_capture_are_refused(tracked_capture, tmp_path):
    capture_dir, results = tracked_capture
    table = MarkerTable.from_arrays(["R01L", "X99"], np.zeros((2, 2, 3)), 10.0)
    write_markers(table, tmp_path)
    with pytest.raises(InputError, match="another capture"):
        read_tracked(tmp_path, Capture.open(capture_dir).tape)
    (tmp_path / "markers.csv").write_text("frame,time\n")  # a damaged set: the manifest no longer matches
    with pytest.raises(InputError, match="markers.csv"):
        write_videos(capture_dir, tmp_path, tmp_path / "view", progress=False)
    assert not (tmp_path / "view" / GRID_NAME).exists()


def _colour_mask(image_bgr: np.ndarray, bgr: tuple[int, int, int]) -> np.ndarray:
    """Pixels of a decoded (lossy) frame close to a drawn class colour."""
    diff = np.abs(image_bgr.astype(int) - np.array(bgr)).max(axis=2)
    return diff < 60


def _decoded_frames(path: Path, luma: bool = False) -> list[np.ndarray]:
    """The video's frames as BGR images, or (``luma``) their full-resolution luma planes."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264"
        assert stream.codec_context.pix_fmt == "yuv420p"
        if luma:
            return [frame.to_ndarray(format="yuv420p")[:frame.height].astype(float) for frame in container.decode(stream)]
        return [frame.to_ndarray(format="bgr24") for frame in container.decode(stream)]


def test_video_frames_carry_dots_at_reprojected_pixels(tracked_capture, tmp_path):
    capture_dir, results = tracked_capture
    capture = Capture.open(capture_dir)
    scale = 2.0
    result = write_videos(capture_dir, results, tmp_path, scale=scale, progress=False)
    assert set(result.cameras) == set(capture.camera_names) and result.frames == [0, 1, 2]
    tracked = read_tracked(results, capture.tape)
    checked = {DotClass.OBSERVED: 0, DotClass.INFERRED: 0, DotClass.FLAGGED: 0}
    errors = []
    for camera in capture.rig:
        frames = _decoded_frames(result.cameras[camera.name])
        lumas = _decoded_frames(result.cameras[camera.name], luma=True)
        assert len(frames) == 3
        size = result.sizes[camera.name]
        assert frames[0].shape[1::-1] == size
        radius = OverlayStyle.for_size(size).dot_radius_px
        for k, (image, luma) in enumerate(zip(frames, lumas)):
            projected = scale_pixels(camera.project(np.nan_to_num(tracked.positions[k], nan=0.0)),
                                     (size[0] / camera.size[0], size[1] / camera.size[1]))
            present = tracked.classes[k] != DotClass.MISSING
            for d in np.flatnonzero(present):
                u, v = projected[d]
                others = np.delete(projected[present], np.flatnonzero(np.flatnonzero(present) == d), axis=0)
                if np.linalg.norm(others - projected[d], axis=1).min() < 2 * radius + 6:
                    continue  # discs touching a neighbour's cannot be told apart
                if not (3 * radius < u < size[0] - 3 * radius and 6 * radius < v < size[1] - 6 * radius):
                    continue  # near the border (header band, legend)
                cls = DotClass(int(tracked.classes[k, d]))
                window = 2 * radius
                x0, y0 = int(round(u)) - window, int(round(v)) - window
                patch = image[y0:y0 + 2 * window + 1, x0:x0 + 2 * window + 1].astype(float)
                mask = _colour_mask(patch, CLASS_COLOURS_BGR[cls])
                assert mask.sum() >= 0.5 * np.pi * radius**2, f"no {cls.name} disc at {camera.name} frame {k} {tracked.labels[d]}"
                # the disc's centre from its black ring in the luma plane (full resolution: yuv420p keeps
                # the colours at half resolution), against the window's border as the background
                y = luma[y0:y0 + patch.shape[0], x0:x0 + patch.shape[1]]
                ys, xs = np.mgrid[y0:y0 + patch.shape[0], x0:x0 + patch.shape[1]]
                background = np.median(np.concatenate([y[0], y[-1], y[:, 0], y[:, -1]]))
                near = np.hypot(xs - xs[mask].mean(), ys - ys[mask].mean()) < radius + RING_PX + 1.0
                weight = np.abs(background - y) * near
                errors.append(float(np.hypot((weight * xs).sum() / weight.sum() - u,
                                             (weight * ys).sum() / weight.sum() - v)))
                checked[cls] += 1
    assert min(checked.values()) >= 3, checked  # every class seen in several places
    assert max(errors) < 1.0, f"disc centres off their reprojection by up to {max(errors):.2f} px"
    # the missing dot is drawn nowhere: its class colour does not appear where it projected
    grid = _decoded_frames(result.grid)
    assert len(grid) == 3 and grid[0].shape[0] >= frames[0].shape[0] // 2


def test_viewer_html_is_self_contained_and_escapes_names(tracked_capture, tmp_path):
    capture_dir, results = tracked_capture
    hostile = tmp_path / "capture"
    shutil.copytree(capture_dir, hostile)
    capture = Capture.open(hostile)
    capture.rig.cameras[0].name = HOSTILE_CAMERA
    capture.subject["id"] = HOSTILE_SUBJECT
    capture.name = "<b>trial & co</b>"
    capture.save()
    page_path = write_viewer(hostile, results, tmp_path / "view" / VIEWER_NAME)
    page = page_path.read_text()
    assert page.count("<script") == 2 and page.count("</script>") == 2  # the template's own, no injected one
    assert "alert(" not in re.sub(r"\\u003c", "", page.split('id="tape-data">')[0])
    assert "&lt;b&gt;trial &amp; co&lt;/b&gt;" in page
    assert not re.search(r"(src|href)=['\"]?(https?:)?//", page)  # nothing fetched from anywhere
    data = json.loads(page.split('id="tape-data">')[1].split("</script>")[0])
    assert data["cameras"][0]["name"] == HOSTILE_CAMERA and HOSTILE_SUBJECT in data["subtitle"]
    assert len(data["positions"]) == 3 * len(data["labels"]) * 3
    parser = html.parser.HTMLParser()
    parser.feed(page)  # well-formed enough to parse
    assert json.loads(json_for_script({"s": "</script><!--\u2028"})) == {"s": "</script><!--\u2028"}
    assert "<" not in json_for_script({"s": "</script>"})


def _chromium(args: list[str], profile: Path) -> subprocess.CompletedProcess:
    command = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
               "--window-size=900,700", "--force-device-scale-factor=1",
               "--proxy-server=http://127.0.0.1:9", "--proxy-bypass-list=<-loopback>",  # no network reachable
               *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=60)


@pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed (apt-get install chromium)")
def test_viewer_draws_the_tape_in_headless_chromium(tracked_capture, tmp_path):
    from PIL import Image

    capture_dir, results = tracked_capture
    page = write_viewer(capture_dir, results, tmp_path / VIEWER_NAME)
    url = page.as_uri() + "#size=860x520"  # the same canvas in both runs, whatever each viewport is
    dom = _chromium(["--dump-dom", url], tmp_path / "profile1").stdout
    drawn = json.loads(html.unescape(re.search(r'data-drawn="([^"]*)"', dom).group(1)))
    tracked = read_tracked(results, Capture.open(capture_dir).tape)
    assert len(drawn) == int((tracked.classes[0] != DotClass.MISSING).sum())  # every dot of frame 0 drawn
    shot = tmp_path / "shot.png"
    _chromium([f"--screenshot={shot}", url], tmp_path / "profile2")
    image = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    hits = 0
    for _label, x, y, cls in drawn:
        b, g, r = CLASS_COLOURS_BGR[DotClass(cls)]
        patch = image[int(round(y)) - 1:int(round(y)) + 2, int(round(x)) - 1:int(round(x)) + 2]
        hits += bool((np.abs(patch - np.array([r, g, b])).max(axis=2) < 40).any())
    assert hits >= 0.8 * len(drawn), f"{hits} of {len(drawn)} dots show their colour in the screenshot"


def test_view_command_writes_videos_and_viewer(tracked_capture, tmp_path, capsys):
    from spinemocap.cli import main

    capture_dir, results = tracked_capture
    copy = tmp_path / "results"
    shutil.copytree(results, copy)
    assert main(["view", str(capture_dir), str(copy), "--frames", "1:3", "--scale", "0.5"]) == 0
    found = view_outputs(copy)
    assert {"grid", "viewer"} <= set(found) and sum(k.startswith("camera:") for k in found) == 3
    assert len(_decoded_frames(found["grid"])) == 2
    # every 2nd frame: half as many frames, played at half the capture's rate (recorded time)
    assert main(["view", str(capture_dir), str(copy), "--frames", "0:3:2", "--scale", "0.5", "--no-grid"]) == 0
    fps = Capture.open(capture_dir).fps
    for key in (k for k in view_outputs(copy) if k.startswith("camera:")):
        assert len(_decoded_frames(view_outputs(copy)[key])) == 2
        with av.open(str(view_outputs(copy)[key])) as container:
            assert float(container.streams.video[0].average_rate) == pytest.approx(fps / 2)
    out = capsys.readouterr().out
    assert "frames/s" in out and VIEWER_NAME in out
    assert main(["view", str(capture_dir), str(copy), "--frames", "5:9"]) == 2  # no tracked frame there


def test_demo_view_step_writes_where_the_report_links(tracked_capture, tmp_path, capsys):
    from spinemocap.app.batch import discover, trial_out_dir
    from spinemocap.commands.demo import DemoContext, step_view

    capture_dir, results = tracked_capture
    ctx = DemoContext(out=tmp_path, capture_dir=capture_dir)
    shutil.copytree(results, tmp_path / "tracked")
    step_view(ctx)
    (trial,) = discover(capture_dir)
    found = view_outputs(trial_out_dir(tmp_path / "report", trial))
    assert {"grid", "viewer"} <= set(found)
    reported = {path for _, path in ctx.outputs}
    assert set(found.values()) <= reported and all(path.is_file() for path in reported)
    assert str(found["viewer"]) in capsys.readouterr().out


def test_viewer_plays_at_recorded_speed():
    from spinemocap.app.viewer.scene3d import playback_rate

    assert playback_rate(np.arange(0, 50) * 0.02, 50.0) == pytest.approx(50.0)
    assert playback_rate(np.arange(0, 50, 2) * 0.02, 50.0) == pytest.approx(25.0)  # every 2nd frame
    assert playback_rate(np.array([0.3]), 50.0) == 50.0


def test_batch_writes_each_tracked_trials_views_and_the_report_links_them(tracked_capture, tmp_path):
    from spinemocap.app.batch import discover, run_batch, trial_out_dir
    from spinemocap.app.report import write_report

    capture_dir, results = tracked_capture
    study = tmp_path / "study"
    shutil.copytree(capture_dir, study / "S01" / "pre" / "trial01")
    (trial,) = discover(study)
    out = tmp_path / "out"
    shutil.copytree(results, trial_out_dir(out, trial))      # a complete tracked set: not tracked again
    result = run_batch(study, out, workers=1, progress=False, view=True)
    (outcome,) = result.trials
    summary = outcome.summary
    assert summary.status == "ok" and summary.view is not None and summary.view.status == "ok", summary
    found = view_outputs(trial_out_dir(out, trial))
    assert {"grid", "viewer"} <= set(found) and len(found) == 2 + 3   # the grid, the viewer, three cameras
    page = write_report(out)["html"].read_text()
    assert "tape3d.html" in page and "all_cameras.mp4" in page


def test_studio_images_shrink_by_a_whole_factor_and_keep_every_pixel():
    # the default size divides the largest camera by a whole number, to at most AUTO_LONG_SIDE px
    assert auto_scale([(2448, 1600)]) == 0.5 and auto_scale([(1024, 768), (480, 360)]) == 1.0
    assert auto_scale([(640, 480), (3000, 2000)]) == 1 / 3 and 3000 / 3 <= AUTO_LONG_SIDE
    columns, rows, tile = grid_layout(6, (1224, 800))
    assert (columns, rows, tile) == (3, 2, (612, 400)) and columns * tile[0] <= GRID_MAX_WIDTH
    # a shrink by 2 or more averages areas: a one-pixel spot between samples still shows
    image = np.zeros((90, 120, 3), np.uint8)
    image[30, 60] = 255  # a bilinear shrink by 3 samples pixels 1, 4, 7, ... and would miss it
    small = resize_image(image, (40, 30))
    assert small.shape == (30, 40, 3) and small[10, 20, 0] == round(255 / 9) and small.sum() == 3 * small[10, 20, 0]
    assert resize_image(image, (120, 90)).shape == (90, 120, 3)
