"""The studio's appearance options: tape colours and painted lab rooms behind the subject; each
changes the render as specified and keeps the tape mask and the ground truth exact."""

import cv2
import numpy as np
import pytest

from spinemocap.commands.synth import BACKDROP_NAMES, TAPE_COLOUR_NAMES
from spinemocap.synth import SynthConfig, build_scene
from spinemocap.synth.appearance import BACKDROPS, TAPE_COLOURS, behind_subject
from spinemocap.synth.rooms import ROOM_ITEMS, paint_room


def test_rooms_are_seeded_and_every_item_paints_something():
    a, b = paint_room((320, 240), 4), paint_room((320, 240), 4)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (240, 320, 3) and a.dtype == np.uint8
    assert np.any(paint_room((320, 240), 5) != a)
    for item in ROOM_ITEMS:
        bare = paint_room((320, 240), 9, items=())
        assert np.any(paint_room((320, 240), 9, items=(item,)) != bare), item
    with pytest.raises(ValueError, match="unknown room items"):
        paint_room((320, 240), 0, items=("sofa",))


def test_other_people_stand_in_the_room_over_the_same_furniture():
    empty = paint_room((640, 480), 12)
    crowded = paint_room((640, 480), 12, people=2)
    np.testing.assert_array_equal(crowded, paint_room((640, 480), 12, people=2))  # seeded
    figures = np.any(crowded != empty, axis=2)
    assert 0.03 < figures.mean() < 0.6  # two people, not the whole room repainted
    rows, cols = np.nonzero(figures)
    assert rows.max() - rows.min() > 0.4 * 480  # standing figures: tall, on the floor
    assert np.any(paint_room((640, 480), 12, people=1) != crowded)
    with pytest.raises(ValueError, match="people must be >= 0"):
        paint_room((640, 480), 12, people=-1)
    with pytest.raises(ValueError, match="bystanders"):
        SynthConfig.preset("tiny", bystanders=1)  # no room to stand in


def test_the_command_line_offers_the_studios_vocabularies():
    assert TAPE_COLOUR_NAMES == tuple(TAPE_COLOURS) and BACKDROP_NAMES == BACKDROPS
    with pytest.raises(ValueError, match="tape_colour"):
        SynthConfig(tape_colour="green")
    with pytest.raises(ValueError, match="backdrop"):
        SynthConfig(backdrop="beach")


def test_backdrop_replaces_only_the_empty_background():
    rgb = np.full((4, 5, 3), 90, np.uint8)
    rgb[1:3, 1:3] = (200, 150, 120)  # the subject
    room = np.arange(60, dtype=np.uint8).reshape(4, 5, 3)
    out = behind_subject(rgb, np.array([90, 90, 90], np.uint8), room)
    np.testing.assert_array_equal(out[1:3, 1:3], rgb[1:3, 1:3])
    outside = np.ones((4, 5), bool)
    outside[1:3, 1:3] = False
    np.testing.assert_array_equal(out[outside], room[outside])


@pytest.fixture(scope="module")
def renders():
    """One tiny frame as the studio rendered it so far, in blue tape, and in front of a room."""
    out = {}
    for key, options in {"plain": {}, "blue": {"tape_colour": "blue"}, "room": {"backdrop": "room"},
                         "people": {"backdrop": "room", "bystanders": 2}}.items():
        scene = build_scene(SynthConfig.preset("tiny", frames=1, seed=21, noise=0.0, **options))
        out[key] = (scene.render(0), scene.frame_groundtruth(0))
        scene.close()
    return out


def test_tape_colour_and_room_change_the_render_and_keep_the_truth(renders):
    plain, truth = renders["plain"]
    for key in ("blue", "room", "people"):
        rendered, gt = renders[key]
        for name in truth:
            np.testing.assert_array_equal(gt[name], truth[name])
        for image, base, mask, base_mask in zip(rendered.images, plain.images, rendered.masks, plain.masks):
            np.testing.assert_array_equal(mask, base_mask)
            differs = np.any(image != base, axis=2)
            if key == "blue":  # only the tape changes (and its anti-aliased rim): blue where it was near black
                tape = mask & differs
                near = cv2.dilate(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
                assert tape.sum() > 0.5 * mask.sum() and not (differs & ~near).any()
                b, g, r = (image[tape].astype(float).mean(axis=0))
                assert b > r + 20
            else:  # the background changes, the tape keeps its pixels
                assert differs.mean() > 0.3
                assert not differs[mask].any()
    room, people = renders["room"][0], renders["people"][0]
    assert any(np.any(a != b) for a, b in zip(people.images, room.images))  # the people stand in the room


# ---------------------------------------------------------------------------------- camera looks
def _scene_image() -> np.ndarray:
    """A grey wall with a dark stripe holding bright dots (BGR uint8, 120 x 160)."""
    image = np.full((120, 160, 3), 150, np.uint8)
    image[30:90, 60:100] = 30
    for y in (40, 60, 80):
        cv2.circle(image, (80, y), 5, (200, 190, 180), -1)
    return image


def test_warm_light_turns_the_frame_orange_and_daylight_leaves_it():
    from spinemocap.synth.appearance import CameraLook, white_balance_gains

    np.testing.assert_allclose(white_balance_gains(6500.0), 1.0, atol=1e-6)
    b, g, r = white_balance_gains(3000.0)
    assert r > g == 1.0 > b
    image = _scene_image()
    warm = CameraLook(colour_temperature_k=3000.0).apply(image, 0.0).astype(float)
    assert warm[..., 2].mean() > image[..., 2].mean() and warm[..., 0].mean() < image[..., 0].mean()
    np.testing.assert_array_equal(CameraLook().apply(image, 0.0), image)


def test_flicker_and_exposure_change_brightness_from_frame_to_frame():
    from spinemocap.synth.appearance import CameraLook

    image = _scene_image()
    look = CameraLook(flicker=0.08, fps=30.0)
    means = [look.apply(image, k / 30.0, phase=0.3).mean() for k in range(6)]
    assert np.ptp(means) > 0.03 * np.mean(means)  # the ripple, sampled at 30 fps
    assert CameraLook(exposure=0.8).apply(image, 0.0).mean() == pytest.approx(0.8 * image.mean(), rel=0.02)


def test_defocus_chroma_and_codecs_keep_the_picture_and_lose_detail():
    from spinemocap.synth.appearance import CameraLook

    image = _scene_image()
    image[5:7, 5:7] = (0, 0, 255)  # a 2x2 red speck: 4:2:0 keeps its brightness, spreads its colour
    sharpness = lambda im: float((np.diff(im.astype(float), axis=1) ** 2).sum())  # noqa: E731  (gradient energy)
    looks = {"defocus": CameraLook(defocus_px=1.0), "420": CameraLook(chroma_420=True),
             "jpeg": CameraLook(codec="jpeg", quality=70), "h264": CameraLook(codec="h264", bitrate_mbps=2.0, fps=30.0)}
    for name, look in looks.items():
        out = look.apply(image, 0.0)
        assert out.shape == image.shape and out.dtype == np.uint8, name
        assert np.abs(out.astype(float) - image).mean() < 6.0, name  # the same picture
        assert np.any(out != image), name
    assert sharpness(looks["defocus"].apply(image, 0.0)) < 0.8 * sharpness(image)
    sub = looks["420"].apply(image, 0.0)
    grey = lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2GRAY).astype(float)  # noqa: E731
    assert np.abs(grey(sub) - grey(image))[30:90, 60:100].max() <= 3  # luma kept
    assert sub[5, 5, 2] < 200 and sub[5, 8, 2] > image[5, 8, 2] + 5  # colour at half resolution


def test_lab_camera_looks_are_seeded_varied_and_keep_the_truth(renders):
    from spinemocap.synth.appearance import camera_looks

    a, b = camera_looks("lab", 40, 3, 100.0), camera_looks("lab", 40, 3, 100.0)
    assert a == b and camera_looks("ideal", 4, 3, 100.0) is None
    assert a is not None and {look.codec for look in a} == {"none", "jpeg", "h264", "h265"}
    assert len({look.chroma_420 for look in a}) == 2 and min(look.readout_ms for look in a) == 0 < max(look.readout_ms for look in a)
    assert 2700 <= min(look.colour_temperature_k for look in a) < max(look.colour_temperature_k for look in a) <= 6500
    with pytest.raises(ValueError, match="camera_look"):
        SynthConfig(camera_look="cinema")
    plain, truth = renders["plain"]
    # global shutters: the rolling shutter moves the dots in the image (its own test)
    scene = build_scene(SynthConfig.preset("tiny", frames=1, seed=21, noise=0.0, camera_look="lab", rolling_shutter_ms=0.0))
    rendered, gt = scene.render(0), scene.frame_groundtruth(0)
    scene.close()
    for name in truth:
        np.testing.assert_array_equal(np.asarray(gt[name]), np.asarray(truth[name]), err_msg=name)
    for image, mask, plain_image, plain_mask in zip(rendered.images, rendered.masks, plain.images, plain.masks):
        np.testing.assert_array_equal(mask, plain_mask)
        assert np.any(image != plain_image)
