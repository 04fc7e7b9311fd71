"""The held-out appearance family: no training set renders it, and `bench detect` scores it."""

import dataclasses

import numpy as np
import pytest

from spinemocap.app import training_data
from spinemocap.app.training_data import HELD_OUT_FAMILY, SynthDataSettings, generate_synthetic, refuse_held_out
from spinemocap.bench import detect as bench
from spinemocap.synth import SynthConfig
from spinemocap.synth.appearance import TAPE_COLOURS


def test_training_refuses_every_part_of_the_held_out_family(tmp_path, monkeypatch):
    refuse_held_out(SynthConfig.preset("tiny"))  # the studio's own look passes
    for key, value in HELD_OUT_FAMILY.items():
        with pytest.raises(ValueError, match=f"{key}={value!r}"):
            refuse_held_out(SynthConfig.preset("tiny", **{key: value}))
    # the generator checks every scene it draws before rendering it
    drawn = training_data.random_scene_config
    monkeypatch.setattr(training_data, "random_scene_config",
                        lambda *a, **k: dataclasses.replace(drawn(*a, **k), tape_colour=HELD_OUT_FAMILY["tape_colour"]))
    with pytest.raises(ValueError, match="held-out appearance"):
        generate_synthetic(tmp_path / "shards", SynthDataSettings(scenes=2), progress=False)
    assert not list((tmp_path / "shards").glob("*.npz"))


def test_the_lab_training_mix_varies_the_look_and_never_holds_the_held_out_tape():
    rng = np.random.default_rng(0)
    drawn = [training_data.lab_appearance(SynthConfig.preset("tiny", seed=k), rng) for k in range(60)]
    colours = {c.tape_colour for c in drawn}
    assert HELD_OUT_FAMILY["tape_colour"] not in colours and len(colours) == len(TAPE_COLOURS) - 1
    assert {c.backdrop for c in drawn} == {"plain", "room"} and {c.camera_look for c in drawn} == {"ideal", "lab"}
    # the tape's roll and finish, the skin's marks and clothing vary too
    assert len({c.tape_roll for c in drawn}) > 2 and len({c.tape_finish for c in drawn}) == 3
    assert {m for c in drawn for m in c.skin_marks} and {i for c in drawn for i in c.clothing}
    assert {c.bystanders for c in drawn if c.backdrop == "room"} == {0, 1, 2}  # other people in some rooms
    for config in drawn:
        refuse_held_out(config)


def test_the_held_out_set_shows_the_held_out_family_at_the_lab_level():
    held = bench.TEST_SETS[bench.HELD_OUT]
    assert (held.tape_colour, held.backdrop, held.camera_look) == (HELD_OUT_FAMILY["tape_colour"], "room", "lab")
    assert held.realism == "lab" and bench.HELD_OUT in bench.DEFAULT_SETS
    with_subject = bench.TEST_SETS[bench.HELD_OUT_SUBJECT]  # the same look on a lab's subject
    assert (with_subject.tape_colour, with_subject.backdrop, with_subject.camera_look, with_subject.realism) == (
        held.tape_colour, held.backdrop, held.camera_look, held.realism) and with_subject.subject == "lab"
    people = bench.TEST_SETS[bench.WITH_PEOPLE]  # the training colour in a room with other people
    assert (people.backdrop, people.bystanders, people.realism) == ("room", 2, "lab") and people.tape_colour != held.tape_colour
    assert bench.WITH_PEOPLE in bench.DEFAULT_SETS and all(t.bystanders == 0 for t in bench.TEST_SETS.values() if t is not people)
    offsets = [test.seed_offset for test in bench.TEST_SETS.values()]
    assert len(set(offsets)) == len(offsets)  # no two sets share scenes


@pytest.mark.slow
def test_the_benchmark_scores_the_held_out_family(monkeypatch):
    held = bench.TEST_SETS[bench.HELD_OUT]
    # the same look at the tiny layout (one frame, three 480x360 cameras; the default realism, whose
    # scene is quicker to build) through the whole scoring
    tiny = dataclasses.replace(held, name="tiny-held-out", preset="tiny", scenes=1, frames=1, supersample=1, realism="skin")
    monkeypatch.setitem(bench.TEST_SETS, tiny.name, tiny)
    scene, cfg = bench.held_out_scene(tiny, 0)
    rendered = scene.render(bench.frames_of(tiny)[0])
    image, tape = rendered.images[0], rendered.masks[0]
    scene.close()
    assert (cfg.tape_colour, cfg.backdrop, cfg.camera_look) == (HELD_OUT_FAMILY["tape_colour"], "room", "lab")
    blue = np.asarray(TAPE_COLOURS["blue"])
    b, g, r = image[tape].reshape(-1, 3).astype(float).mean(axis=0)
    assert b > r and blue[2] > blue[0]  # the tape shows blue
    assert np.unique(image[~tape].reshape(-1, 3), axis=0).shape[0] > 1000  # a room, not a plain backdrop
    results = bench.run_detect_benchmark([tiny.name], say=lambda _: None)
    tiny_set = results.sets[tiny.name]
    assert isinstance(tiny_set, bench.SetResult)
    dots = tiny_set.dots
    for name in ("net", "classical", "SimpleBlobDetector"):
        d = dots[name]
        assert d.true_positives + d.missed > 20  # every visible dot of the three views counted
        assert 0 <= d.recall <= 1 and 0 <= d.precision <= 1
    assert dots["blobs in exact mask"].recall > 0.8  # the render's dots are where the truth says
