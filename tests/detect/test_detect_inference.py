"""The network's inference form: batch norm folded into the convolutions and the decoder's
concatenations replaced by summed convolutions must give the plain module's logits up to float
rounding (stated tolerance below), for the shipped weights and for a model whose batch norms are far
from identity; the detector with it must find exactly the dots, and the same mask, as with the plain
module, on a studio frame (six cameras at a quarter of the pixels) and on drawn tapes. bfloat16 is an
option only: asked for, the network computes in it; an unknown precision is an InputError."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spinemocap.detect import Detector
from spinemocap.detect.detector import shipped_weights_path
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.segnet import InferenceUNet, TapeUNet, load_weights, pad_to_multiple, to_tensor
from spinemocap.fileio import InputError

# float32 logits are tens in magnitude; folding and splitting reorder the sums, nothing else
LOGIT_ATOL = 1e-3


def _views(seed: int = 3) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for size in [(256, 168), (40, 256), (120, 96)]:  # stage-1 frame, a tall stage-2 crop, another
        image = draw_sample(rng, size=(size[0] * 3, size[1] * 3), px_per_mm=1.2, noise=2.0).image
        out.append(pad_to_multiple(image[::3, ::3], 8)[0])
    return out


def _logits(model: torch.nn.Module, view: np.ndarray) -> torch.Tensor:
    with torch.inference_mode():
        return model(to_tensor(view))


def test_inference_form_gives_the_plain_modules_logits_for_the_shipped_weights():
    plain, _ = load_weights(shipped_weights_path())
    fast = InferenceUNet(plain)
    assert fast.stride == plain.stride
    for view in _views():
        ref, got = _logits(plain, view), _logits(fast, view)
        assert got.shape == ref.shape and ref.abs().max() > 1.0
        assert torch.allclose(got, ref, rtol=0, atol=LOGIT_ATOL), float((got - ref).abs().max())
    # a batch, channels-last as the detector runs it, gives each image's own logits
    batch = np.stack(_views()[1:2] * 3)
    with torch.inference_mode():
        out = fast.to(memory_format=torch.channels_last)(to_tensor(batch))
    assert torch.allclose(out, _logits(plain, batch), rtol=0, atol=LOGIT_ATOL)


def test_folding_uses_every_batch_norm_statistic():
    torch.manual_seed(0)
    plain = TapeUNet((4, 6, 8))
    for m in plain.modules():  # batch norms far from identity: folding errors would show
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-1, 1)
            m.running_var.uniform_(0.2, 3)
            m.weight.data.uniform_(0.5, 2)
            m.bias.data.uniform_(-1, 1)
    plain.eval()
    fast = InferenceUNet(plain)
    for view in _views(5):
        ref, got = _logits(plain, view), _logits(fast, view)
        assert torch.allclose(got, ref, rtol=1e-5, atol=1e-5), float((got - ref).abs().max())
    with pytest.raises(ValueError, match="eval mode"):
        InferenceUNet(plain.train())


def _plain_detector() -> Detector:
    det = Detector("net", runtime="torch")  # the module below runs (not ONNX Runtime's export)
    det._segment.model = load_weights(det._segment.weights_path)[0].to(memory_format=torch.channels_last)
    return det


@pytest.fixture(scope="module")
def studio_images():
    """The studio's six cameras at a quarter of the pixels, one frame (default realism)."""
    pytest.importorskip("pyvista")
    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset("studio", frames=1, size=(1224, 800)))
    return scene.render(0, with_masks=False).images


def test_detector_finds_the_plain_modules_dots(studio_images):
    rng = np.random.default_rng(11)
    drawn = [draw_sample(rng, size=size, px_per_mm=ppm, noise=2.0).image
             for size, ppm in [((480, 640), 1.4), ((800, 600), 2.2)]]
    fast, plain = Detector("net"), _plain_detector()
    assert not isinstance(fast._segment.model, TapeUNet)  # the detector runs the inference form
    total = 0
    for c, image in enumerate(list(studio_images) + drawn):
        a, b = fast.detect(image, camera=c), plain.detect(image, camera=c)
        assert np.array_equal(a.uv, b.uv) and np.array_equal(a.confidence, b.confidence)
        assert np.array_equal(a.mask, b.mask)
        total += len(a)
    assert total > 50  # the tape and its dots are seen


def test_bfloat16_is_an_option_and_an_unknown_precision_is_an_input_error():
    det = Detector("net", precision="bfloat16")
    assert det._segment.dtype == torch.bfloat16
    assert all(p.dtype == torch.bfloat16 for p in det._segment.model.parameters())
    view = _views()[0]
    logits = det._segment._logits(view)
    assert logits.dtype == np.float32 and logits.shape == view.shape[:2]
    plain, _ = load_weights(shipped_weights_path())
    ref = _logits(plain, view)[0, 0].numpy()
    assert np.mean((logits > 0) == (ref > 0)) > 0.99  # the same picture, not the same numbers
    with pytest.raises(InputError, match="unknown network precision"):
        Detector("net", precision="float16")


def test_torch_threads_are_set_only_when_they_differ(monkeypatch):
    from spinemocap.detect.detector import NetSegmenter

    seg = NetSegmenter(device="cpu", threads=1)
    image = _views()[0]
    before = torch.get_num_threads()
    calls = []
    real = torch.set_num_threads
    monkeypatch.setattr(torch, "set_num_threads", lambda n: (calls.append(n), real(n)))
    try:
        real(2)
        seg.tape_boxes([image])
        assert torch.get_num_threads() == 1 and calls == [1]  # set when it differed ...
        seg.tape_boxes([image])
        seg.segment_boxes(image, [(slice(0, 40), slice(0, 60))])
        assert calls == [1]                                   # ... and not again
    finally:
        real(before)
