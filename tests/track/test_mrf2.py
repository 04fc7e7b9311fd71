"""Image evidence and MRF2 (refinement on the images) on a small rendered scene."""

import cv2
import numpy as np
import pytest

from spinemocap.camera import Camera, Rig
from spinemocap.tape import TapeSpec
from spinemocap.track.config import MRF1Config, MRF2Config
from spinemocap.track.evidence import build_evidence
from spinemocap.track.mrf1 import fit_mrf1
from spinemocap.track.mrf2 import RefinementMRF, TemplateEvidenceScore, refine_mrf2
from spinemocap.track.types import FeasibleSet

TAPE = TapeSpec(n_rows=13).graph


def surface(u, v):
    """Tape on a back curved both ways: runs along +Z, outward normal ~ +Y, subject's right -X."""
    theta, phi = (v - 150) / 600.0, u / 150.0
    return np.stack([-150 * np.sin(phi), -600 * (1 - np.cos(theta)) - 150 * (1 - np.cos(phi)),
                     900 + 600 * np.sin(theta)], axis=-1)


def normal_at(u, v, eps=0.5):
    n = np.cross(surface(u + eps, v) - surface(u - eps, v), surface(u, v + eps) - surface(u, v - eps))
    return n / np.linalg.norm(n)


def rig_behind(size=(640, 480), focal=1000.0):
    target = surface(0.0, 150.0)
    cams = [Camera.look_at(f"cam{i}", target + 1500 * np.array([np.sin(a), np.cos(a), 0.15]), target, size, focal)
            for i, a in enumerate(np.radians([-50, -15, 15, 50]))]
    return Rig(cams)


def _paint(img, cam, outline, value):
    h, w = img.shape
    layer = np.zeros((h, w), np.uint8)
    cv2.fillPoly(layer, [np.round(cam.project(outline) * 16).astype(np.int32)], 255, cv2.LINE_AA, shift=4)
    alpha = layer.astype(np.float32) / 255
    return img * (1 - alpha) + value * alpha


def render(rig, skin=170.0, tape_grey=45.0, dot=205.0, noise=3.0, seed=0):
    """Grey images (dark tape on skin, bright anti-aliased dot holes) and tape masks."""
    spec, rng = TAPE.spec, np.random.default_rng(seed)
    vs = np.linspace(-spec.end_margin_mm, TAPE.uv_mm[:, 1].max() + spec.end_margin_mm, 60)
    half = spec.width_mm / 2
    outline = np.concatenate([surface(-half + 0 * vs, vs), surface(half + 0 * vs, vs)[::-1]])
    ring = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    radius = spec.dot_diameter_mm / 2
    images, masks = [], []
    for cam in rig:
        w, h = cam.size
        img = _paint(np.full((h, w), skin, np.float32), cam, outline, tape_grey)
        mask = np.zeros((h, w), np.uint8)
        cv2.fillPoly(mask, [np.round(cam.project(outline) * 16).astype(np.int32)], 1, cv2.LINE_8, shift=4)
        for u, v in TAPE.uv_mm:
            if (cam.center - surface(u, v)) @ normal_at(u, v) > 0:
                img = _paint(img, cam, surface(u + radius * np.cos(ring), v + radius * np.sin(ring)), dot)
        images.append(np.clip(img + rng.normal(scale=noise, size=img.shape), 0, 255).astype(np.uint8))
        masks.append(mask > 0)
    return images, masks


@pytest.fixture(scope="module")
def scene():
    rig = rig_behind()
    images, masks = render(rig)
    truth = surface(TAPE.uv_mm[:, 0], TAPE.uv_mm[:, 1])
    return rig, images, masks, truth


def test_evidence_is_low_on_dots_high_between_and_grows_off_the_tape(scene):
    rig, images, masks, truth = scene
    cam = rig[1]
    ev = build_evidence(images[1], masks[1], crop_margin_px=None)  # the whole image
    at_dots = ev.sample(cam.project(truth))
    mids = 0.5 * (truth[TAPE.solid_edges[:, 0]] + truth[TAPE.solid_edges[:, 1]])
    between = ev.sample(cam.project(mids))
    assert at_dots.max() < 0.2 and np.median(between) > 0.6
    # a dot's centre is the bottom of its bowl: 2 px away the cost is clearly higher
    assert np.all(ev.sample(cam.project(truth) + [2.0, 0.0]) > at_dots + 0.03)
    # off the tape: above 1 and increasing with the distance to the mask
    centre = cam.project(surface(0.0, 150.0)[None])[0]
    off = ev.sample(np.array([centre + [60.0, 0], centre + [120.0, 0], centre + [200.0, 0]]))
    assert off[0] > 1.0 and off[0] < off[1] < off[2]
    # bilinear sampling reproduces the cost image at pixel centres
    assert ev.sample(np.array([[10.0, 20.0]]))[0] == pytest.approx(ev.cost[20, 10], abs=1e-6)
    # the default crop to the tape's box (+ margin) agrees inside it and is high beyond it
    cropped = build_evidence(images[1], masks[1], crop_margin_px=40)
    assert cropped.cost.size < 0.5 * ev.cost.size
    near = np.concatenate([cam.project(truth), cam.project(mids), [centre + [60.0, 0]]])
    np.testing.assert_allclose(cropped.sample(near), ev.sample(near), atol=1e-5)
    assert cropped.sample(np.array([centre + [200.0, 0]]))[0] >= off[0]


def test_evidence_downscale_keeps_dots(scene):
    rig, images, masks, truth = scene
    half = build_evidence(images[2], masks[2], downscale=0.5, crop_margin_px=None)
    assert half.cost.shape == (images[2].shape[0] // 2, images[2].shape[1] // 2)
    assert np.median(half.sample(rig[2].project(truth))) < 0.2


def test_visibility_uses_the_facing_test(scene):
    rig, images, masks, truth = scene
    front = Camera.look_at("front", surface(0.0, 150.0) + [0, -1500, 200], surface(0.0, 150.0), (640, 480), 1000.0)
    rig5 = Rig(list(rig) + [front])
    evidence = [build_evidence(i, m) for i, m in zip(images, masks)] + [build_evidence(images[0], masks[0])]
    model = RefinementMRF(TAPE, rig5, evidence, MRF2Config())
    model.prepare(truth)
    assert model.visible[:, :4].numpy().all()  # the four cameras behind see every dot
    assert not model.visible[:, 4].numpy().any()  # the camera in front of the subject sees none


def test_mrf2_pulls_perturbed_dots_onto_the_images(scene):
    rig, images, masks, truth = scene
    evidence = [build_evidence(i, m) for i, m in zip(images, masks)]
    start = truth + np.random.default_rng(5).normal(scale=2.0, size=truth.shape)
    start_err = np.linalg.norm(start - truth, axis=1).mean()
    config = MRF2Config(polish=True)
    result = refine_mrf2(start, TAPE, rig, evidence, config, rng=np.random.default_rng(0))
    err = np.linalg.norm(result.positions - truth, axis=1)
    pbp_err = np.linalg.norm(result.extra["pbp_positions"] - truth, axis=1)
    assert start_err > 2.5
    assert pbp_err.mean() < 0.5 * start_err  # particle BP alone
    assert err.mean() < 0.8 and err.max() < 2.0  # with the continuous polish
    hist = np.array(result.energy_history)
    n_pbp = config.iterations + 1
    assert np.all(hist[1:n_pbp] <= np.array(result.extra["energy_baselines"]))
    assert np.all(np.diff(hist[n_pbp:]) <= 0)
    assert hist[-1] < hist[0]
    assert result.extra["visible"].shape == (TAPE.n_dots, 4)


def test_mrf2_rejects_mismatched_evidence(scene):
    rig, images, masks, truth = scene
    with pytest.raises(ValueError, match="evidence images for 4 cameras"):
        refine_mrf2(truth, TAPE, rig, [None, None])


def test_mrf2_reports_skin_points_under_the_tape(scene):
    rig, images, masks, truth = scene
    evidence = [build_evidence(i, m) for i, m in zip(images, masks)]
    thick_tape = TapeSpec(n_rows=13, thickness_mm=0.8).graph
    config = MRF2Config(iterations=0)  # no search: only the offset acts
    result = refine_mrf2(truth, thick_tape, rig, evidence, config)
    shift = result.positions - truth
    np.testing.assert_allclose(np.linalg.norm(shift, axis=1), 0.8, atol=1e-9)
    assert np.all(shift[:, 1] < -0.75)  # inward: against the outward normal (+Y here)


def test_template_evidence_score_breaks_the_two_row_tie(scene):
    rig, images, masks, truth = scene
    evidence = [build_evidence(i, m) for i, m in zip(images, masks)]
    score = TemplateEvidenceScore(rig, evidence, TAPE)
    u, v = TAPE.uv_mm[:, 0], TAPE.uv_mm[:, 1]
    shifted = [surface(u, v + 50.0), surface(u, v - 50.0)]  # same dot pattern, two rows along
    costs = score(np.stack([truth] + shifted))
    assert costs[0] < 0.5 * costs[1:].min()
    # MRF1 on a feasible set missing both ends of the tape (rows 1-3 and 11-13) places it right
    # only with the images' help
    middle = (TAPE.row >= 3) & (TAPE.row <= 9)
    fs = FeasibleSet(points=truth[middle], normals=np.tile([0.0, 1.0, 0.0], (middle.sum(), 1)),
                     edges=np.zeros((0, 2), int), source_index=np.arange(middle.sum()), n_target=0,
                     n_target_initial=0)
    helped = fit_mrf1(fs, TAPE, MRF1Config(), up=np.array([0, 0, 1.0]), template_score=score)
    assert np.linalg.norm(helped.positions - truth, axis=1)[middle].max() < 2.0


def test_mrf2_holds_dots_that_no_view_informs(scene):
    rig, images, masks, truth = scene
    # every view at the cost cap (as behind an occluder): no dot is seen, each stays at its start
    blank = [build_evidence(np.zeros_like(i), m) for i, m in zip(images, masks)]
    start = truth + np.random.default_rng(1).normal(scale=1.0, size=truth.shape)
    held = refine_mrf2(start, TAPE, rig, blank, MRF2Config(), rng=np.random.default_rng(0))
    assert not held.extra["visible"].any()
    assert np.linalg.norm(held.positions - start, axis=1).mean() < 0.3
    free = refine_mrf2(start, TAPE, rig, blank, MRF2Config(anchor_unseen=0.0), rng=np.random.default_rng(0))
    assert np.linalg.norm(free.positions - start, axis=1).mean() > 0.6  # the shape terms alone let them drift
