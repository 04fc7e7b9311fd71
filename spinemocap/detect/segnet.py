"""A compact U-Net for tape segmentation, in plain PyTorch (no torchvision).

The network maps a BGR image at working resolution (a few hundred px) to one logit per pixel
(tape vs not tape). It is fully convolutional, so any input size divisible by ``2**depth`` works;
:func:`pad_to_multiple` takes care of that. About 0.3 M parameters: ~1.2 MB of float32 weights.

Inputs: float tensor (B, 3, H, W), BGR scaled to [0, 1] and centred (``x - 0.5``), see
:func:`to_tensor`. Outputs: logits (B, 1, H, W).
"""

from __future__ import annotations

import copy

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F


class ConvBlock(nn.Sequential):
    """Two 3x3 convolutions, each with batch norm and ReLU."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__(
            nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
            nn.Conv2d(c_out, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
        )


class TapeUNet(nn.Module):
    """U-Net with ``len(channels)`` levels; ``channels`` per level, finest first."""

    def __init__(self, channels: tuple[int, ...] = (16, 24, 40, 64)):
        super().__init__()
        self.channels = tuple(int(c) for c in channels)
        self.down = nn.ModuleList()
        c_prev = 3
        for c in self.channels:
            self.down.append(ConvBlock(c_prev, c))
            c_prev = c
        self.up = nn.ModuleList()
        for c_skip in reversed(self.channels[:-1]):
            self.up.append(ConvBlock(c_prev + c_skip, c_skip))
            c_prev = c_skip
        self.head = nn.Conv2d(c_prev, 1, 1)

    @property
    def stride(self) -> int:
        """Input sides must be multiples of this."""
        return 2 ** (len(self.channels) - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, block in enumerate(self.down):
            if i:
                x = F.max_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        for block, skip in zip(self.up, reversed(skips[:-1])):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))
        return self.head(x)


class InferenceUNet(nn.Module):
    """A :class:`TapeUNet` in eval mode rewritten for fast inference; same logits up to float
    rounding (see tests/detect/test_detect_inference.py).

    - Batch norm (eval mode: a per-channel scale and shift) is folded into the weights and a bias
      of the convolution before it, so no separate normalisation pass runs.
    - The first convolution of each decoder block reads the upsampled coarser features and the
      skip connection as two convolutions whose results are added (the channels of a convolution
      over a concatenation are a sum over the concatenated parts), so no concatenated copy is made.
    Weights are channels-last: the layout of :func:`to_tensor`'s input (NHWC pixels viewed as
    NCHW), so no convolution converts layouts. Plain tensor ops only: runs on any device/dtype."""

    def __init__(self, model: TapeUNet):
        super().__init__()
        if model.training:
            raise ValueError("InferenceUNet needs a model in eval mode (batch norm uses its running statistics)")
        self.channels = model.channels
        self.down = nn.ParameterList()  # per level: w1, b1, w2, b2
        for block in model.down:
            self.down.extend(_folded_block(block))
        self.up = nn.ParameterList()    # per level: w1 (coarse part), w1 (skip part), b1, w2, b2
        for block, c_skip in zip(model.up, reversed(self.channels[:-1])):
            w1, b1, w2, b2 = _folded_block(block)
            c_coarse = w1.shape[1] - c_skip  # forward concatenates [upsampled, skip]
            self.up.extend([_param(w1[:, :c_coarse]), _param(w1[:, c_coarse:]), b1, w2, b2])
        self.head_w = _param(model.head.weight.detach())
        self.head_b = _param(model.head.bias.detach())
        self.requires_grad_(False)

    @property
    def stride(self) -> int:
        return 2 ** (len(self.channels) - 1)

    def encode(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The encoder's features of each level, finest first (the last is the bottom level)."""
        skips = []
        d = list(self.down)
        for i in range(len(self.channels)):
            if i:
                x = F.max_pool2d(x, 2)
            x = F.relu_(F.conv2d(x, d[4 * i], d[4 * i + 1], padding=1))
            x = F.relu_(F.conv2d(x, d[4 * i + 2], d[4 * i + 3], padding=1))
            skips.append(x)
        return skips

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = self.encode(x)
        x = skips[-1]
        u = list(self.up)
        for i, skip in enumerate(reversed(skips[:-1])):
            w_coarse, w_skip, b1, w2, b2 = u[5 * i:5 * i + 5]
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            y = F.conv2d(skip, w_skip, b1, padding=1)
            y += F.conv2d(x, w_coarse, None, padding=1)
            x = F.relu_(F.conv2d(F.relu_(y), w2, b2, padding=1))
        return F.conv2d(x, self.head_w, self.head_b)


def _param(t: torch.Tensor) -> nn.Parameter:
    return nn.Parameter(t.detach().clone().contiguous(memory_format=torch.channels_last) if t.ndim == 4
                        else t.detach().clone(), requires_grad=False)


def _folded_block(block: ConvBlock) -> list[nn.Parameter]:
    """[w1, b1, w2, b2] of a ConvBlock with each batch norm folded into its convolution:
    BN(conv(x, w)) = conv(x, w * s) + (beta - mean * s), s = gamma / sqrt(var + eps)."""
    out = []
    for conv, bn in ((block[0], block[1]), (block[3], block[4])):
        assert isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d)
        scale = bn.weight.detach().double() / torch.sqrt(bn.running_var.double() + bn.eps)
        w = conv.weight.detach().double() * scale[:, None, None, None]
        b = bn.bias.detach().double() - bn.running_mean.double() * scale
        if conv.bias is not None:
            b = b + conv.bias.detach().double() * scale
        out += [_param(w.float()), _param(b.float())]
    return out


RUNTIMES = ("auto", "onnxruntime", "torch")
ONNX_PRECISIONS = ("float32", "int8")  # of :class:`OnnxUNet`'s arithmetic  # what runs the detector's passes (auto: onnxruntime where it can)


class _PixelsToLogits(nn.Module):
    """uint8 BGR pixels (B, H, W, 3) -> logits (B, H, W): :func:`to_tensor` and the forward pass
    of an :class:`InferenceUNet` in one graph, for the ONNX export. Two differences, the same
    logits: the upsampling is by a constant factor 2 (equal to upsampling to the skip's size where
    every side is a multiple of the stride, as :func:`pad_to_multiple` makes it; ONNX Runtime
    runs a constant-factor resize in its blocked layout), and ``concat`` (else summed convolutions)
    sets how each decoder block reads the upsampled features and the skip connection."""

    def __init__(self, net: InferenceUNet, concat: bool):
        super().__init__()
        self.net = net
        self.concat = concat

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        net = self.net
        skips = net.encode(to_tensor(pixels))
        x, u = skips[-1], list(net.up)
        for i, skip in enumerate(reversed(skips[:-1])):
            w_coarse, w_skip, b1, w2, b2 = u[5 * i:5 * i + 5]
            x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            if self.concat:
                y = F.conv2d(torch.cat([x, skip], dim=1), torch.cat([w_coarse, w_skip], dim=1), b1, padding=1)
            else:
                y = F.conv2d(skip, w_skip, b1, padding=1) + F.conv2d(x, w_coarse, None, padding=1)
            x = F.relu(F.conv2d(F.relu(y), w2, b2, padding=1))
        return F.conv2d(x, net.head_w, net.head_b)[:, 0]


def _channels_padded(net: InferenceUNet, multiple: int) -> InferenceUNet:
    """A copy of ``net`` whose levels have a multiple of ``multiple`` channels each. The added
    channels have zero weights and biases: they stay 0 through every ReLU and add nothing to the
    next convolution, so the logits are the same. (ONNX Runtime's blocked layout holds 16
    channels per block with AVX-512; a level of 12 channels runs its convolutions in the plain
    layout, with conversions before and after each.)"""
    out = copy.deepcopy(net)
    cs = [-(-c // multiple) * multiple for c in net.channels]

    def pad(t: torch.Tensor, n_out: int, n_in: int | None = None) -> nn.Parameter:
        z = torch.zeros((n_out,) if n_in is None else (n_out, n_in, *t.shape[2:]), dtype=t.dtype, device=t.device)
        z[tuple(slice(0, n) for n in t.shape)] = t
        return _param(z)

    d, u = out.down, out.up
    for i, c in enumerate(cs):
        c_in = cs[i - 1] if i else 3
        d[4 * i], d[4 * i + 1] = pad(d[4 * i], c, c_in), pad(d[4 * i + 1], c)
        d[4 * i + 2], d[4 * i + 3] = pad(d[4 * i + 2], c, c), pad(d[4 * i + 3], c)
    for j in range(len(cs) - 1):
        c, c_coarse = cs[len(cs) - 2 - j], cs[len(cs) - 1 - j]
        u[5 * j], u[5 * j + 1], u[5 * j + 2] = pad(u[5 * j], c, c_coarse), pad(u[5 * j + 1], c, c), pad(u[5 * j + 2], c)
        u[5 * j + 3], u[5 * j + 4] = pad(u[5 * j + 3], c, c), pad(u[5 * j + 4], c)
    out.head_w = pad(out.head_w, 1, cs[0])
    out.channels = tuple(cs)
    return out


class OnnxUNet:
    """An :class:`InferenceUNet` run by ONNX Runtime on the CPU: the same logits up to float
    rounding for less CPU per pass than torch (ONNX Runtime runs the convolutions, ReLUs fused,
    the pooling and the 2x upsampling in its blocked-channel NCHWc layout).

    The model is exported at construction from the given module's weights (in memory, nothing
    written to disk; ~0.4 s, once per process for given weights, see :func:`_onnx_model`) with
    torch's TorchScript-based exporter (it needs the ``onnx`` package, not ``onnxscript``).
    Input: uint8 BGR pixels (B, H, W, 3) with H and W multiples of :attr:`stride`
    (:func:`pad_to_multiple`); the scaling of :func:`to_tensor` is in the graph. Any H, W and B:
    no shape is specialised. ``threads``: ONNX Runtime's threads per pass (``None``: its
    default, all cores); set once, at construction. Several threads may call it at once.
    ImportError when ``onnxruntime`` or ``onnx`` is missing; RuntimeError when the exporter needs
    another package, or when the session's logits of a small fixed input (one pass at
    construction) are not the module's up to float rounding or cannot be computed: a runtime
    that would answer wrongly or fail later is found while the detector can still fall back."""

    def __init__(self, net: InferenceUNet, threads: int | None = 1, channel_multiple: int = 16, concat: bool = True,
                 precision: str = "float32"):
        import onnx  # noqa: F401  (the exporter needs it; fail here, early, with ImportError)
        import onnxruntime as ort

        if precision not in ONNX_PRECISIONS:
            raise ValueError(f"unknown ONNX Runtime precision {precision!r} (choose {' or '.join(ONNX_PRECISIONS)})")
        self.stride = net.stride
        self.precision = precision
        try:
            self.model_bytes = _onnx_model(net, channel_multiple, concat)
        except ImportError as exc:  # inside torch's exporter: not "onnxruntime or onnx is missing"
            raise RuntimeError(f"torch's ONNX exporter needs {exc.name or exc}") from exc
        if precision == "int8":
            self.model_bytes = _int8_model(self.model_bytes, self.stride)
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(threads) if threads else 0
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")  # no busy-waiting threads
        options.log_severity_level = 3
        self.session = ort.InferenceSession(self.model_bytes, options, providers=["CPUExecutionProvider"])
        self._check(net)

    CHECK_RTOL = 1e-3  # of the largest logit: float rounding is ~1e-6 of it, a wrong graph ~1
    CHECK_SIGNS_INT8 = 0.98  # int8: the share of pixels whose logit has torch's sign, on a drawn tape

    def _check(self, net: InferenceUNet) -> None:
        """float32: one pass on a fixed pseudo-random input of 4x4 strides against ``net``'s torch
        logits. int8 (logits move by a few % of their range): one pass on a drawn tape, whose
        mask's pixels must mostly keep the sign of torch's logits."""
        if self.precision == "int8":
            pixels = _calibration_inputs(self.stride, n=1, seed=12345)[0]
        else:
            pixels = np.random.default_rng(0).integers(0, 256, (1, 4 * self.stride, 4 * self.stride, 3), dtype=np.uint8)
        with torch.inference_mode():
            ref = net(to_tensor(pixels))[:, 0].float().numpy()
        got = self(pixels)
        if got.shape != ref.shape:
            raise RuntimeError(f"ONNX Runtime's logits have shape {got.shape}, torch's {ref.shape}")
        if self.precision == "int8":
            same = float(np.mean((got > 0) == (ref > 0)))
            if not same >= self.CHECK_SIGNS_INT8:
                raise RuntimeError(f"ONNX Runtime's int8 logits have torch's sign on only {same:.1%} of a test input")
            return
        err = float(np.abs(got - ref).max())
        if not err <= self.CHECK_RTOL * max(1.0, float(np.abs(ref).max())):
            raise RuntimeError(f"ONNX Runtime's logits differ from torch's by {err:.3g} on a test input")

    def __call__(self, pixels: np.ndarray) -> np.ndarray:
        """Logits (B, H, W) float32 of uint8 BGR pixels (B, H, W, 3)."""
        return self.session.run(None, {"pixels": np.ascontiguousarray(pixels, dtype=np.uint8)})[0]


_EXPORTED: dict[tuple, bytes] = {}  # ONNX models exported in this process, by weights and form


def _onnx_model(net: InferenceUNet, channel_multiple: int, concat: bool) -> bytes:
    """The ONNX model (serialised) of ``net`` in the form of :class:`_PixelsToLogits`, its channels
    padded to ``channel_multiple``; exported once per process for the same weights (keyed by a
    hash of every parameter, so another weights file or a changed module exports anew)."""
    import hashlib
    import io
    import warnings

    digest = hashlib.sha256()
    for name, p in net.state_dict().items():
        digest.update(name.encode())
        digest.update(p.detach().float().cpu().contiguous().numpy().tobytes())
    key = (digest.hexdigest(), net.channels, channel_multiple, concat)
    if key not in _EXPORTED:
        form = _PixelsToLogits(_channels_padded(net, channel_multiple).float().cpu(), concat).eval()
        example = torch.zeros(1, 2 * net.stride, 2 * net.stride, 3, dtype=torch.uint8)
        buf = io.BytesIO()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the TorchScript-based exporter is deprecated (still shipped in torch 2.13)
            torch.onnx.export(form, (example,), buf, dynamo=False, input_names=["pixels"], output_names=["logits"],
                              dynamic_axes={"pixels": {0: "b", 1: "h", 2: "w"}, "logits": {0: "b", 1: "h", 2: "w"}},
                              opset_version=17)
        _EXPORTED[key] = buf.getvalue()
    return _EXPORTED[key]


_INT8: dict[tuple[bytes, bool], bytes] = {}  # int8 models made in this process, by float model digest and range


def cpu_has_vnni() -> bool:
    """Whether this CPU has VNNI (AVX-512 VNNI or AVX-VNNI) by Linux's ``/proc/cpuinfo``; False
    where that cannot be read. Without VNNI, x86 int8 kernels multiply uint8 by int8 in 16-bit
    pairs that can saturate (ONNX Runtime PR #12088), so weights are then quantized to 7 bits."""
    try:
        with open("/proc/cpuinfo") as fh:
            flags = next((line for line in fh if line.startswith("flags")), "").split()
    except OSError:
        return False
    return "avx512_vnni" in flags or "avx_vnni" in flags


def _calibration_inputs(stride: int, n: int = 24, seed: int = 0) -> list[np.ndarray]:
    """Network inputs (1, H, W, 3) uint8 for the int8 calibration: drawn tapes
    (:mod:`spinemocap.detect.drawn`; no data is shipped) in the two kinds of view the detector
    feeds the network: a crop around the tape at working resolution (tape across most of it) and,
    every fourth, a whole frame (a small tape in a large background), sizes varied."""
    from .drawn import draw_sample

    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        if i % 4 == 3:  # a whole frame at 256 px wide: the tape is a small part of it
            sample = draw_sample(rng, size=(256, 168), px_per_mm=float(rng.uniform(0.15, 0.3)),
                                 n_rows=int(rng.integers(7, 14)), supersample=4, noise=3.0)
        else:  # a stage-2 crop: long side 256 px
            short = int(rng.integers(64, 200))
            size = (short, 256) if rng.random() < 0.7 else (256, short)
            sample = draw_sample(rng, size=size, px_per_mm=float(rng.uniform(0.35, 0.8)),
                                 n_rows=int(rng.integers(5, 14)), supersample=4, noise=3.0)
        out.append(pad_to_multiple(sample.image, stride)[0][None])
    return out


def _int8_model(model_bytes: bytes, stride: int) -> bytes:
    """The float ONNX model quantized to int8 by ONNX Runtime (static QDQ: int8 weights per
    tensor, uint8 activations whose ranges are the minima/maxima over :func:`_calibration_inputs`);
    made once per process for the same float model. On a CPU without VNNI (:func:`cpu_has_vnni`)
    the weights use 7 bits (``reduce_range``), against the saturation of its int8 kernels. ONNX
    Runtime's quantizer works on files: a temporary folder holds them while it runs."""
    import hashlib
    import logging
    import tempfile
    from pathlib import Path

    from onnxruntime.quantization import (
        CalibrationDataReader,
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    reduce_range = not cpu_has_vnni()
    key = (hashlib.sha256(model_bytes).digest(), reduce_range)
    if key not in _INT8:
        inputs = iter(_calibration_inputs(stride))

        class _Reader(CalibrationDataReader):
            def get_next(self):
                x = next(inputs, None)
                return None if x is None else {"pixels": x}

        def advice(record: logging.LogRecord) -> bool:  # the quantizer's advice to pre-process the model
            return "pre-process" not in record.getMessage() and "pre-processing" not in record.getMessage()

        root = logging.getLogger()  # where the quantizer logs it
        root.addFilter(advice)
        try:
            with tempfile.TemporaryDirectory(prefix="spinemocap-int8-") as tmp:
                src, dst = Path(tmp) / "float32.onnx", Path(tmp) / "int8.onnx"
                src.write_bytes(model_bytes)
                quantize_static(str(src), str(dst), _Reader(), quant_format=QuantFormat.QDQ, per_channel=False,
                                reduce_range=reduce_range,
                                activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                                calibrate_method=CalibrationMethod.MinMax)
                _INT8[key] = dst.read_bytes()
        finally:
            root.removeFilter(advice)
    return _INT8[key]


def to_tensor(images_bgr: np.ndarray | torch.Tensor) -> torch.Tensor:
    """uint8 (H, W, 3) or (B, H, W, 3) BGR -> float (B, 3, H, W) in [-0.5, 0.5], on the device of
    the input (a uint8 tensor already on the GPU is converted there)."""
    t = images_bgr if isinstance(images_bgr, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(images_bgr))
    if t.ndim == 3:
        t = t[None]
    return t.permute(0, 3, 1, 2).float() / 255.0 - 0.5


def pad_to_multiple(image: np.ndarray, multiple: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Pad (H, W, ...) at the bottom/right by edge replication to multiples of ``multiple``;
    returns the padded array and the original (H, W)."""
    h, w = image.shape[:2]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph or pw:
        pad = [(0, ph), (0, pw)] + [(0, 0)] * (image.ndim - 2)
        image = np.pad(image, pad, mode="edge")
    return image, (h, w)


def save_weights(model: TapeUNet, path, metadata: dict | None = None) -> None:
    """Store the state dict and architecture (atomically) in a ``.pt`` file."""
    from ..fileio import atomic_write

    payload = {"channels": list(model.channels), "state_dict": model.state_dict(), "metadata": metadata or {}}
    with atomic_write(path, "wb") as handle:
        torch.save(payload, handle)


def load_weights(path) -> tuple[TapeUNet, dict]:
    """Load a ``.pt`` file written by :func:`save_weights` (or a training checkpoint); returns
    the model in eval mode and its metadata. Raises InputError naming the file when unreadable."""
    from pathlib import Path

    from ..fileio import InputError

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "weights file not found")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        model = TapeUNet(tuple(payload["channels"]))
        model.load_state_dict(payload["state_dict"] if "state_dict" in payload else payload["model"])
    except Exception as exc:  # torch raises many types for a damaged or foreign file
        raise InputError(path, f"not a spinemocap segmentation weights file ({exc.__class__.__name__}: {exc})") from exc
    model.eval()
    return model, dict(payload.get("metadata", {}))
