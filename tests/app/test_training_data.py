"""Training the tape network on studio data: the studio renders into the first data folder (its
shards kept on a second run), further folders are taken as they are, and the weights' metadata
records the data and the provenance it was given."""

from __future__ import annotations

import json
import shutil

import numpy as np

from spinemocap.app.training_data import SynthDataSettings, train_on_studio
from spinemocap.detect import Detector
from spinemocap.detect.train import TrainSettings

# two tiny-layout scenes (studio seeds 1000, 1001): one for training, one for validation
TINY = SynthDataSettings(scenes=2, frames_per_scene=1, seed=1, layouts=("tiny",), sequence_frames=20, val_fraction=0.5)
QUICK = TrainSettings(epochs=1, steps=1, batch=2, crop=48, channels=(4, 4, 4, 4))


def test_trains_on_rendered_and_given_shards(tmp_path):
    out = tmp_path / "run"
    meta = train_on_studio(out, QUICK, TINY, provenance={"command": "spinemocap detector train"}, progress=False)
    data = out / "data"  # the default folder
    assert sorted(p.name for p in data.glob("*.npz")) == ["synth_0000.npz", "synth_0001.npz"]
    assert meta["command"] == "spinemocap detector train" and meta["data"]["kind"] == "synthetic studio"
    assert meta["data"]["folders"] == [str(data)] and meta["data"]["scenes"] == 2
    assert meta["data"]["train_views"] > 0 and meta["data"]["val_views"] > 0
    assert json.loads((out / "weights.json").read_text()) == json.loads(json.dumps(meta))
    assert Detector("net", weights=out / "weights.pt").segment(np.zeros((48, 64, 3), np.uint8)).shape == (48, 64)

    rendered = {p.name: p.stat().st_mtime_ns for p in data.glob("*.npz")}
    extra = shutil.copytree(data, tmp_path / "extra")  # another data set, taken as it is
    both = train_on_studio(tmp_path / "run2", QUICK, TINY, data=(data, extra), progress=False)
    assert {p.name: p.stat().st_mtime_ns for p in data.glob("*.npz")} == rendered  # kept, not rendered again
    assert both["data"]["folders"] == [str(data), str(extra)]
    assert both["data"]["train_views"] == 2 * meta["data"]["train_views"]
    assert both["data"]["val_views"] == 2 * meta["data"]["val_views"]
