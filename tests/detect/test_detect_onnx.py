"""The network on ONNX Runtime: the detector's default runtime on the CPU in float32.
Its logits must be the torch inference form's up to float rounding (any input size the detector
makes, batches included, also from several threads at once), the detector must find exactly the
same dots and mask with it as with torch, and where onnxruntime (or onnx, which torch's exporter
needs) cannot be imported the detector falls back to torch by itself; asked for explicitly, a
missing or unusable runtime is an InputError naming the reason."""

from __future__ import annotations

import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch

from spinemocap.detect import Detector
from spinemocap.detect.detector import NetSegmenter, shipped_weights_path
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.segnet import InferenceUNet, OnnxUNet, load_weights, pad_to_multiple, to_tensor
from spinemocap.fileio import InputError

# float32 logits are tens in magnitude; the two runtimes sum the convolutions in different orders
LOGIT_ATOL = 1e-3


def _views(seed: int = 3) -> list[np.ndarray]:
    """Drawn tapes at the sizes the detector feeds the network (padded to the stride)."""
    rng = np.random.default_rng(seed)
    out = []
    for size in [(256, 168), (40, 256), (120, 96), (8, 8), (256, 256)]:  # stage 1, crops, the smallest, a square
        image = draw_sample(rng, size=(size[0] * 3, size[1] * 3), px_per_mm=1.2, noise=2.0).image
        out.append(pad_to_multiple(image[::3, ::3], 8)[0])
    return out


def _torch_logits(net: InferenceUNet, pixels: np.ndarray) -> np.ndarray:
    with torch.inference_mode():
        return net(to_tensor(pixels))[:, 0].numpy()


@pytest.fixture(scope="module")
def nets():
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    net = InferenceUNet(load_weights(shipped_weights_path())[0])
    return net, OnnxUNet(net, threads=1)


def test_onnx_logits_equal_the_torch_modules(nets):
    net, onnx = nets
    assert onnx.stride == net.stride == 8
    for view in _views():
        ref, got = _torch_logits(net, view), onnx(view[None])
        assert got.shape == ref.shape == (1,) + view.shape[:2] and got.dtype == np.float32
        assert np.abs(ref).max() > 1.0
        assert np.abs(got - ref).max() <= LOGIT_ATOL, float(np.abs(got - ref).max())
    # a batch gives each image's own logits; shapes change from call to call (no re-specialisation)
    batch = np.stack(_views()[2:3] * 3)
    got = onnx(batch)
    assert got.shape == batch.shape[:3]
    assert np.abs(got - _torch_logits(net, batch)).max() <= LOGIT_ATOL
    assert np.array_equal(got[0], got[2])


def test_onnx_session_runs_from_several_threads_at_once(nets):
    _, onnx = nets
    views = _views(9)
    alone = [onnx(v[None]) for v in views]
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(lambda v: onnx(v[None]), views * 4))
    assert all(np.array_equal(a, b) for a, b in zip(alone * 4, together))


def test_onnx_runtime_finds_the_torch_runtimes_dots(nets):
    onnx, plain = Detector("net"), Detector("net", runtime="torch")
    assert onnx._segment.runtime == "onnxruntime" and plain._segment.runtime == "torch"
    assert plain._segment.onnx is None
    rng = np.random.default_rng(11)
    total = 0
    for size, ppm in [((480, 640), 1.4), ((800, 600), 2.2), ((600, 900), 1.8)]:
        image = draw_sample(rng, size=size, px_per_mm=ppm, noise=2.0).image
        a, b = onnx.detect(image), plain.detect(image)
        assert np.array_equal(a.uv, b.uv) and np.array_equal(a.confidence, b.confidence)
        assert np.array_equal(a.mask, b.mask)
        total += len(a)
    assert total > 20  # the tapes and their dots are seen


@pytest.mark.parametrize("missing", ["onnxruntime", "onnx"])
def test_detector_falls_back_to_torch_without_onnxruntime(monkeypatch, missing):
    monkeypatch.setitem(sys.modules, missing, None)  # import raises ImportError, as when not installed
    seg = NetSegmenter(device="cpu")
    assert seg.runtime == "torch" and seg.onnx is None
    view = _views()[1]
    logits = seg._logits(view)
    assert logits.shape == view.shape[:2] and np.abs(logits).max() > 1.0
    # the message names the package that failed to import (where neither is installed, the first tried)
    with pytest.raises(InputError, match="'onnxruntime' asked for, but onnx(runtime)? cannot be imported"):
        NetSegmenter(device="cpu", runtime="onnxruntime")


def test_runtime_choices():
    with pytest.raises(InputError, match="unknown network runtime"):
        NetSegmenter(runtime="tensorrt")
    with pytest.raises(InputError, match="float32 on the CPU only"):
        NetSegmenter(runtime="onnxruntime", precision="bfloat16")
    bf16 = NetSegmenter(precision="bfloat16")  # auto: bfloat16 stays on torch
    assert bf16.runtime == "torch" and bf16.onnx is None


def test_padded_channels_change_no_logit():
    """The export pads every level to 16 channels (zero weights): the same logits in torch."""
    from spinemocap.detect.segnet import _channels_padded

    net = InferenceUNet(load_weights(shipped_weights_path())[0])
    padded = _channels_padded(net, 16)
    assert net.channels[0] % 16 != 0 and all(c % 16 == 0 for c in padded.channels)
    assert padded.down[0].shape[0] == 16 and net.down[0].shape[0] == net.channels[0]  # the original is untouched
    for view in _views(4):
        ref, got = _torch_logits(net, view), _torch_logits(padded, view)
        assert np.abs(got - ref).max() <= 1e-5


def test_export_happens_once_per_weights(nets):
    from spinemocap.detect import segnet

    net, onnx = nets
    again = OnnxUNet(net, threads=1)
    assert again.model_bytes is onnx.model_bytes  # the same weights: no second export
    other = InferenceUNet(load_weights(shipped_weights_path())[0])
    with torch.no_grad():
        other.head_b += 1.0  # other weights: exported anew, and the logits follow them
    moved = OnnxUNet(other, threads=1)
    assert moved.model_bytes is not onnx.model_bytes and len(segnet._EXPORTED) >= 2
    view = _views()[2][None]
    assert np.abs(moved(view) - onnx(view) - 1.0).max() <= LOGIT_ATOL


@pytest.mark.parametrize("failure, said", [
    (RuntimeError("exporter refused"), "exporter refused"),
    # an ImportError inside torch's exporter is not "onnxruntime is not installed": said, not silent
    (ModuleNotFoundError("No module named 'onnxscript'", name="onnxscript"), "exporter needs onnxscript"),
])
def test_a_failing_export_falls_back_to_torch_with_a_warning(monkeypatch, nets, failure, said):
    from spinemocap.detect import segnet

    def refuse(*args, **kwargs):
        raise failure

    monkeypatch.setattr(segnet, "_EXPORTED", {})  # nothing cached: the export runs
    monkeypatch.setattr(torch.onnx, "export", refuse)
    with pytest.warns(RuntimeWarning, match=said):
        seg = NetSegmenter(device="cpu")
    assert seg.runtime == "torch" and seg.onnx is None
    with pytest.raises(InputError, match=f"failed to load the network.*{said}"):
        NetSegmenter(device="cpu", runtime="onnxruntime")


def test_a_session_computing_other_logits_is_refused_at_load(monkeypatch, nets):
    # the session is checked against the torch module at construction: an export that runs but
    # computes another network's logits (here: a real export of other weights) is not used
    from spinemocap.detect import segnet

    net, _ = nets
    other = InferenceUNet(load_weights(shipped_weights_path())[0])
    with torch.no_grad():
        other.head_b += 1.0
    wrong = segnet._onnx_model(other, 16, True)
    monkeypatch.setattr(segnet, "_onnx_model", lambda *args: wrong)
    with pytest.raises(RuntimeError, match="logits differ from torch's by 1"):
        OnnxUNet(net, threads=1)
    with pytest.warns(RuntimeWarning, match="logits differ"):
        seg = NetSegmenter(device="cpu")
    assert seg.runtime == "torch" and seg.onnx is None
    with pytest.raises(InputError, match="failed to load the network"):
        NetSegmenter(device="cpu", runtime="onnxruntime")
