"""The network in int8 on ONNX Runtime: ``Detector("net", precision="int8")``, an
option (float32 stays the default). Its logits are quantized, so they are not float32's: they
must keep float32's sign almost everywhere and stay within a small part of the logit range, and
the detector must find the same dots as in float32 on drawn tapes (the clean-up works on the
image itself). int8 kernels differ between CPUs (VNNI or not): nothing here asks for the same
bits on another machine. Asked for where ONNX Runtime cannot run it, int8 is an InputError (no
silent float32)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch

from spinemocap.detect import Detector
from spinemocap.detect.detector import NetSegmenter, shipped_weights_path
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.segnet import InferenceUNet, OnnxUNet, load_weights, pad_to_multiple
from spinemocap.fileio import InputError


def _views(seed: int) -> list[np.ndarray]:
    """Drawn tapes at the sizes the detector feeds the network (padded to the stride); not the
    calibration's drawings (other seeds and sizes)."""
    rng = np.random.default_rng(seed)
    out = []
    for size in [(256, 168), (40, 256), (120, 96), (8, 8), (256, 256)]:  # stage 1, crops, the smallest, a square
        image = draw_sample(rng, size=(size[0] * 3, size[1] * 3), px_per_mm=1.2, noise=2.0).image
        out.append(pad_to_multiple(image[::3, ::3], 8)[0])
    return out


@pytest.fixture(scope="module")
def detectors():
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    return Detector("net"), Detector("net", precision="int8")


def test_int8_graph_is_quantized_and_its_logits_follow_float32(detectors):
    import onnx

    f32, i8 = detectors[0]._segment, detectors[1]._segment
    assert i8.runtime == f32.runtime == "onnxruntime" and i8.precision == "int8"
    ops = {node.op_type for node in onnx.load_from_string(i8.onnx.model_bytes).graph.node}
    assert {"QuantizeLinear", "DequantizeLinear"} <= ops  # really int8 (QDQ), not the float graph
    for seed in (5, 6):
        for view in _views(seed):
            a, b = f32.onnx(view[None]), i8.onnx(view[None])
            assert b.shape == a.shape and b.dtype == np.float32
            scale = float(np.abs(a).max())
            assert scale > 5.0
            err = float(np.abs(a - b).max())
            assert 0.0 < err <= 0.2 * scale, (view.shape, err, scale)  # quantized, yet close
            assert np.mean((a > 0) == (b > 0)) >= 0.995, view.shape  # the mask's sign, nearly everywhere


def test_int8_detector_finds_the_float32_dots(detectors):
    f32, i8 = detectors
    rng = np.random.default_rng(11)
    total = 0
    for size, ppm in [((480, 640), 1.4), ((800, 600), 2.2), ((600, 900), 1.8), ((640, 480), 1.0)]:
        image = draw_sample(rng, size=size, px_per_mm=ppm, noise=2.0).image
        a, b = f32.detect(image), i8.detect(image)
        assert len(a) == len(b) > 10
        nearest = np.linalg.norm(a.uv[:, None] - b.uv[None], axis=2).min(axis=1)
        assert nearest.max() <= 0.25  # px: the clean-up finds the dots on the image itself
        assert np.sum(a.mask != b.mask) <= 0.01 * a.mask.sum()
        total += len(a)
    assert total > 50


def test_int8_session_runs_from_several_threads_at_once(detectors):
    from concurrent.futures import ThreadPoolExecutor

    onnx = detectors[1]._segment.onnx
    views = _views(9)
    alone = [onnx(v[None]) for v in views]
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(lambda v: onnx(v[None]), views * 4))
    assert all(np.array_equal(a, b) for a, b in zip(alone * 4, together))


def test_int8_model_is_made_once_per_process(detectors):
    again = NetSegmenter(precision="int8")
    assert again.onnx is not None and again.onnx.model_bytes is detectors[1]._segment.onnx.model_bytes


def test_int8_choices(monkeypatch):
    with pytest.raises(InputError, match="unknown network precision.*int8"):
        NetSegmenter(precision="int4")
    with pytest.raises(InputError, match="'int8' runs on ONNX Runtime on the CPU only"):
        NetSegmenter(precision="int8", runtime="torch")
    with pytest.raises(ValueError, match="unknown ONNX Runtime precision"):
        OnnxUNet(InferenceUNet(load_weights(shipped_weights_path())[0]), precision="bfloat16")
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # as when not installed: no silent float32
    with pytest.raises(InputError, match="cannot be imported"):
        NetSegmenter(precision="int8")


def test_an_int8_model_computing_other_logits_is_refused_at_load(monkeypatch, detectors):
    # the int8 session is checked against the torch module at construction (signs on a drawn
    # tape): a model that runs but answers for other weights is refused, an InputError for int8
    from spinemocap.detect import segnet

    net = InferenceUNet(load_weights(shipped_weights_path())[0])
    other = InferenceUNet(load_weights(shipped_weights_path())[0])
    with torch.no_grad():
        other.head_b -= 30.0  # no pixel is tape any more
    wrong = segnet._int8_model(segnet._onnx_model(other, 16, True), net.stride)
    monkeypatch.setattr(segnet, "_int8_model", lambda *args: wrong)
    with pytest.raises(RuntimeError, match="int8 logits have torch's sign on only"):
        OnnxUNet(net, threads=1, precision="int8")
    with pytest.raises(InputError, match=r"\(int8\) failed to load the network"):
        NetSegmenter(precision="int8")


def test_without_vnni_the_weights_take_7_bits(monkeypatch, detectors):
    # x86 int8 kernels without VNNI can saturate: there the weights are quantized to 7 bits. Run
    # here (a VNNI CPU or not), that model too must find the float32 dots.
    from spinemocap.detect import segnet

    vnni = segnet.cpu_has_vnni()
    monkeypatch.setattr(segnet, "cpu_has_vnni", lambda: not vnni)
    other = Detector("net", precision="int8")
    assert other._segment.onnx.model_bytes != detectors[1]._segment.onnx.model_bytes
    image = draw_sample(np.random.default_rng(12), size=(640, 480), px_per_mm=1.6, noise=2.0).image
    a, b = detectors[0].detect(image), other.detect(image)
    assert len(a) == len(b) > 10
    assert np.linalg.norm(a.uv[:, None] - b.uv[None], axis=2).min(axis=1).max() <= 0.25
