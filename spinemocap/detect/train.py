"""Training and fine-tuning of the tape segmentation network.

One loop serves both: ``train`` starts from random weights, ``finetune`` from given weights
(usually the shipped ones) with a lower learning rate. Each epoch draws ``steps`` batches of
random ``crop`` x ``crop`` windows from the training views (most centred on tape), augments
them (flips, scale, colour, channel order, blur, noise), minimises BCE + soft Dice, then
measures IoU on the validation views at their full working size.

Resumable: ``OUT/checkpoint.pt`` holds model, optimiser, epoch, history and RNG state after
every epoch; running again with the same ``OUT`` continues. The best epoch (validation IoU) is
exported to ``OUT/weights.pt`` with ``OUT/weights.json`` (settings, data, command, history) and
a learning-curve plot ``OUT/training.png``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.nn import functional as F

from ..fileio import InputError, atomic_path, atomic_write
from .dataset import ViewSet
from .segnet import TapeUNet, load_weights, pad_to_multiple, save_weights, to_tensor

log = logging.getLogger(__name__)


@dataclass
class TrainSettings:
    """Hyper-parameters. ``steps`` batches per epoch; ``crop`` training window side in px."""

    epochs: int = 15
    steps: int = 60
    batch: int = 10
    crop: int = 112
    lr: float = 3e-3
    weight_decay: float = 1e-4
    seed: int = 0
    channels: tuple[int, ...] = (12, 16, 32, 48)
    tape_centred: float = 0.7   # share of windows centred on a tape pixel
    threads: int = 1   # small convolutions gain little from threads; on a shared CPU they lose

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["channels"] = list(self.channels)
        return d


# ---------------------------------------------------------------------------------- sampling
def _window(image: np.ndarray, mask: np.ndarray, size: int, rng: np.random.Generator, tape_centred: float):
    """A random ``size`` x ``size`` window (reflect-padded where the view is smaller)."""
    scale = float(np.exp(rng.uniform(np.log(0.7), np.log(1.4))))
    if abs(scale - 1) > 0.05:
        h, w = mask.shape
        dsize = (max(8, int(w * scale)), max(8, int(h * scale)))
        image = cv2.resize(image, dsize, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
        mask = cv2.resize(mask.astype(np.uint8), dsize, interpolation=cv2.INTER_NEAREST).astype(bool)
    h, w = mask.shape
    if h < size or w < size:
        ph, pw = max(0, size - h), max(0, size - w)
        pads = ((ph // 2, ph - ph // 2), (pw // 2, pw - pw // 2))
        image = np.pad(image, pads + ((0, 0),), mode="reflect")
        mask = np.pad(mask, pads, mode="reflect")
        h, w = mask.shape
    if rng.random() < tape_centred and mask.any():
        ys, xs = np.nonzero(mask)
        j = rng.integers(len(ys))
        cy, cx = ys[j] + rng.integers(-size // 4, size // 4 + 1), xs[j] + rng.integers(-size // 4, size // 4 + 1)
    else:
        cy, cx = rng.integers(0, h), rng.integers(0, w)
    y0 = int(np.clip(cy - size // 2, 0, h - size))
    x0 = int(np.clip(cx - size // 2, 0, w - size))
    return image[y0:y0 + size, x0:x0 + size], mask[y0:y0 + size, x0:x0 + size]


def augment(image: np.ndarray, mask: np.ndarray, rng: np.random.Generator):
    """Photometric and geometric augmentation of one uint8 window and its mask."""
    if rng.random() < 0.5:
        image, mask = image[:, ::-1], mask[:, ::-1]
    if rng.random() < 0.3:  # upside down: handstands, cameras mounted rotated
        image, mask = image[::-1], mask[::-1]
    x = image.astype(np.float32) / 255.0
    if rng.random() < 0.3:  # other tape / skin / background colours
        x = x[:, :, rng.permutation(3)]
    gain = rng.uniform(0.6, 1.4) * rng.uniform(0.85, 1.15, 3)
    x = np.clip(x * gain + rng.uniform(-0.1, 0.1), 0, 1) ** rng.uniform(0.7, 1.4)
    if rng.random() < 0.3:
        x = cv2.GaussianBlur(x, (0, 0), rng.uniform(0.5, 1.5))
    if rng.random() < 0.5:
        x = x + rng.normal(0, rng.uniform(0.005, 0.03), x.shape).astype(np.float32)
    return np.clip(x * 255, 0, 255).astype(np.uint8), np.ascontiguousarray(mask)


def sample_batch(views: ViewSet, s: TrainSettings, rng: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    images, masks = [], []
    for i in rng.integers(0, len(views), s.batch):
        img, m = _window(views.images[i], views.masks[i], s.crop, rng, s.tape_centred)
        img, m = augment(img, m, rng)
        images.append(img)
        masks.append(m)
    return to_tensor(np.stack(images)), torch.from_numpy(np.stack(masks)[:, None].astype(np.float32))


def loss_fn(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """BCE + soft Dice (Dice keeps thin, small tape masks from being ignored)."""
    bce = F.binary_cross_entropy_with_logits(logits, target)
    p = torch.sigmoid(logits)
    inter = (p * target).sum(dim=(1, 2, 3))
    dice = 1 - (2 * inter + 1) / (p.sum(dim=(1, 2, 3)) + target.sum(dim=(1, 2, 3)) + 1)
    return bce + dice.mean()


# ---------------------------------------------------------------------------------- validation
@torch.inference_mode()
def predict_view(model: TapeUNet, image: np.ndarray) -> np.ndarray:
    """Logits (h, w) float32 for one working-resolution view."""
    padded, (h, w) = pad_to_multiple(image, model.stride)
    return model(to_tensor(padded))[0, 0, :h, :w].numpy()


def evaluate(model: TapeUNet, views: ViewSet) -> dict:
    """IoU over all validation views pooled, and the mean of per-view IoU (views with tape)."""
    model.eval()
    inter = union = 0
    per_view = []
    for img, m in zip(views.images, views.masks):
        pred = predict_view(model, img) > 0
        i, u = int((pred & m).sum()), int((pred | m).sum())
        inter, union = inter + i, union + u
        if m.any():
            per_view.append(i / u)
    return {"iou": inter / max(union, 1), "mean_view_iou": float(np.mean(per_view)) if per_view else float("nan")}


# ---------------------------------------------------------------------------------- loop
def train(
    train_views: ViewSet,
    val_views: ViewSet,
    out: Path,
    settings: TrainSettings,
    init_weights: Path | None = None,
    provenance: dict | None = None,
    progress: bool = True,
) -> dict:
    """Train (or fine-tune from ``init_weights``) into ``out``; resumes from ``out/checkpoint.pt``.
    Returns the exported metadata (also written to ``out/weights.json``)."""
    from tqdm import tqdm

    if len(train_views) == 0:
        raise InputError(out, "no training views")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(settings.threads)
    torch.manual_seed(settings.seed)
    rng = np.random.default_rng(settings.seed)
    if init_weights is not None:
        model, _ = load_weights(init_weights)
    else:
        model = TapeUNet(settings.channels)
    opt = torch.optim.AdamW(model.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    total = settings.epochs * settings.steps
    history: list[dict] = []
    start = 0
    ckpt_path = out / "checkpoint.pt"
    if ckpt_path.is_file():
        ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        model = TapeUNet(tuple(ckpt["channels"]))
        model.load_state_dict(ckpt["model"])
        opt = torch.optim.AdamW(model.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
        opt.load_state_dict(ckpt["optimizer"])
        history, start = ckpt["history"], ckpt["epoch"]
        rng.bit_generator.state = ckpt["rng"]
        torch.set_rng_state(ckpt["torch_rng"])
        log.info("resuming %s at epoch %d", ckpt_path, start + 1)
    best = max((h["val_iou"] for h in history), default=-1.0)
    for epoch in range(start, settings.epochs):
        model.train()
        t0, losses = time.perf_counter(), []
        bar = tqdm(range(settings.steps), desc=f"epoch {epoch + 1}/{settings.epochs}", unit="batch",
                   disable=not progress, leave=False)
        for step in bar:
            for group in opt.param_groups:
                group["lr"] = learning_rate(epoch * settings.steps + step, total, settings.lr)
            x, y = sample_batch(train_views, settings, rng)
            loss = loss_fn(model(x), y)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.3f}")
        metrics = evaluate(model, val_views) if len(val_views) else {"iou": float("nan"), "mean_view_iou": float("nan")}
        row = {"epoch": epoch + 1, "loss": float(np.mean(losses)), "val_iou": metrics["iou"],
               "val_mean_view_iou": metrics["mean_view_iou"], "seconds": time.perf_counter() - t0}
        history.append(row)
        msg = f"epoch {epoch + 1}: loss {row['loss']:.4f}  val IoU {row['val_iou']:.4f} (mean per view {row['val_mean_view_iou']:.4f})  {row['seconds']:.0f} s"
        (tqdm.write if progress else log.info)(msg)
        if not row["val_iou"] <= best or math.isnan(row["val_iou"]):  # better, or no validation data
            best = row["val_iou"]
            save_weights(model, out / "best.pt")
        with atomic_path(ckpt_path) as tmp:
            torch.save({"channels": list(model.channels), "model": model.state_dict(), "optimizer": opt.state_dict(),
                        "epoch": epoch + 1, "history": history,
                        "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state()}, tmp)
    return export(out, settings, history, provenance or {}, init_weights)


def learning_rate(step: int, total: int, peak: float) -> float:
    """Linear warm-up over the first 10 % of steps, then cosine decay to 2 % of ``peak``. A
    function of the step alone, so a resumed run with more epochs simply stretches it."""
    warm = max(1, total // 10)
    if step < warm:
        return peak * (step + 1) / warm
    t = min(1.0, (step - warm) / max(1, total - warm))
    return peak * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * t)))


def export(out: Path, settings: TrainSettings, history: list[dict], provenance: dict, init_weights: Path | None) -> dict:
    """Best epoch -> ``weights.pt`` (with metadata inside) + ``weights.json`` + ``training.png``."""
    model, _ = load_weights(out / "best.pt")
    best = max(history, key=lambda h: -1 if math.isnan(h["val_iou"]) else h["val_iou"])
    meta = {
        "format": "spinemocap.detect.segnet/1",
        "best_epoch": best["epoch"], "val_iou": best["val_iou"],
        "train_settings": settings.to_dict(),
        "init_weights": str(init_weights) if init_weights else None,
        "history": history,
        **provenance,
    }
    save_weights(model, out / "weights.pt", meta)
    with atomic_write(out / "weights.json") as handle:
        json.dump(meta, handle, indent=2)
    plot_history(history, out / "training.png")
    return meta


def plot_history(history: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [h["epoch"] for h in history]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(epochs, [h["loss"] for h in history], "o-", label="training loss (BCE + Dice)")
    ax.plot(epochs, [h["val_iou"] for h in history], "s-", label="validation IoU")
    ax.set_xlabel("epoch")
    ax.set_ylim(0, max(1.05, max(h["loss"] for h in history)))
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title("tape segmentation training")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
