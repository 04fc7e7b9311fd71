"""``spinemocap synth --vicon``: record a virtual Vicon on the studio's body and write
``vicon.c3d`` (Vicon frame and clock) and the truth into ``groundtruth.npz``.

Application layer: wires the studio (:mod:`spinemocap.synth`) to the body model package
(:mod:`spinemocap.bodymodel.virtual_vicon`) and the exporters.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

import exporters

from ..bodymodel.anny_body import PHENOTYPE_KEYS, AnnyModel
from ..bodymodel.base import RestBody
from ..bodymodel.tape import lay_tape
from ..bodymodel.virtual_vicon import ViconSetup, VirtualVicon, record
from ..fileio import atomic_path
from ..markers import MarkerTable
from ..synth.motions import spine_motion
from ..synth.scene import build_scene


def studio_rest_body(scene) -> RestBody:
    """The studio's body at rest as a :class:`RestBody` (anny's zero pose lifted onto the floor,
    identical to ``scene.body.rest_vertices``)."""
    shape = np.array([scene.body.phenotype[k] for k in PHENOTYPE_KEYS])
    rest = AnnyModel().rest(shape)
    lift = scene.body.floor_offset
    return dataclasses.replace(rest, vertices=rest.vertices + lift, spine_chain=rest.spine_chain + lift,
                               joints={k: v + lift for k, v in rest.joints.items()})


def record_scene(scene, setup: ViconSetup | None = None) -> VirtualVicon:
    """Record the virtual Vicon over a built studio scene's duration."""
    rest = studio_rest_body(scene)
    laid = lay_tape(rest, scene.tape, scene.config.tape_start)
    return record(rest, laid, lambda t: scene.body.pose(spine_motion(scene.config.motion, t))[0],
                  scene.n_frames / scene.fps, setup)


def write_virtual_vicon(config, out: str | os.PathLike, setup: ViconSetup | None = None) -> VirtualVicon:
    """Record the virtual Vicon for a studio configuration whose capture is in ``out``; write
    ``out/vicon.c3d`` and add the ``vicon_*`` truth to ``out/groundtruth.npz``."""
    scene = build_scene(config)
    try:
        vicon = record_scene(scene, setup)
    finally:
        scene.close()
    out = Path(out)
    first = round(vicon.time_s[0] * vicon.setup.rate_hz)
    table = MarkerTable.from_arrays(vicon.labels, vicon.positions, vicon.setup.rate_hz, first_frame=first,
                                    meta={"subject": "studio", "source": "virtual Vicon (spinemocap synth --vicon)"})
    exporters.write(table, out / "vicon.c3d")
    gt_path = out / "groundtruth.npz"
    with np.load(gt_path) as existing:
        arrays = {k: existing[k] for k in existing.files}
    arrays.update(vicon.groundtruth())
    with atomic_path(gt_path) as tmp:
        np.savez_compressed(tmp, **arrays)
    return vicon
