"""Training data for the tape network and its training (``spinemocap detector train|finetune``):
random studio scenes rendered by :mod:`spinemocap.synth`, cut into the network's views by
:mod:`spinemocap.detect.dataset` and saved as shards, or a lab's labelled images turned into
shards; then :func:`spinemocap.detect.train.train` on them. Application layer: it joins two domain
packages (synth renders, detect learns)."""

from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Sequence

import numpy as np
from tqdm import tqdm

from ..detect.dataset import import_labelled, load_shards, save_shard, views_of
from ..fileio import atomic_path
from ..synth import SynthConfig, build_scene
from ..synth.appearance import TAPE_COLOURS, lab_subject
from ..synth.motions import MOTIONS

if TYPE_CHECKING:
    from ..detect.train import TrainSettings

log = logging.getLogger(__name__)

AppearanceMix = Literal["studio", "lab"]


@dataclass
class SynthDataSettings:
    """How synthetic training data is drawn. Scene ``k`` uses studio seed ``seed * 1000 + k``;
    scenes whose index falls in the last ``val_fraction`` go to validation. Benchmarks use seeds
    from :data:`HELD_OUT_SEED_BASE` on, never touched here."""

    scenes: int = 60
    frames_per_scene: int = 2
    seed: int = 0
    val_fraction: float = 0.15
    layouts: tuple[str, ...] = ("tiny", "artificial", "studio")
    scale: float = 0.5   # render size relative to the layout's reference size (focal scales along)
    sequence_frames: int = 200  # frames are drawn from 2 s of motion at 100 fps (bent, twisted poses)
    appearance: AppearanceMix = "studio"  # 'lab': also tape colours, painted rooms and lab camera looks

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["layouts"] = list(self.layouts)
        return d


HELD_OUT_SEED_BASE = 900_000
# an appearance no training set may hold: the benchmark's held-out set (bench detect) shows it,
# in painted rooms and camera looks drawn from held-out seeds (training rooms come from its own)
HELD_OUT_FAMILY = {"tape_colour": "blue"}


def refuse_held_out(config: SynthConfig) -> None:
    """Raise ValueError when ``config`` renders any part of :data:`HELD_OUT_FAMILY`."""
    held = [f"{k}={v!r}" for k, v in HELD_OUT_FAMILY.items() if getattr(config, k) == v]
    if held:
        raise ValueError(f"training scenes may not render the benchmark's held-out appearance ({', '.join(held)}); "
                         "choose another tape colour, backdrop or camera look")
_REFERENCE_SIZE = {"tiny": (480, 360), "artificial": (1024, 768), "studio": (2448, 1600)}
_CAMERAS = {"tiny": 3, "artificial": 4, "studio": 6}


def random_scene_config(rng: np.random.Generator, seed: int, layouts=("tiny", "artificial", "studio"), scale: float = 0.5,
                        sequence_frames: int = 200):
    """A synthetic-studio configuration with a random body, skin tone, motion, blur, noise and
    occluders (lighting follows from the seed inside the studio)."""

    layout = str(rng.choice(list(layouts)))
    w, h = _REFERENCE_SIZE[layout]
    s = 1.0 if layout == "tiny" else scale
    phenotype = {k: float(rng.uniform(0.05, 0.95)) for k in ("gender", "age", "muscle", "weight", "height")}
    return SynthConfig.preset(
        layout, frames=int(sequence_frames), seed=seed, size=(int(w * s), int(h * s)),
        cameras=_CAMERAS[layout], phenotype=phenotype, skin_tone=float(rng.uniform(0, 1)),
        motion=str(rng.choice(sorted(MOTIONS))), blur=float(rng.choice([0.0, 0.0, 0.0, 0.4])),
        noise=float(rng.uniform(0.5, 5.0)), occlusion=str(rng.choice(["none", "none", "light", "heavy"])),
        band=bool(rng.random() < 0.2), rows=int(rng.choice([9, 11, 13])),
    )


def lab_appearance(config: SynthConfig, rng: np.random.Generator) -> SynthConfig:
    """``config`` with a lab's appearance drawn from ``rng``: a tape colour of
    :data:`TAPE_COLOURS` less :data:`HELD_OUT_FAMILY`'s (half black), a painted room behind the
    subject in half the scenes (one or two other people standing in half of those rooms), the
    ``lab`` camera look in two thirds (H.264 / H.265, rolling shutters among them); and from the
    scene's own stream the tape's roll and finish, the skin's marks and clothing
    (:func:`~spinemocap.synth.appearance.lab_subject`)."""
    colours = [c for c in TAPE_COLOURS if c != HELD_OUT_FAMILY["tape_colour"]]
    others = [c for c in colours if c != "black"]
    colour = "black" if rng.random() < 0.5 else str(rng.choice(others))
    subject = lab_subject(np.random.default_rng([config.seed, 79]))
    backdrop = "room" if rng.random() < 0.5 else "plain"
    people = int(np.random.default_rng([config.seed, 80]).choice(3, p=[0.5, 0.3, 0.2])) if backdrop == "room" else 0
    return dataclasses.replace(config, tape_colour=colour, backdrop=backdrop, bystanders=people,
                               camera_look="lab" if rng.random() < 2 / 3 else "ideal", **subject)


def vary_appearance(scene, rng: np.random.Generator) -> None:
    """Random background and tape colours (dark tapes of several hues) before the first render."""
    background = tuple(float(c) for c in rng.uniform(0.05, 0.9, 3))
    tape = tuple(float(c) for c in rng.uniform(0.02, 0.25, 3))
    scene.appearance = dataclasses.replace(scene.appearance, background_rgb=background, tape_rgb=tape)


def generate_synthetic(out: Path, settings: SynthDataSettings, progress: bool = True) -> Path:
    """Render ``settings.scenes`` scenes into shards under ``out`` (existing shards are kept:
    an interrupted run resumes where it stopped). Writes ``settings.json`` beside them."""

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "settings.json") as tmp:
        tmp.write_text(json.dumps(settings.to_dict(), indent=2))
    n_val = max(1, int(round(settings.scenes * settings.val_fraction)))
    for k in tqdm(range(settings.scenes), desc="rendering training scenes", unit="scene", disable=not progress):
        path = out / f"synth_{k:04d}.npz"
        if path.exists():
            continue
        seed = settings.seed * 1000 + k
        rng = np.random.default_rng([seed, 77])
        cfg = random_scene_config(rng, seed, settings.layouts, settings.scale, settings.sequence_frames)
        if settings.appearance == "lab":
            cfg = lab_appearance(cfg, rng)
        refuse_held_out(cfg)
        try:
            scene = build_scene(cfg)
        except ValueError as exc:  # no camera sees the tape: draw another time
            log.info("scene %d skipped: %s", k, exc)
            save_shard(path, [], "train", {"seed": seed, "skipped": str(exc)})
            continue
        if settings.appearance == "studio" or cfg.tape_colour == "black":
            vary_appearance(scene, rng)  # dark tapes of any hue (and plain backgrounds of any colour)
        views = []
        for f in rng.choice(cfg.frames, size=min(settings.frames_per_scene, cfg.frames), replace=False):
            rendered = scene.render(int(f))
            for img, m in zip(rendered.images, rendered.masks):
                if m is None:
                    raise RuntimeError("the scene rendered a view without its tape mask")
                views += views_of(img, m, rng)
        scene.close()
        split = "val" if k >= settings.scenes - n_val else "train"
        save_shard(path, views, split, {"seed": seed, "config": cfg.to_dict()})
    return out


def train_on_studio(out: Path, settings: TrainSettings, synth: SynthDataSettings, data: Sequence[Path] = (),
                    weights: Path | None = None, provenance: dict[str, Any] | None = None,
                    progress: bool = True) -> dict[str, Any]:
    """Render the studio's training data into the first folder of ``data`` (default ``out/data``;
    shards already there are kept), take the shards of every folder of ``data`` as they are, and
    train into ``out`` (from ``weights``, else from random weights; resumable). Returns the
    exported metadata (``out/weights.json``), ``provenance`` and the data's description in it."""
    from ..detect.train import train

    folders = list(data) or [Path(out) / "data"]
    generate_synthetic(folders[0], synth, progress)
    train_views, val_views = load_shards(folders[0])
    for extra in folders[1:]:
        more_train, more_val = load_shards(extra)
        train_views.extend(more_train)
        val_views.extend(more_val)
    log.info("%d training views, %d validation views from %s", len(train_views), len(val_views), folders)
    described = {"kind": "synthetic studio", **synth.to_dict(), "folders": [str(f) for f in folders],
                 "train_views": len(train_views), "val_views": len(val_views)}
    return train(train_views, val_views, out, settings, init_weights=weights,
                 provenance={**(provenance or {}), "data": described}, progress=progress)


def finetune_on_images(out: Path, settings: TrainSettings, images: Path, masks: Path | None = None,
                       coco: Path | None = None, val_fraction: float = 0.24, seed: int = 0,
                       weights: Path | None = None, provenance: dict[str, Any] | None = None,
                       progress: bool = True) -> tuple[dict[str, Any], int, int]:
    """Fine-tune the network (``weights``, default the shipped ones) on a lab's labelled
    ``images`` (PNG ``masks`` or ``coco`` polygons; :func:`spinemocap.detect.dataset.import_labelled`
    into ``out/data``, ``val_fraction`` of them for validation, split by ``seed``) into ``out``.
    Returns the exported metadata (``out/weights.json``) and the training and validation image
    counts."""
    from ..detect.detector import shipped_weights_path
    from ..detect.train import train

    data = Path(out) / "data"
    n_train, n_val = import_labelled(data, images, masks=masks, coco=coco, val_fraction=val_fraction, seed=seed)
    train_views, val_views = load_shards(data)
    described = {"kind": "lab", "images": str(images), "masks": str(masks) if masks else None,
                 "coco": str(coco) if coco else None, "train_images": n_train, "val_images": n_val}
    meta = train(train_views, val_views, out, settings, init_weights=weights or shipped_weights_path(),
                 provenance={**(provenance or {}), "data": described}, progress=progress)
    return meta, n_train, n_val


# ---------------------------------------------------------------------------------- lab data
