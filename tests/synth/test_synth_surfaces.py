"""The studio's tape rolls and finishes, skin marks, clothing, rolling shutter and H.265: each
changes the render where it should, is seeded, and keeps the tape mask and the ground truth
consistent with what is drawn."""

import cv2
import numpy as np
import pytest

from spinemocap.capture import Capture
from spinemocap.commands.synth import (
    CLOTHING_NAMES,
    CODEC_NAMES,
    SKIN_MARK_NAMES,
    TAPE_FINISH_NAMES,
    TAPE_ROLL_NAMES,
)
from spinemocap.synth import SynthConfig, build_scene, write_capture
from spinemocap.synth.appearance import CODECS, TAPE_ROLLS, CameraLook, camera_looks, lab_subject, video_frame
from spinemocap.synth.occluders import CLOTHING_ITEMS
from spinemocap.synth.shutter import exposed, row_weights
from spinemocap.synth.surfaces import SKIN_MARKS, TAPE_FINISHES, skin_texture, tape_texture

BASE = {"frames": 1, "seed": 21, "noise": 0.0, "rows": 13}


def _render(**options):
    scene = build_scene(SynthConfig.preset("tiny", **BASE, **options))
    rendered, gt = scene.render(0), scene.frame_groundtruth(0)
    scene.close()
    return rendered, gt, scene


@pytest.fixture(scope="module")
def plain():
    return _render()


def _grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(float)


def _near(mask: np.ndarray, px: int = 2) -> np.ndarray:
    return cv2.dilate(mask.astype(np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)).astype(bool)


def _assert_same_truth(gt: dict, truth: dict) -> None:
    for name in truth:
        np.testing.assert_array_equal(np.asarray(gt[name]), np.asarray(truth[name]), err_msg=name)


def test_the_command_line_offers_the_studios_vocabularies():
    assert TAPE_ROLL_NAMES == tuple(TAPE_ROLLS) and TAPE_FINISH_NAMES == TAPE_FINISHES
    assert SKIN_MARK_NAMES == SKIN_MARKS and CLOTHING_NAMES == CLOTHING_ITEMS and CODEC_NAMES == CODECS
    for bad in ({"tape_roll": "huge"}, {"tape_finish": "glitter"}, {"skin_marks": ("scales",)},
                {"clothing": ("hat",)}, {"rolling_shutter_ms": -1.0}, {"camera_codec": "vp9"}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            SynthConfig(**bad)
    assert SynthConfig(skin_marks=("tattoo", "hair", "hair")).skin_marks == ("hair", "tattoo")


def test_a_roll_sets_the_tape_spec_the_capture_gives_the_tracker(tmp_path, plain):
    for roll, (diameter, pitch, columns) in TAPE_ROLLS.items():
        spec = build_scene(SynthConfig.preset("tiny", **BASE, tape_roll=roll)).tape
        assert (spec.dot_diameter_mm, spec.row_pitch_mm, spec.column_spacing_mm) == (diameter, pitch, columns)
    out = write_capture(SynthConfig.preset("tiny", **BASE, tape_roll="wide_rows", realism="ideal"), tmp_path / "c",
                        progress=False)
    tape = Capture.open(out).tape
    assert (tape.row_pitch_mm, tape.column_spacing_mm) == (30.0, 16.0)
    gt = np.load(out / "groundtruth.npz")
    # the rendered dots lie the roll's pitch apart (no tension, no skin strain at the ideal level)
    np.testing.assert_allclose(gt["row_spacing_mm"], 30.0, rtol=0.03)


def _hole_pixels(rendered) -> int:
    """Skin-bright pixels inside the tape's silhouette: the holes."""
    return sum(int((m & (_grey(im) > 100)).sum()) for im, m in zip(rendered.images, rendered.masks))


def test_small_holes_show_half_the_skin(plain):
    small, _, _ = _render(tape_roll="small_holes")
    ratio = _hole_pixels(small) / _hole_pixels(plain[0])
    assert 0.3 < ratio < 0.7  # (7 mm / 10 mm)^2 = 0.49, rim pixels blur it


@pytest.mark.parametrize("finish", ["weave", "printed"])
def test_a_tape_finish_changes_only_the_tape(plain, finish):
    rendered, gt, _ = _render(tape_finish=finish)
    base, truth, _ = plain
    _assert_same_truth(gt, truth)
    changed_total = 0
    for image, mask, base_image, base_mask in zip(rendered.images, rendered.masks, base.images, base.masks):
        np.testing.assert_array_equal(mask, base_mask)
        differs = np.any(image != base_image, axis=2)
        assert not (differs & ~_near(mask)).any()  # nothing changes off the tape
        tape = mask & (_grey(base_image) < 60)  # the tape's own surface (not its holes)
        changed_total += int((differs & tape).sum())
        spread = _grey(image)[tape].std() - _grey(base_image)[tape].std()
        assert spread > 1.0, finish  # a smooth black tape becomes textured
    assert changed_total > 0


def test_finish_textures_are_seeded_and_distinct():
    args = ((0.1, 0.3, 0.7), 50.0, (-12.5, 312.5))
    weave = tape_texture("weave", *args, seed=4)
    assert weave is not None and tape_texture("smooth", *args, seed=4) is None
    np.testing.assert_array_equal(weave.image, tape_texture("weave", *args, seed=4).image)
    assert np.any(weave.image != tape_texture("weave", *args, seed=5).image)
    printed = tape_texture("printed", *args, seed=4)
    assert printed is not None and printed.image.shape == weave.image.shape
    # printed ink contrasts with the blue tape: a share of the texels far from its colour
    far = np.abs(printed.image.astype(float) - np.array([25, 76, 184])).sum(axis=2) > 150
    assert 0.02 < far.mean() < 0.8
    with pytest.raises(ValueError, match="tape finish"):
        tape_texture("glitter", *args, seed=4)


def test_each_skin_mark_paints_the_skin_darker_and_is_seeded():
    extent = ((-320.0, 320.0), (634.0, 1529.0))
    skin = (0.85, 0.68, 0.55)
    plain_value = np.array(skin) * 255
    for mark in ("hair", "freckles", "moles", "tattoo"):
        texture = skin_texture((mark,), skin, extent, 0.0, seed=3)
        assert texture is not None, mark
        delta = texture.image.astype(float) - plain_value
        marked = np.abs(delta).sum(axis=2) > 20
        assert marked.any() and delta[marked].mean() < 0, mark  # marks are darker than the skin
        np.testing.assert_array_equal(texture.image, skin_texture((mark,), skin, extent, 0.0, seed=3).image)
        assert np.any(texture.image != skin_texture((mark,), skin, extent, 0.0, seed=4).image), mark
    assert skin_texture(("sweat",), skin, extent, 0.0, seed=3) is None  # a sheen, not a picture
    with pytest.raises(ValueError, match="skin marks"):
        skin_texture(("scales",), skin, extent, 0.0, seed=3)


def test_skin_marks_change_the_skin_and_show_through_the_holes_only(plain):
    rendered, gt, _ = _render(skin_marks=("hair", "freckles", "moles", "tattoo"))
    base, truth, _ = plain
    _assert_same_truth(gt, truth)
    for image, mask, base_image, base_mask in zip(rendered.images, rendered.masks, base.images, base.masks):
        np.testing.assert_array_equal(mask, base_mask)
        grey, base_grey = _grey(image), _grey(base_image)
        body = (base_grey != base_grey[0, 0]) & ~_near(mask)
        assert grey[body].mean() < base_grey[body].mean() - 1  # the marks darken the skin
        # the tape's own surface keeps its pixels (its holes show the marked skin)
        tape_surface = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & (base_grey < 40)
        tape_surface &= ~_near(base_grey >= 40, 1)
        np.testing.assert_array_equal(image[tape_surface], base_image[tape_surface])


def test_sweat_puts_a_sheen_on_the_skin(plain):
    rendered, gt, _ = _render(skin_marks=("sweat",))
    base, truth, _ = plain
    _assert_same_truth(gt, truth)
    for image, mask, base_image, base_mask in zip(rendered.images, rendered.masks, base.images, base.masks):
        np.testing.assert_array_equal(mask, base_mask)
        base_grey = _grey(base_image)
        body = (base_grey != base_grey[0, 0]) & ~_near(mask)
        assert np.percentile(_grey(image)[body], 99.5) > np.percentile(base_grey[body], 99.5) + 3


def test_clothing_hides_the_tape_in_the_images_masks_and_visibility_alike(plain):
    rendered, gt, scene = _render(clothing=("shorts", "bra_strap"))
    base, truth, _ = plain
    assert scene.band is not None and scene.band.colours is not None
    hidden = truth["visible"] & ~gt["visible"]
    assert hidden.any() and not (gt["visible"] & ~truth["visible"]).any()  # the strap crosses the tape
    for c, (image, mask, base_image, base_mask) in enumerate(zip(rendered.images, rendered.masks, base.images,
                                                                  base.masks)):
        assert not (mask & ~base_mask).any()  # clothing only hides tape
        uv = np.round(gt["uv"][c]).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < mask.shape[1]) & (uv[:, 1] >= 0) & (uv[:, 1] < mask.shape[0])
        at_dots = np.zeros(len(uv), bool)
        at_dots[inside] = mask[uv[inside, 1], uv[inside, 0]]
        assert not at_dots[hidden[c]].any()  # a dot the truth calls hidden has no tape in the mask
        assert at_dots[gt["visible"][c] & inside].all()  # a visible one has
        assert np.any(image != base_image, axis=2).mean() > 0.05  # the garments are drawn
    again, _, _ = _render(clothing=("shorts", "bra_strap"))
    for image, other in zip(rendered.images, again.images):
        np.testing.assert_array_equal(image, other)


# ---------------------------------------------------------------------------------- rolling shutter
def test_row_weights_interpolate_in_time_and_sum_to_one():
    instants = np.array([0.0, 0.01, 0.02])
    w = row_weights(instants, np.array([0.0, 0.005, 0.02]), 0.0)
    np.testing.assert_allclose(w, [[1, 0, 0], [0.5, 0.5, 0], [0, 0, 1]])
    blurred = row_weights(instants, np.array([0.01]), 0.02)
    np.testing.assert_allclose(blurred.sum(axis=1), 1.0)
    assert blurred[0, 1] > blurred[0, 0] > 0
    images = [np.full((3, 2, 3), v, np.uint8) for v in (0, 100, 200)]
    rgb, mask = exposed(images, [np.zeros((3, 2), bool), np.ones((3, 2), bool), np.ones((3, 2), bool)], w)
    np.testing.assert_allclose(rgb[:, 0, 0], [0, 50, 200])
    np.testing.assert_array_equal(mask[:, 0], [False, True, True])


def _hole_centres(image: np.ndarray, mask: np.ndarray, near_uv: np.ndarray) -> np.ndarray:
    """(N, 2) px: for each of ``near_uv`` (N, 2) the centroid of the bright hole inside the tape's
    silhouette nearest to it."""
    holes = (mask & (_grey(image) > 100)).astype(np.uint8)
    n, _, stats, centres = cv2.connectedComponentsWithStats(holes)
    centres = centres[1:][stats[1:, cv2.CC_STAT_AREA] >= 4]
    return centres[np.linalg.norm(centres[:, None] - near_uv[None], axis=2).argmin(axis=0)]


def test_a_rolling_shutter_shears_the_image_and_the_truth_follows_it():
    """A fast swing (forehand, 100 fps) through a 20 ms readout: the dots move by pixels from
    where a global shutter sees them (rows above the middle one way, below the other), and the
    truth moves as the image's holes do."""
    config = {"frames": 50, "fps": 100.0, "seed": 5, "noise": 0.0, "motion": "forehand", "cameras": 2}
    results = {}
    for readout in (0.0, 20.0):
        scene = build_scene(SynthConfig.preset("tiny", **config, rolling_shutter_ms=readout))
        results[readout] = (scene.render(42), scene.frame_groundtruth(42))
        scene.close()
    (still, still_gt), (rolling, rolling_gt) = results[0.0], results[20.0]
    for name in ("dots", "visible"):
        np.testing.assert_array_equal(rolling_gt[name], still_gt[name])
    for c in range(2):
        assert np.any(rolling.masks[c] != still.masks[c])
        seen = still_gt["visible"][c]
        uv = still_gt["uv"][c][seen]
        truth_shift = rolling_gt["uv"][c][seen] - uv
        image_shift = (_hole_centres(rolling.images[c], rolling.masks[c], uv)
                       - _hole_centres(still.images[c], still.masks[c], uv))
        assert np.linalg.norm(truth_shift, axis=1).max() > 1.5
        assert np.median(np.linalg.norm(image_shift - truth_shift, axis=1)) < 0.3
        assert np.percentile(np.linalg.norm(image_shift - truth_shift, axis=1), 90) < 0.6


# ---------------------------------------------------------------------------------- H.265
def test_h265_codes_the_frame_like_a_sports_camera():
    image = np.full((120, 160, 3), 150, np.uint8)
    image[30:90, 60:100] = 30
    for y in (40, 60, 80):
        cv2.circle(image, (80, y), 5, (200, 190, 180), -1)
    h265 = CameraLook(codec="h265", bitrate_mbps=2.0, fps=30.0).apply(image, 0.0)
    h264 = CameraLook(codec="h264", bitrate_mbps=2.0, fps=30.0).apply(image, 0.0)
    assert h265.shape == image.shape and np.abs(h265.astype(float) - image).mean() < 6.0
    assert np.any(h265 != image) and np.any(h265 != h264)
    with pytest.raises(ValueError, match="video codec"):
        video_frame(image, "vp9", 2.0, 30.0)
    looks = camera_looks("ideal", 3, 0, 100.0, readout_ms=12.0, codec="h265")
    assert looks is not None and all(look.codec == "h265" and look.chroma_420 and look.readout_ms == 12.0
                                     for look in looks)


def test_the_lab_subject_mix_covers_every_option():
    drawn = [lab_subject(np.random.default_rng([k, 79])) for k in range(80)]
    assert {d["tape_roll"] for d in drawn} == set(TAPE_ROLLS)
    assert {d["tape_finish"] for d in drawn} == set(TAPE_FINISHES)
    assert set().union(*(d["skin_marks"] for d in drawn)) == set(SKIN_MARKS)
    assert set().union(*(d["clothing"] for d in drawn)) == set(CLOTHING_ITEMS)
    rolls = [d["tape_roll"] for d in drawn]
    assert max(set(rolls), key=rolls.count) == "standard"
