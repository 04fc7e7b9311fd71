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
    for key, options in {"plain": {}, "blue": {"tape_colour": "blue"}, "room": {"backdrop": "room"}}.items():
        scene = build_scene(SynthConfig.preset("tiny", frames=1, seed=21, noise=0.0, **options))
        out[key] = (scene.render(0), scene.frame_groundtruth(0))
        scene.close()
    return out


def test_tape_colour_and_room_change_the_render_and_keep_the_truth(renders):
    plain, truth = renders["plain"]
    for key in ("blue", "room"):
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
