"""The detector the tracker calls: tape mask (instances) and dots, per camera image.

``Detector(name="net")`` (default) segments with the shipped network in two stages, never at full
resolution:

1. the whole frame reduced to 256 px wide -> coarse tape mask -> boxes around its components;
2. each box, padded by half its size and reduced to <= 256 px on its long side -> logits,
   bilinearly upsampled to the box at full resolution;
3. at full resolution (``refine=True``, :mod:`spinemocap.detect.refine`): components without a
   dot are dropped, dark dotted regions that continue the tape are added (the network can stop
   short where the tape bends or lies in shadow), and while the mask runs out of its box the
   box grows and steps 2-3 repeat, keeping only the network's answer that touches the tape
   followed so far; finally the outline is snapped onto the tape's edge.

``Detector(name="classical")`` uses :mod:`spinemocap.detect.classical` instead. Either way the
dots come from :func:`spinemocap.detect.blobs.find_dots` inside the mask.

``last_timings`` holds the seconds spent per stage in the latest call (for the benchmark).
"""

from __future__ import annotations

import os
import time
from importlib import resources
from pathlib import Path
from typing import Callable, NamedTuple

import cv2
import numpy as np
import torch

from ..capture import read_image, to_grey
from ..fileio import InputError
from ..views import ViewDots
from .blobs import BlobParams, fill_holes, find_dots, mask_box, merge_close
from .classical import segment_classical
from .dataset import CROP_PAD, WORK_WIDTH, crop_scale, frame_view
from .instances import kept_instances, split_instances, union
from .lattice import tape_regions
from .refine import RefineParams, components_touching, extend_along_tape
from .segnet import RUNTIMES, InferenceUNet, OnnxUNet, cpu_has_vnni, load_weights, pad_to_multiple, to_tensor

SHIPPED_WEIGHTS = "tape_unet_lab_mix.pt"  # the default: the studio's renders and the lab mix
STUDIO_WEIGHTS = "tape_unet.pt"  # shipped beside the default: trained on the studio's renders alone


class MaskDots(NamedTuple):
    """A camera image's tape mask (H, W) bool and the dots on it: ``uv`` (N, 2) px (x, y), ``confidence`` (N,);
    ``box``: a box holding every pixel of the mask (None: the mask may lie anywhere)."""

    mask: np.ndarray
    uv: np.ndarray
    confidence: np.ndarray
    box: tuple[slice, slice] | None = None

NAMES = ("net", "classical")
PRECISIONS = ("float32", "bfloat16", "int8")  # of the network's arithmetic


def shipped_weights_path(name: str = SHIPPED_WEIGHTS) -> Path:
    """Path of a weights file shipped inside the package (spinemocap/detect/weights/; default: the
    default weights, :data:`SHIPPED_WEIGHTS`)."""
    return Path(str(resources.files("spinemocap.detect").joinpath("weights").joinpath(name)))


class NetSegmenter:
    """Two-stage segmentation with :class:`TapeUNet` (see the module docstring). ``runtime``:
    what runs the network's passes, ``auto`` (ONNX Runtime for float32 on the CPU where
    onnxruntime and onnx import, else torch), ``onnxruntime`` or ``torch``."""

    def __init__(self, weights: str | os.PathLike | None = None, refine: bool = True, threads: int | None = 1,
                 min_area_work_px: int = 4, box_logit: float = -1.0, max_grow: int = 3,
                 refine_params: RefineParams | None = None, device: str = "auto",
                 blob_params: BlobParams | None = None, precision: str = "float32", runtime: str = "auto"):
        self.weights_path = Path(weights) if weights else shipped_weights_path()
        net, self.metadata = load_weights(self.weights_path)
        # The inference form: batch norm folded into the convolutions, no concatenation copies,
        # channels-last weights (the layout of to_tensor's input); the same logits up to float
        # rounding, ~19 % less CPU per pass in the detector.
        self.model = InferenceUNet(net)
        auto = precision == "auto"
        if auto:
            precision = auto_precision(device, runtime)
        if precision not in PRECISIONS:
            raise InputError(None, f"unknown network precision {precision!r} (choose auto, {', '.join(PRECISIONS)})")
        # bfloat16 (an option, not the default): ~45 % less CPU per pass on a CPU with AVX-512 BF16,
        # but a few dots change. int8 (an option, not the default):
        # ONNX Runtime's int8 kernels on the CPU, calibrated on drawn tapes; a few dots change, and
        # int8 kernels differ between CPUs (VNNI or not).
        self.precision = precision
        self.dtype = torch.bfloat16 if precision == "bfloat16" else torch.float32
        self.refine = refine  # False: stage 1 only, upsampled (a quick look; no boxes)
        self.threads = threads
        self.min_area_work_px = min_area_work_px
        self.box_logit = box_logit  # stage-1 logit threshold for boxes (-1: p > 0.27)
        self.max_grow = max_grow    # times a box may grow to follow the tape out of it
        self.refine_params = refine_params or RefineParams()
        self.blob_params = blob_params or BlobParams()  # the clean-up's dots are the detector's
        self.device = torch.device(resolve_device(device))
        self.model = self.model.to(device=self.device, dtype=self.dtype)
        # The runtime of the passes: ONNX Runtime for float32 on the CPU (14-22 % less CPU per pass,
        # the same dots), else torch (the GPU, bfloat16, and the
        # fallback where onnxruntime/onnx cannot be imported or the export fails). ``self.runtime``
        # says which runs.
        if runtime not in RUNTIMES:
            raise InputError(None, f"unknown network runtime {runtime!r} (choose {', '.join(RUNTIMES)})")
        self.onnx: OnnxUNet | None = None
        if precision == "int8" and (runtime == "torch" or self.device.type != "cpu"):
            raise InputError(None, f"network precision 'int8' runs on ONNX Runtime on the CPU only "
                                   f"(asked: runtime {runtime} on {self.device})")
        if runtime != "torch" and self.device.type == "cpu" and self.dtype == torch.float32:
            # int8 asked for: no silent fallback to float32 (the caller chose the arithmetic)
            explicit = runtime == "onnxruntime" or (precision == "int8" and not auto)
            try:
                self.onnx = self._onnx_session(threads, auto)
            except ImportError as exc:
                if explicit:
                    raise InputError(None, f"network runtime 'onnxruntime' asked for, but {exc.name or exc} "
                                           "cannot be imported (pip install onnxruntime onnx)") from exc
            except Exception as exc:  # the exporter or ONNX Runtime refused (another torch or ORT version)
                import warnings

                if explicit:
                    raise InputError(None, f"network runtime 'onnxruntime' ({precision}) failed to load the network "
                                           f"({exc.__class__.__name__}: {exc})") from exc
                warnings.warn(f"ONNX Runtime could not load the network ({exc.__class__.__name__}: {exc}); "
                              "the network runs on torch (same dots, more CPU)", RuntimeWarning, stacklevel=2)
        elif runtime == "onnxruntime":
            raise InputError(None, "network runtime 'onnxruntime' runs float32 on the CPU only "
                                   f"(asked: {precision} on {self.device})")
        self.runtime = "onnxruntime" if self.onnx is not None else "torch"
        # wall seconds spent in the network's passes so far, the copies to and from the device
        # included (the copy back waits for the device): the detection budget's network share
        self.network_s = 0.0

    def _onnx_session(self, threads: int | None, auto: bool) -> OnnxUNet:
        """The ONNX Runtime session in ``self.precision``; int8 chosen by ``auto`` falls back to
        float32, with a RuntimeWarning, when it cannot load (int8 asked for raises)."""
        if self.precision == "int8" and auto:
            try:
                return OnnxUNet(self.model, threads, precision="int8")
            except Exception as exc:
                import warnings

                warnings.warn(f"the network's int8 arithmetic could not load ({exc.__class__.__name__}: {exc}); "
                              "it runs in float32", RuntimeWarning, stacklevel=3)
                self.precision = "float32"
        return OnnxUNet(self.model, threads, precision="int8" if self.precision == "int8" else "float32")

    def _use_threads(self) -> None:
        """torch's threads for this calling thread, set only when they differ: a
        ``torch.set_num_threads`` call slows the network passes after it (~3 ms, ~20 %,
        per pass when set before every pass)."""
        if self.threads and torch.get_num_threads() != self.threads:
            torch.set_num_threads(self.threads)

    def _logits(self, view: np.ndarray) -> np.ndarray:
        return self._logits_batch(view[None])[0]

    def _logits_batch(self, views: np.ndarray) -> np.ndarray:
        """Logits (B, h, w) of equally sized BGR views (B, h, w, 3) in one network pass."""
        start = time.perf_counter()
        padded, (h, w) = pad_to_multiple(np.moveaxis(views, 0, 2), self.model.stride)
        padded = np.moveaxis(padded, 2, 0)
        if self.onnx is not None:
            logits = self.onnx(padded)[:, :h, :w]
        else:
            with torch.inference_mode():
                # the uint8 pixels travel to the device (a quarter of float32's bytes), converted there
                pixels = torch.from_numpy(np.ascontiguousarray(padded)).to(self.device)
                out = self.model(to_tensor(pixels).to(self.dtype))[:, 0, :h, :w]
                logits = out.float().cpu().numpy()
        self.network_s += time.perf_counter() - start
        return logits

    def __call__(self, image: np.ndarray) -> np.ndarray:
        self._use_threads()
        if not self.refine:
            h, w = image.shape[:2]
            view, _ = frame_view(image)
            return cv2.resize(self._logits(view), (w, h), interpolation=cv2.INTER_LINEAR) > 0
        return self.segment_boxes(image, self.tape_boxes([image])[0]).mask

    def tape_boxes(self, images: list[np.ndarray]) -> list[list[tuple[slice, slice]]]:
        """Stage 1 on several images at once (one batched network pass per image size): per
        image, the padded full-resolution boxes around the coarse mask's components."""
        self._use_threads()
        views = [frame_view(image)[0] for image in images]
        out: list[list[tuple[slice, slice]]] = [[] for _ in images]
        by_shape: dict[tuple, list[int]] = {}
        for i, view in enumerate(views):
            by_shape.setdefault(view.shape, []).append(i)
        for idx in by_shape.values():
            logits = self._logits_batch(np.stack([views[i] for i in idx]))
            for i, coarse_logits in zip(idx, logits):
                out[i] = self._coarse_boxes(coarse_logits, images[i].shape[:2])
        return out

    def _coarse_boxes(self, coarse_logits: np.ndarray, shape: tuple[int, int]) -> list[tuple[slice, slice]]:
        # Boxes come from a generous threshold: a thin stripe may be faint at 256 px, and stage 2
        # decides anyway.
        h, w = shape
        coarse = coarse_logits > self.box_logit
        n, _, stats, _ = cv2.connectedComponentsWithStats(coarse.astype(np.uint8), connectivity=8)
        sx, sy = w / coarse.shape[1], h / coarse.shape[0]
        return [padded_box(x * sx, y * sy, (x + bw) * sx, (y + bh) * sy, (h, w))
                for x, y, bw, bh, area in stats[1:] if area >= self.min_area_work_px]

    def segment_boxes(self, image: np.ndarray, boxes: list[tuple[slice, slice]], grey: np.ndarray | None = None) -> MaskDots:
        """Stages 2-3 (network per box, growth, full-resolution clean-up) in the given boxes:
        the tape mask (H, W) bool and the dots the clean-up found in it (uv (N, 2) full-frame px,
        confidence (N,); the detector's dots, found once). Stage 1's boxes give the full search;
        a box predicted from earlier frames skips stage 1 (sequence mode). ``grey``: ``image``'s
        grey levels when at hand (the clean-up reads only those)."""
        self._use_threads()
        source = image if grey is None else grey
        h, w = image.shape[:2]
        mask = np.zeros((h, w), bool)
        uvs, confs = [], []
        y0, x0, y1, x1 = h, w, 0, 0  # the final boxes' union: the mask lies there
        for box in boxes:
            part = extend_along_tape(source[box], self._net_mask(image, box), self.refine_params, self.blob_params)
            for _ in range(self.max_grow):
                grown = _grown_box(part.mask, box, (h, w))
                if grown is None:
                    break
                so_far = _moved(part.mask, box, grown)  # the tape runs out of the box: follow it
                seen = components_touching(self._net_mask(image, grown), so_far)
                part = extend_along_tape(source[grown], so_far | seen, self.refine_params, self.blob_params)
                box = grown
            mask[box] |= part.snapped  # part belongs to the final box
            uvs.append(part.uv + [box[1].start, box[0].start])
            confs.append(part.confidence)
            y0, x0 = min(y0, box[0].start), min(x0, box[1].start)
            y1, x1 = max(y1, box[0].stop), max(x1, box[1].stop)
        if not uvs:
            return MaskDots(mask, np.zeros((0, 2)), np.zeros(0), (slice(0, 0), slice(0, 0)))
        uv, conf = np.concatenate(uvs), np.concatenate(confs)
        if len(uvs) > 1:  # boxes may overlap: a dot must not be reported twice (as find_dots merges regions)
            uv, conf = merge_close(uv, conf, self.blob_params.merge_distance * 4.0)
        return MaskDots(mask, uv, conf, (slice(y0, y1), slice(x0, x1)))

    def _net_mask(self, image: np.ndarray, box: tuple[slice, slice]) -> np.ndarray:
        """Stage 2: the network's tape mask (bool, box size, holes filled) of one box."""
        crop = image[box]
        s = crop_scale(box, WORK_WIDTH)
        ch, cw = crop.shape[:2]
        small = cv2.resize(crop, (max(8, int(round(cw * s))), max(8, int(round(ch * s)))), interpolation=cv2.INTER_AREA) if s < 1 else crop
        logits = self._logits(small)
        # The tape's mask covers its dots: fill any holes the network leaves at them.
        return fill_holes(cv2.resize(logits, (cw, ch), interpolation=cv2.INTER_LINEAR) > 0)


def auto_precision(device: str = "auto", runtime: str = "auto") -> str:
    """The network's arithmetic for ``precision="auto"``: ``int8`` (ONNX Runtime) where the
    network runs on a CPU with VNNI through ONNX Runtime (~37 % less CPU per pass, the same
    accuracy on the 100-frame studio capture), else ``float32``
    (a GPU, torch asked for, a CPU without VNNI: its int8 speed is unmeasured, or onnxruntime
    missing)."""
    import importlib.util

    if runtime == "torch" or resolve_device(device) != "cpu" or not cpu_has_vnni():
        return "float32"
    return "int8" if importlib.util.find_spec("onnxruntime") is not None else "float32"


def resolve_device(device: str = "auto") -> str:
    """``auto`` -> ``cuda`` when torch sees a CUDA GPU, else ``cpu``; ``cpu`` and ``cuda[:N]`` pass
    through. InputError naming the parameter ``device`` for another name, or ``cuda`` where
    torch sees no CUDA GPU."""
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cpu":
        return device
    if not device.startswith("cuda"):
        raise InputError("device", f"unknown device {device!r} (choose auto, cpu or cuda)")
    if not torch.cuda.is_available():
        raise InputError("device", f"device {device!r} asked for, but torch sees no CUDA GPU "
                                   f"(torch {torch.__version__}); choose cpu or auto")
    return device


def _moved(part: np.ndarray, box: tuple[slice, slice], grown: tuple[slice, slice]) -> np.ndarray:
    """``part`` (mask of ``box``) placed into a mask of the larger box ``grown``."""
    out = np.zeros((grown[0].stop - grown[0].start, grown[1].stop - grown[1].start), bool)
    out[box[0].start - grown[0].start:box[0].stop - grown[0].start,
        box[1].start - grown[1].start:box[1].stop - grown[1].start] = part
    return out


def _grown_box(part: np.ndarray, box: tuple[slice, slice], shape: tuple[int, int]) -> tuple[slice, slice] | None:
    """A larger box when the mask ``part`` touches an edge of ``box`` inside the frame, else None."""
    h, w = shape
    ys, xs = box
    touches = ((ys.start > 0 and part[0].any()) or (ys.stop < h and part[-1].any())
               or (xs.start > 0 and part[:, 0].any()) or (xs.stop < w and part[:, -1].any()))
    if not touches:
        return None
    rows, cols = np.flatnonzero(part.any(axis=1)), np.flatnonzero(part.any(axis=0))
    grown = padded_box(xs.start + cols[0], ys.start + rows[0], xs.start + cols[-1] + 1, ys.start + rows[-1] + 1, shape)
    union = (slice(min(ys.start, grown[0].start), max(ys.stop, grown[0].stop)),
             slice(min(xs.start, grown[1].start), max(xs.stop, grown[1].stop)))
    return None if union == box else union


def padded_box(x0: float, y0: float, x1: float, y1: float, shape: tuple[int, int]) -> tuple[slice, slice]:
    """Box grown like the training crops (:data:`CROP_PAD` x its size per side), clipped."""
    h, w = shape
    px, py = max(CROP_PAD * (x1 - x0), 8), max(CROP_PAD * (y1 - y0), 8)
    return (slice(max(0, int(y0 - py)), min(h, int(np.ceil(y1 + py)))),
            slice(max(0, int(x0 - px)), min(w, int(np.ceil(x1 + px)))))


class Detector:
    """Tape and dot detector for single camera images (BGR uint8, any size).

    Args:
        name: ``"net"`` (the shipped network) or ``"classical"``.
        blob_params: :class:`BlobParams` for the dots.
        lattice: :meth:`detect` keeps only the tape regions whose dots lie on the tape's lattice,
            and their dots (:func:`spinemocap.detect.lattice.tape_regions`); False keeps every
            region and dot found.
        **options: for ``"net"``: ``weights`` (path), ``refine`` (two-stage clean-up on/off),
            ``threads`` (the network's threads per pass; default 1, the tracker runs cameras in
            parallel; ``None``: the runtime's default), ``precision`` (``float32`` default,
            ``bfloat16`` on torch, ``int8`` on ONNX Runtime on the CPU, or ``auto``:
            :func:`auto_precision`), ``runtime`` (``auto``: ONNX Runtime for float32 on the CPU
            where it imports and the export loads, else torch with a RuntimeWarning;
            ``onnxruntime``; ``torch``), ``device``. For ``"classical"``: ``work_width``.

    Raises:
        ValueError: an unknown ``name``.
        TypeError: an unknown option.
        InputError: an unknown precision or runtime, or one that cannot run here.
    """

    def __init__(self, name: str = "net", blob_params: BlobParams | None = None, lattice: bool = True, **options):
        if name not in NAMES:
            raise ValueError(f"unknown detector {name!r}; choose from {list(NAMES)}")
        self.name = name
        self.lattice = lattice
        self.blob_params = blob_params or BlobParams()
        if name == "net":
            self._segment: NetSegmenter | Callable[[np.ndarray], np.ndarray] = NetSegmenter(blob_params=self.blob_params, **options)
        else:
            work_width = int(options.pop("work_width", 1600))
            if options:
                raise TypeError(f"unknown options for the classical detector: {sorted(options)}")
            self._segment = lambda image: segment_classical(image, work_width=work_width)
        self.last_timings: dict[str, float] = {}

    # -------------------------------------------------------------------- masks
    def instances(self, image_bgr: np.ndarray) -> list[np.ndarray]:
        """Tape instances: one (H, W) bool mask per separate stripe piece, largest first."""
        t = time.perf_counter()
        raw = self._segment(_check_image(image_bgr))
        out = split_instances(raw)
        self.last_timings["segment_s"] = time.perf_counter() - t
        return out

    def segment(self, image_bgr: np.ndarray, boxes: list[tuple[slice, slice]] | None = None) -> np.ndarray:
        """Tape mask (H, W) bool at full resolution: the union of :meth:`instances`.
        ``boxes`` (``net`` only): search only these full-resolution boxes (skips stage 1)."""
        if boxes is None:
            return union(self.instances(image_bgr), image_bgr.shape[:2])
        return self._segment_with_dots(_check_image(image_bgr), boxes).mask

    def _segment_with_dots(self, image_bgr: np.ndarray, boxes: list[tuple[slice, slice]],
                           grey: np.ndarray | None = None) -> MaskDots:
        """``net`` in ``boxes``: the tape mask (union of its kept instances) and the dots the
        clean-up found on it (those of dropped specks removed)."""
        if not isinstance(self._segment, NetSegmenter):
            raise ValueError("only the 'net' detector searches given boxes")
        t = time.perf_counter()
        found = self._segment.segment_boxes(image_bgr, boxes, grey)
        self.last_timings["cleanup_s"] = time.perf_counter() - t  # network passes of stage 2 included
        if found.box is None:
            mask = kept_instances(found.mask)
        else:  # the same instances, labelled within the searched boxes (the mask is empty outside them)
            mask = found.mask
            mask[found.box] = kept_instances(mask[found.box])
        on_mask = _on_mask(found.uv, mask, self.blob_params)
        uv, confidence = found.uv[on_mask], found.confidence[on_mask]
        if self.lattice:
            mask, on_tape = tape_regions(mask, uv, found.box)
            uv, confidence = uv[on_tape], confidence[on_tape]
        self.last_timings["segment_s"] = time.perf_counter() - t
        return MaskDots(mask, uv, confidence)

    @property
    def network_s(self) -> float:
        """Wall seconds this detector has spent in network passes (0 for ``classical``)."""
        return self._segment.network_s if isinstance(self._segment, NetSegmenter) else 0.0

    @property
    def searches_boxes(self) -> bool:
        """True when :meth:`segment` and :meth:`detect` accept ``boxes`` (the ``net`` detector)."""
        return isinstance(self._segment, NetSegmenter) and self._segment.refine

    def tape_boxes(self, images_bgr: list[np.ndarray]) -> list[list[tuple[slice, slice]]]:
        """Stage 1 of the ``net`` detector for several images in one batched network pass:
        per image the full-resolution boxes that :meth:`detect` then searches (``boxes=``)."""
        if not self.searches_boxes or not isinstance(self._segment, NetSegmenter):
            raise ValueError("only the 'net' detector with refine=True finds tape boxes")
        return self._segment.tape_boxes([_check_image(image) for image in images_bgr])

    # -------------------------------------------------------------------- dots
    def find_dots(self, image_bgr: np.ndarray, mask: np.ndarray, expected_dot_px: float | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Dots inside ``mask`` (``image_bgr`` may also be the grey image): ``uv`` (N, 2) sub-pixel px (x, y) and ``confidence`` (N,)."""
        t = time.perf_counter()
        out = find_dots(image_bgr, mask, expected_dot_px, self.blob_params)
        self.last_timings["dots_s"] = time.perf_counter() - t
        return out

    def detect(self, image_bgr: np.ndarray, camera: int = 0, expected_dot_px: float | None = None,
               boxes: list[tuple[slice, slice]] | None = None, grey_now: bool = True) -> ViewDots:
        """Mask + dots of one camera image as :class:`ViewDots` (with the grey image for MRF2).
        ``expected_dot_px``: dot diameter in px; estimated from the mask width when None.
        ``boxes``: search only there (``net``; from :meth:`tape_boxes` or predicted), else the whole image.
        ``grey_now=False``: the view holds the colour image and makes the grey one when it is first
        read (the same pixels; a tracker that reads it in few frames skips the conversion in the others)."""
        image_bgr = _check_image(image_bgr)
        if self.searches_boxes and expected_dot_px is None:
            # the clean-up finds the dots at full resolution: reuse them (one blob pass); it reads
            # the grey image when one is made now, else it converts only its boxes
            grey = to_grey(image_bgr) if grey_now else None
            found = self._segment_with_dots(image_bgr, boxes if boxes is not None else self.tape_boxes([image_bgr])[0], grey)
            self.last_timings["dots_s"] = 0.0  # inside segment_s
            if grey is None:
                return ViewDots(camera=camera, uv=found.uv, confidence=found.confidence, mask=found.mask, colour=image_bgr)
            return ViewDots(camera=camera, uv=found.uv, confidence=found.confidence, mask=found.mask, image=grey)
        grey = to_grey(image_bgr)  # once: the dots and MRF2 both use it
        mask = self.segment(image_bgr, boxes)
        uv, conf = self.find_dots(grey, mask, expected_dot_px)
        if self.lattice:
            mask, on_tape = tape_regions(mask, uv, mask_box(mask))
            uv, conf = uv[on_tape], conf[on_tape]
        return ViewDots(camera=camera, uv=uv, confidence=conf, mask=mask, image=grey)

    def detect_file(self, path: str | os.PathLike, camera: int = 0, expected_dot_px: float | None = None) -> ViewDots:
        """:meth:`detect` on an image file; a missing or corrupt file raises InputError naming it."""
        return self.detect(read_image(path), camera, expected_dot_px)


def _on_mask(uv: np.ndarray, mask: np.ndarray, blob_params: BlobParams) -> np.ndarray:
    """Which dots ``uv`` (N, 2) px lie on ``mask`` grown by the blob margin (of a 4 px dot at
    least: dots on the tape's edge count, as :func:`find_dots` counts them); False for those of
    components that were dropped."""
    if not len(uv):
        return np.zeros(0, bool)
    h, w = mask.shape
    ij = np.clip(np.round(uv).astype(int), 0, [w - 1, h - 1])
    if mask[ij[:, 1], ij[:, 0]].all():
        return np.ones(len(uv), bool)
    r = int(np.ceil(blob_params.margin * 4.0)) + 1
    ys = slice(max(0, ij[:, 1].min() - r), ij[:, 1].max() + r + 1)
    xs = slice(max(0, ij[:, 0].min() - r), ij[:, 0].max() + r + 1)
    grown = cv2.dilate(mask[ys, xs].view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return grown[ij[:, 1] - ys.start, ij[:, 0] - xs.start].astype(bool)


def _check_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise InputError(None, f"expected a BGR uint8 image (H, W, 3), got {image.dtype} {image.shape}")
    return image
