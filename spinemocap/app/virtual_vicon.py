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
from ..bodymodel.virtual_vicon import (
    TapeMarkers,
    ViconSetup,
    VirtualVicon,
    default_tape_rows,
    interleave_rows,
    record,
    tape_marker_layout,
)
from ..fileio import InputError, atomic_path
from ..markers import MarkerTable
from ..synth.motions import spine_motion
from ..synth.scene import build_scene
from ..synth.visibility import MeshRayCaster


def studio_rest_body(scene) -> RestBody:
    """The studio's body at rest as a :class:`RestBody` (anny's zero pose lifted onto the floor,
    identical to ``scene.body.rest_vertices``)."""
    shape = np.array([scene.body.phenotype[k] for k in PHENOTYPE_KEYS])
    rest = AnnyModel().rest(shape)
    lift = scene.body.floor_offset
    return dataclasses.replace(rest, vertices=rest.vertices + lift, spine_chain=rest.spine_chain + lift,
                               joints={k: v + lift for k, v in rest.joints.items()})


def studio_tape_markers(scene, radius_mm: float, beside_mm: float) -> TapeMarkers:
    """The Vicon markers on and beside the studio's own tape, as the studio lays it and strains the
    skin under it at every instant: each centre marker sits on the tape (its underside point, the
    tape's thickness and the marker's radius out along the tape's normal), so it moves with the
    studio's dots; the beside markers ride on the same strained skin chart beside the tape (beyond
    the chart's edge, extrapolated from it), their radius out along its normal."""
    tape = scene.tape_on_skin
    spec = tape.spec
    labels, centres, sides = tape_marker_layout(spec, default_tape_rows(spec), beside_mm)
    material = tape.material(np.concatenate([centres, sides.reshape(-1, 2)]))
    heights = np.concatenate([np.full(len(centres), spec.thickness_mm + radius_mm), np.full(2 * len(sides), radius_mm)])
    dots_z = tape.pose(scene.body.rest_vertices).dots()[:, 2]

    def points(time_s: float, vertices: np.ndarray, normals: np.ndarray) -> np.ndarray:
        posed = scene.posed_tape(time_s=time_s, posed=(vertices, normals))
        p = posed.points(material) + heights[:, None] * posed.normals(material)
        return interleave_rows(p[: len(centres)], p[len(centres) :])

    return TapeMarkers(labels, (float(dots_z.min()), float(dots_z.max())), points)


def body_ray_caster(faces: np.ndarray):
    """Posed vertices -> segment test against that body (the studio's ray caster,
    :class:`spinemocap.synth.visibility.MeshRayCaster`): the Vicon's occlusion test."""
    return lambda vertices: MeshRayCaster(vertices, faces).blocked


def record_scene(scene, setup: ViconSetup | None = None, occlusion: bool = True, progress: bool = False) -> VirtualVicon:
    """Record the virtual Vicon over a built studio scene's duration; its tape markers ride on the
    studio's own tape (skin strain included); ``occlusion``: markers the body hides from all but
    one of the Vicon's cameras gap (``setup.cameras``)."""
    setup = setup or ViconSetup()
    rest = studio_rest_body(scene)
    markers = studio_tape_markers(scene, setup.marker_diameter_mm / 2, setup.beside_mm)
    return record(rest, markers, lambda t: scene.body.pose(spine_motion(scene.config.motion, t))[0],
                  scene.n_frames / scene.fps, setup, ray_caster=body_ray_caster(rest.faces) if occlusion else None,
                  progress=progress)


def write_virtual_vicon(config, out: str | os.PathLike, setup: ViconSetup | None = None, wand_seconds: float = 4.0,
                        progress: bool = False) -> VirtualVicon:
    """Record the virtual Vicon for a studio configuration whose capture is in ``out``; write
    ``out/vicon.c3d`` and add the ``vicon_*`` truth to ``out/groundtruth.npz``; with
    ``wand_seconds`` > 0 also the wand wave that co-registers the rig with this Vicon
    (``out/wand/``, truth ``wand_*``; :mod:`spinemocap.app.wand_wave`)."""
    scene = build_scene(config)
    try:
        return write_scene_vicon(scene, out, setup, wand_seconds, progress)
    finally:
        scene.close()


def write_scene_vicon(scene, out: str | os.PathLike, setup: ViconSetup | None = None, wand_seconds: float = 4.0,
                      progress: bool = False) -> VirtualVicon:
    """:func:`write_virtual_vicon` for an already built studio scene."""
    from .wand_wave import write_wand_wave

    if wand_seconds < 0:
        raise InputError("wand_seconds", f"must be positive (got {wand_seconds:g}); 0 turns the wand wave off")
    setup = setup or ViconSetup()
    vicon = record_scene(scene, setup, progress=progress)
    wave = write_wand_wave(scene, setup, out, wand_seconds, progress) if wand_seconds > 0 else None
    out = Path(out)
    first = round(vicon.time_s[0] * vicon.setup.rate_hz)
    table = MarkerTable.from_arrays(vicon.labels, vicon.positions, vicon.setup.rate_hz, first_frame=first,
                                    meta={"subject": "studio", "source": "virtual Vicon (spinemocap synth --vicon)"})
    exporters.write(table, out / "vicon.c3d")
    gt_path = out / "groundtruth.npz"
    arrays: dict[str, np.ndarray] = {}
    if gt_path.exists():  # the studio's own truth is kept
        with np.load(gt_path) as existing:
            arrays = {k: existing[k] for k in existing.files}
    arrays.update(vicon.groundtruth())
    if wave is not None:
        arrays.update(wave.groundtruth())
    with atomic_path(gt_path) as tmp:
        np.savez_compressed(tmp, allow_pickle=False, **arrays)
    return vicon
