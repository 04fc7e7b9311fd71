"""Camera rigs of the synthetic studio: cameras on an arc behind the athlete.

The subject faces ``-Y``, so the back faces ``+Y``; azimuth 0 is straight behind (camera on the
``+Y`` side), positive azimuths toward the subject's left (``+X``). Cameras look at the tape's
rest centre. Each camera gets mild, seeded lens imperfections: radial/tangential distortion,
principal point a little off centre, fx and fy differing by a few per mille.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera, Rig


@dataclass(frozen=True)
class ArcLayout:
    """Cameras evenly spread over ``arc_deg`` behind the subject, ``radius_mm`` from the target
    (horizontal distance), ``elevations_deg`` cycled over the cameras, ``focal_px`` for images
    ``reference_width_px`` wide (scaled with the width of the actual images)."""

    arc_deg: float
    radius_mm: float
    elevations_deg: tuple[float, ...]
    focal_px: float
    reference_width_px: int


LAYOUTS = {
    "tiny": ArcLayout(arc_deg=60.0, radius_mm=1100.0, elevations_deg=(12.0,), focal_px=1150.0, reference_width_px=480),
    # The paper's Artificial experiment: 4 views that all see the whole tape when nothing occludes.
    "artificial": ArcLayout(arc_deg=70.0, radius_mm=2000.0, elevations_deg=(18.0, 8.0), focal_px=2300.0, reference_width_px=1024),
    # The paper's studio: 6 cameras, 180 degree arc, 2448x1600 (12 mm lens, 3.45 um pixels).
    "studio": ArcLayout(arc_deg=180.0, radius_mm=3000.0, elevations_deg=(5.0, 25.0), focal_px=3480.0, reference_width_px=2448),
}


def arc_rig(layout: ArcLayout, n_cameras: int, size: tuple[int, int], target_mm: np.ndarray,
            distortion: float, rng: np.random.Generator) -> Rig:
    """A rig of ``n_cameras`` on ``layout``'s arc, image ``size`` (W, H), looking at ``target_mm``.

    ``distortion`` scales the random lens distortion (0 = ideal pinhole, 1 = mild: about 1 % radial
    displacement at the image corners). The focal length scales with the image width, so a
    ``--size`` override keeps the framing.
    """
    if n_cameras < 1:
        raise ValueError(f"need at least one camera; got {n_cameras}")
    target = np.asarray(target_mm, float)
    azimuths = np.linspace(-layout.arc_deg / 2, layout.arc_deg / 2, n_cameras) if n_cameras > 1 else np.zeros(1)
    w, h = size
    cameras = []
    for k, az in enumerate(np.radians(azimuths)):
        el = np.radians(layout.elevations_deg[k % len(layout.elevations_deg)])
        direction = np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])
        position = target + layout.radius_mm / np.cos(el) * direction
        fx = layout.focal_px * w / layout.reference_width_px
        pp = ((w - 1) / 2 + rng.uniform(-0.01, 0.01) * w, (h - 1) / 2 + rng.uniform(-0.01, 0.01) * h)
        dist = distortion * np.array([
            rng.uniform(-0.10, -0.04), rng.uniform(0.0, 0.04),
            rng.normal(0, 5e-4), rng.normal(0, 5e-4), 0.0,
        ])
        cam = Camera.look_at(f"cam{k + 1}", position, target, size, fx, dist=dist, principal_point=pp)
        cam.K[1, 1] = fx * (1 + rng.uniform(-0.003, 0.003))
        cameras.append(cam)
    return Rig(cameras)

