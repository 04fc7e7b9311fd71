"""Synthetic studio: an anny body with perforated tape on its back, filmed by a virtual camera
rig, with occluders, rendered offscreen, and exact ground truth.

    from spinemocap.synth import SynthConfig, build_scene, write_capture
    scene = build_scene(SynthConfig.preset("tiny"))
    frame = scene.render(0)                 # .images (BGR), .masks (tape silhouettes)
    scene.groundtruth["dots"]               # (F, D, 3) mm
    write_capture(SynthConfig.preset("artificial", frames=20, occlusion="heavy"), "out")

Modules, in the order a scene is assembled: body (anny, phenotype, posing), motions,
tape_on_skin (laying and barycentric binding), rigs (camera layouts), occluders (balls, band),
visibility (ray casting), render (pyvista offscreen, exact OpenCV projection), scene (assembly,
ground truth), writer (capture folder). Heavy libraries load only when a scene is built.
"""

from .scene import RenderedFrame, Scene, SynthConfig, build_scene
from .writer import write_capture

__all__ = ["SynthConfig", "build_scene", "write_capture", "Scene", "RenderedFrame"]
