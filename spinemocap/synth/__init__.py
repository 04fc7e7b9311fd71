"""Synthetic studio: an anny body with perforated tape on its back, filmed by a virtual camera
rig, with occluders, rendered offscreen, and exact ground truth.

    from spinemocap.synth import SynthConfig, build_scene, write_capture
    scene = build_scene(SynthConfig.preset("tiny"))
    frame = scene.render(0)                 # .images (BGR), .masks (tape silhouettes)
    scene.groundtruth["dots"]               # (F, D, 3) mm
    write_capture(SynthConfig.preset("artificial", frames=20, occlusion="heavy"), "out")

Modules, in the order a scene is assembled: body (anny, phenotype, posing, vertebral levels),
motions, tape_on_skin (the taut strip from the start level, taping tension, skin binding),
skin_strain (the Schober skin strain of a real back), rigs (camera layouts), lab_errors
(calibration and sync errors of the written rig), occluders (balls, band), visibility (ray
casting), render (pyvista offscreen, exact OpenCV projection), scene (assembly, realism levels,
ground truth), writer (capture folder); wand (a waved marker wand for calibration scenes). Heavy libraries load only when a scene is built.

Realism: ``SynthConfig(realism="ideal" | "skin" | "lab")``; ``skin`` (the default) has the
skin strain on, ``lab`` adds taping tension, calibration and sync errors and more sensor noise
(see :data:`spinemocap.synth.scene.REALISM_LEVELS`).
"""

from .scene import RenderedFrame, Scene, SynthConfig, build_scene
from .writer import write_capture

__all__ = ["SynthConfig", "build_scene", "write_capture", "Scene", "RenderedFrame"]
