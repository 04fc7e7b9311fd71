"""Synthetic studio: projection of the renders, ground truth vs pixels, tape binding, occlusion
levels against the paper's Table 2, settings validation, determinism, the capture folder."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.bench.synth import PAPER_TABLE2, views_histogram
from spinemocap.camera import Camera
from spinemocap.capture import Capture, FrameSource
from spinemocap.skin import vertex_normals
from spinemocap.synth import SynthConfig, build_scene, write_capture
from spinemocap.synth.tape_on_skin import KEYPOINT_NAMES


@pytest.fixture(scope="module")
def occluded_scene():
    """Tiny rig, 7-row tape, a sports-bra band over the upper rows and plenty of balls."""
    config = SynthConfig.preset("tiny", frames=3, rows=7, band=True, band_level="T12", balls=2500,
                                skin_tone=0.2, seed=3)
    scene = build_scene(config)
    yield scene
    scene.close()


# ---------------------------------------------------------------------- rendering geometry
def test_render_projection_matches_camera_model():
    """Small unlit spheres at known 3D points land where Camera.project puts them (< 0.5 px),
    with an off-centre principal point, fx != fy and lens distortion."""
    import pyvista as pv

    from spinemocap.synth.render import Appearance, CameraRenderer

    cam = Camera.look_at("c", (300, 2000, 1300), (0, 0, 1100), (640, 480), 900.0,
                         dist=(-0.15, 0.05, 0.001, -0.0008, 0), principal_point=(331.3, 229.6))
    cam.K[1, 1] = 915.0
    tri = np.array([[0, 1, 2]])
    renderer = CameraRenderer(cam, tri, tri, tri, Appearance(skin_rgb=(0.8, 0.6, 0.5), background_rgb=(0, 0, 0)))
    renderer.body.points = np.array([[0, -9000, 0], [1, -9000, 0], [0, -9000, 1.0]])
    renderer.tape.points = renderer.body.points
    points = np.array([[0, 0, 1100], [200, 0, 1300], [-250, 100, 900], [150, -100, 1000], [-420, 0, 1480]], float)
    for p in points:
        renderer.plotter.add_mesh(pv.Sphere(radius=4.0, center=p, theta_resolution=40, phi_resolution=40),
                                  color="white", ambient=1.0, diffuse=0.0, specular=0.0)
    gray = renderer.snapshot().astype(float).sum(axis=2)
    renderer.close()
    expected = cam.project(points)
    for uv in expected:
        x0, y0 = int(round(uv[0])), int(round(uv[1]))
        yy, xx = np.mgrid[y0 - 8 : y0 + 9, x0 - 8 : x0 + 9]
        window = gray[y0 - 8 : y0 + 9, x0 - 8 : x0 + 9]
        assert window.sum() > 0, f"no sphere rendered near {uv}"
        centroid = np.array([(window * xx).sum(), (window * yy).sum()]) / window.sum()
        assert np.linalg.norm(centroid - uv) < 0.5, (centroid, uv)
    # the distortion is not negligible: ignoring it would miss by pixels at the far point
    assert np.linalg.norm(cam.project(points[-1:], distort=False) - expected[-1]) > 2.0


def test_visible_dots_are_bright_blobs_in_the_tape_and_occluded_ones_are_not(occluded_scene):
    scene = occluded_scene
    frame = 2
    gt = scene.frame_groundtruth(frame)
    rendered = scene.render(frame)
    assert gt["visible"].any() and (~gt["visible"]).any(), "scene must have visible and occluded dots"
    import cv2

    from spinemocap.synth.occluders import segments_blocked_by_spheres
    from spinemocap.synth.visibility import rim_points

    # a ball over part of a dot (centre seen, 2+ rim points hidden) counts as occluded: the centre
    # pixel cannot tell, so such dots are left out
    tape = scene.posed_tape(frame)
    samples = np.concatenate([gt["dots"][:, None], rim_points(gt["dots"], tape.dot_normals(), 5.0)], axis=1)
    centres, radii = scene.balls.at(scene.times[frame])
    n_checked = 0
    for c, (image, mask) in enumerate(zip(rendered.images, rendered.masks)):
        gray = cv2.blur(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(float), (3, 3))
        cam_centre = np.repeat(scene.rig[c].center[None], samples.size // 3, axis=0)
        hidden = segments_blocked_by_spheres(cam_centre, samples.reshape(-1, 3), centres, radii).reshape(-1, 5)
        partial = ~hidden[:, 0] & (hidden[:, 1:].sum(axis=1) >= 2)
        for d, (u, v) in enumerate(gt["uv"][c]):
            if not scene.rig[c].in_image(np.array([[u, v]]), margin=3)[0] or partial[d]:
                continue
            x, y = int(round(u)), int(round(v))
            blob = gray[y, x] > 80 and mask[y, x]  # a bright hole inside the tape's silhouette
            assert blob == gt["visible"][c, d], (scene.rig[c].name, scene.labels[d], gray[y, x], mask[y, x])
            n_checked += 1
    assert n_checked >= 3 * scene.tape.n_dots * 0.75


def test_tape_masks_cover_visible_dots_and_tape_is_dark(occluded_scene):
    rendered = occluded_scene.render(0)
    gt = occluded_scene.frame_groundtruth(0)
    for c, (image, mask) in enumerate(zip(rendered.images, rendered.masks)):
        assert mask.dtype == bool and mask.shape == image.shape[:2]
        assert 0.002 < mask.mean() < 0.2
        uv = np.round(gt["uv"][c][gt["visible"][c]]).astype(int)
        assert mask[uv[:, 1], uv[:, 0]].all()
        tape_gray = image[mask].mean()
        assert tape_gray < image[~mask].mean()


def test_mask_rendered_around_the_tape_equals_a_full_canvas_mask(occluded_scene, monkeypatch):
    renderer = occluded_scene.renderers[1]
    meshes = occluded_scene.meshes(1)
    cropped = renderer._render_mask(meshes)
    assert renderer._mask_size[0] < renderer.canvas_size[0]  # the mask window really is smaller
    monkeypatch.setattr(renderer, "_tape_region", lambda tape_vertices: (0, 0, *renderer.canvas_size))
    full = renderer._render_mask(meshes)
    assert cropped.sum() > 500
    np.testing.assert_array_equal(cropped, full)


# ---------------------------------------------------------------------- tape on skin
def test_tape_rest_spacing_matches_spec_and_stretches_plausibly_in_motion():
    from spinemocap.synth.scene import cached_tape_on_skin

    tos = cached_tape_on_skin((), 13, "L4")
    body, graph = tos.body, tos.spec.graph
    solid = graph.edges[graph.solid]

    def ratios(vertices):
        p = tos.dot_positions(vertices)
        return np.linalg.norm(p[solid[:, 0]] - p[solid[:, 1]], axis=1) / graph.rest_length_mm[graph.solid]

    rest = ratios(body.rest_vertices)
    assert np.abs(rest - 1).max() < 0.03, rest
    posed, applied = body.pose(np.array([[40.0, 0, 0], [0, 30.0, 0], [0, 0, 35.0]]))
    np.testing.assert_allclose(applied, [[40, 0, 0], [0, 30, 0], [0, 0, 35]], atol=4.0)
    for vertices in posed:
        r = ratios(vertices)
        assert 0.9 < r.min() and r.max() < 1.15, (r.min(), r.max())  # skin stretch: a few %
        assert np.abs(r - rest).max() > 0.005  # the tape really deforms with the skin
    # the dots lie on the back and the tape runs up the spine from the start level
    p = tos.dot_positions(body.rest_vertices)
    row_height = np.array([p[graph.row == r, 2].mean() for r in range(13)])
    assert np.all(p[:, 1] > 0) and np.all(np.diff(row_height) > 15)
    assert np.abs(p[:, 0]).max() < 20  # centred on the midline (dots at -15, 0, +15 mm)
    assert tos.row_levels[0] == "L4" and tos.row_levels[-1].startswith("T")


def test_applied_angles_follow_motion_signs():
    from spinemocap.synth.scene import cached_body

    body = cached_body(())
    posed, applied = body.pose(np.array([[0.0, 0, 0], [30.0, 0, 0], [0, 25.0, 0], [0, 0, 30.0]]))
    head = np.argmax(body.rest_vertices[:, 2])
    moved = posed[:, head] - posed[0, head]
    assert moved[1, 1] < -100  # flexion: head forward (-Y)
    assert moved[2, 0] < -100  # lateral bending to the right (-X)
    shoulder = np.argmax(body.rest_vertices[:, 0] * (body.rest_vertices[:, 2] > 1300))  # left shoulder, +X
    # axial rotation to the left (counter-clockwise from above): the left shoulder swings back (+Y)
    assert posed[3, shoulder, 1] - posed[0, shoulder, 1] > 30
    np.testing.assert_allclose(applied[0], 0, atol=1e-6)


# ---------------------------------------------------------------------- occlusion
def test_artificial_rig_sees_every_dot_without_occluders():
    scene = build_scene(SynthConfig.preset("artificial", frames=55, fps=10.0))
    visible = scene.groundtruth["visible"]
    assert visible.shape == (55, 4, 32)
    assert visible.all()


@pytest.mark.parametrize("level", ["light", "heavy"])
def test_occlusion_levels_reproduce_table2_shares(level):
    """The whole 5.48 s of the paper's sequence sampled at 25 fps (visibility only, no render)."""
    scene = build_scene(SynthConfig.preset("artificial", fps=25.0, frames=137, occlusion=level))
    counts = views_histogram(scene.groundtruth["visible"])
    share = counts / counts.sum() * 100
    paper = PAPER_TABLE2[level] / PAPER_TABLE2[level].sum() * 100
    assert np.abs(share - paper).max() < 3.0, (share.round(1), paper.round(1))


# ---------------------------------------------------------------------- settings
@pytest.mark.parametrize(
    "overrides, message",
    [
        (dict(rows=0), "rows must be odd"),
        (dict(rows=4), "rows must be odd"),
        (dict(frames=0), "frames"),
        (dict(motion="moonwalk"), "unknown motion"),
        (dict(occlusion="extreme"), "unknown occlusion"),
        (dict(tape_start="X9"), "vertebral level"),
        (dict(phenotype={"age": 2.0}), "phenotype"),
        (dict(tape_tension=1.5), "tape_tension must lie"),
        (dict(calibration_error_px=-1.0), "calibration_error_px must lie"),
        (dict(sync_error_ms=-1.0), "sync_error_ms must lie"),
        (dict(skin_strain=-1.0), "skin_strain"),
    ],
)
def test_impossible_settings_raise_clear_errors(overrides, message):
    with pytest.raises(ValueError, match=message):
        SynthConfig.preset("tiny", **overrides)


def test_unknown_preset_and_blind_rig_raise():
    with pytest.raises(ValueError, match="unknown preset"):
        SynthConfig.preset("hollywood")
    with pytest.raises(ValueError, match="unknown synthetic studio settings"):
        SynthConfig.preset("tiny", colour="red")
    # two cameras at the ends of the studio's 180 degree arc look at the subject's flanks
    with pytest.raises(ValueError, match="no camera sees the tape"):
        build_scene(SynthConfig.preset("studio", cameras=2, frames=1, size=(320, 200)))
    with pytest.raises(ValueError, match="does not fit"):
        build_scene(SynthConfig.preset("tiny", rows=31, frames=1))


# ---------------------------------------------------------------------- determinism and output
def test_same_seed_same_capture_other_seed_differs():
    a = build_scene(SynthConfig.preset("tiny", frames=2, balls=300, seed=5))
    b = build_scene(SynthConfig.preset("tiny", frames=2, balls=300, seed=5))
    c = build_scene(SynthConfig.preset("tiny", frames=2, balls=300, seed=6))
    for key in ("dots", "uv", "visible"):
        np.testing.assert_array_equal(a.groundtruth[key], b.groundtruth[key])
    img_a, img_b, img_c = a.render(1).images[0], b.render(1).images[0], c.render(1).images[0]
    np.testing.assert_array_equal(img_a, img_b)
    assert not np.array_equal(img_a, img_c)
    assert not np.allclose(a.rig[0].K, c.rig[0].K)
    for s in (a, b, c):
        s.close()


def test_write_capture_opens_with_capture_and_groundtruth_has_documented_shapes(tmp_path):
    config = SynthConfig.preset("tiny", frames=2, balls=100)
    out = write_capture(config, tmp_path / "cap", progress=False)
    capture = Capture.open(out)
    assert capture.n_frames == 2 and capture.fps == config.fps and len(capture.rig) == 3
    # the default tape starts at S1 and passes the T12/L1 junction by two rows (9 rows on this body)
    assert capture.tape.n_rows == 9 and capture.subject["tape_start"] == "S1"
    np.testing.assert_allclose(capture.up, [0, 0, 1])
    assert capture.subject["facing"] == [0.0, -1.0, 0.0]
    images = capture.frame_source().read(1)
    assert len(images) == 3 and images[0].shape == (360, 480, 3) and images[0].dtype == np.uint8
    assert (out / "masks" / "cam2" / "000001.png").is_file()
    gt = np.load(out / "groundtruth.npz")
    F, C, D = 2, 3, 22
    assert list(gt["labels"]) == capture.tape.labels
    assert gt["dots"].shape == (F, D, 3) and gt["dot_normals"].shape == (F, D, 3)
    assert gt["visible"].shape == (F, C, D) and gt["visible"].dtype == bool
    assert gt["uv"].shape == (F, C, D, 2)
    assert gt["angles_deg"].shape == (F, 3) and list(gt["angle_names"]) == ["flexion", "lateral_bending", "axial_rotation"]
    assert gt["keypoints"].shape == (F, 8, 3) and gt["row_levels"].shape == (9,) and gt["row_levels"][0] == "S1"
    assert gt["row_stretch"].shape == (F, 8) and gt["width_stretch"].shape == (F, 9)
    assert gt["rig_R"].shape == (C, 3, 3) and gt["sync_offset_s"].shape == (C,)
    assert float(gt["fps"]) == config.fps
    # uv is the camera model's projection of the dots (distorted pixels)
    np.testing.assert_allclose(gt["uv"][1], capture.rig.project(gt["dots"][1]), atol=1e-6)
    assert list(gt["keypoint_names"]) == list(KEYPOINT_NAMES)


def test_keypoints_are_back_landmarks_left_and_right_of_the_spine(occluded_scene):
    """Hips, waist, shoulder-blade angles, shoulders: on the back skin, paired left (+X) and right
    (-X) of the spine at their anatomical heights, and they move with the body."""
    body, tos = occluded_scene.body, occluded_scene.tape_on_skin
    rest = tos.keypoints.points(body.rest_vertices, body.faces)
    levels = body.level_heights()
    left, right = rest[0::2], rest[1::2]
    np.testing.assert_allclose(left[:, [1, 2]], right[:, [1, 2]], atol=2.0)  # anny is symmetric
    assert np.all(left[:, 0] > 60) and np.all(right[:, 0] < -60)
    np.testing.assert_allclose(left[:, 2], [body.rest_bone_heads["upperleg01.L"][2], levels["L1"], levels["T7"],
                                            body.rest_bone_heads["shoulder01.L"][2]], atol=1.0)
    # on the back: the skin there faces backwards (+Y), and the points are on the skin surface
    normals = tos.keypoints.normals(vertex_normals(body.rest_vertices, body.faces), body.faces)
    assert np.all(normals[:, 1] > 0.3)
    assert np.all(rest[:, 1] > body.rest_bone_heads["spine03"][1])
    # bound to the skin: the ground truth follows the posed body
    gt = occluded_scene.frame_groundtruth(2)
    v, _ = occluded_scene._posed(2)
    np.testing.assert_allclose(gt["keypoints"], tos.keypoints.points(v, body.faces))
    assert gt["keypoints"].shape == (8, 3)


def test_frame_source_renders_in_process(occluded_scene):
    source = occluded_scene.frame_source()
    assert isinstance(source, FrameSource)
    assert source.camera_names == occluded_scene.rig.names and source.n_frames == 3
    images = source.read(1)
    np.testing.assert_array_equal(images[0], occluded_scene.render(1).images[0])
    with pytest.raises(IndexError):
        source.read(3)


def test_cli_synth_writes_capture_and_reports_bad_settings(tmp_path, capsys):
    from spinemocap.cli import main

    assert main(["synth", str(tmp_path / "c"), "--preset", "tiny", "--frames", "1", "--size", "320x240",
                 "--no-progress"]) == 0
    assert Capture.open(tmp_path / "c").rig[0].size == (320, 240)
    assert main(["synth", str(tmp_path / "d"), "--rows", "0"]) == 2
    assert "rows must be odd" in capsys.readouterr().err


def test_video_capture_round_trips_losslessly(tmp_path):
    config = SynthConfig.preset("tiny", frames=2, size=(320, 240), video=True, noise=0.0)
    out = write_capture(config, tmp_path / "v", progress=False)
    capture = Capture.open(out)
    assert capture.media == "video" and (out / "videos" / "cam1.avi").is_file()
    assert not (out / "images").exists()
    frames = capture.frame_source().read(1)
    scene = build_scene(config)
    np.testing.assert_array_equal(frames[2], scene.render(1).images[2])  # FFV1 is lossless
    scene.close()


def test_demo_synthesis_step_reports_a_readable_capture(tmp_path, capsys):
    from spinemocap.commands.demo import DemoContext, step_synthesize

    ctx = DemoContext(out=tmp_path, quick=True)
    step_synthesize(ctx)
    capture = Capture.open(ctx.capture_dir)
    assert capture.n_frames == 4 and len(capture.rig) == 4
    assert all(path.exists() for _, path in ctx.outputs)
    assert str(ctx.capture_dir / "groundtruth.npz") in capsys.readouterr().out


def test_motions_start_neutral_and_have_their_character():
    from spinemocap.synth.motions import MOTIONS, spine_motion

    t = np.arange(0, 6.0, 0.01)
    for name in MOTIONS:
        np.testing.assert_allclose(spine_motion(name, [0.0])[0], 0.0, atol=1e-9)
    peak = {name: np.abs(spine_motion(name, t)).max(axis=0) for name in MOTIONS}
    assert peak["flexion"][0] > 40 and peak["flexion"][1:].max() == 0
    assert peak["lateral"][1] > 25 and peak["rotation"][2] > 30
    assert (peak["mixed"] > 20).all()  # all three planes at once, large amplitude
    speed = np.abs(np.diff(spine_motion("forehand", t)[:, 2])) / 0.01
    assert speed.max() > 500  # deg/s: a fast axial swing
    with pytest.raises(ValueError, match="unknown motion"):
        spine_motion("moonwalk", t)


def test_impossible_tape_starts_are_refused_with_the_reason():
    """A start is refused only when the tape cannot be laid: too long for the back above it."""
    with pytest.raises(ValueError, match=r"starting at T6 does not fit on the back.*use fewer rows"):
        build_scene(SynthConfig.preset("tiny", rows=13, tape_start="T6", frames=1))
