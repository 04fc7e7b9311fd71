"""An analytic tape on a bending rod: exact dot positions for a prescribed spine motion.

The reference for the angle definitions that needs no body model: the tape's midline is a rod
whose local frame (a, s, r) -- see :mod:`frames` -- turns at given rates per millimetre of
length: flexion about ``r`` (positive = forward), lateral bending about ``a`` (positive =
toward the right), axial twist about ``s`` (positive = toward the left). Integrating the rates
between two levels gives exactly the angles :func:`frames.cardan_angles` must report for a
single-axis motion, so tests can check the whole angle pipeline against closed-form numbers.
Dots sit at ``u`` along the rod's ``r`` axis (a flat strip, no skin curvature).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from ..fileio import atomic_write
from ..tape import TapeSpec
from .frames import neutral_frame

Rates = Callable[[np.ndarray], np.ndarray]


def bent_tape_dots(tape: TapeSpec, rates_deg_per_mm: Rates, up=(0.0, 0.0, 1.0),
                   facing=(0.0, -1.0, 0.0), origin_mm=(0.0, 0.0, 1000.0),
                   step_mm: float = 0.25) -> np.ndarray:
    """(D, 3) dot positions in mm (world). ``rates_deg_per_mm(v)`` maps rest positions ``v``
    (n,) along the tape to (n, 3) turning rates (flexion, lateral, twist) in deg/mm.
    Row 1 starts at ``origin_mm`` with the neutral frame of ``up``/``facing``."""
    graph = tape.graph
    v = np.arange(0.0, graph.uv_mm[:, 1].max() + step_mm, step_mm)
    increments = _increments(rates_deg_per_mm, v[:-1], step_mm)
    frames = np.empty((len(v), 3, 3))
    frames[0] = neutral_frame(np.asarray(up, float), np.asarray(facing, float))
    for k, inc in enumerate(increments):
        frames[k + 1] = frames[k] @ inc
    points = np.asarray(origin_mm, float) + np.concatenate([[np.zeros(3)], np.cumsum(frames[:-1, :, 1] * step_mm, axis=0)])
    k = np.clip(np.rint(graph.uv_mm[:, 1] / step_mm).astype(int), 0, len(v) - 1)
    return points[k] + frames[k][:, :, 2] * graph.uv_mm[:, :1]


def _increments(rates_deg_per_mm: Rates, v: np.ndarray, step_mm: float) -> np.ndarray:
    """(n, 3, 3) local turns of the rod over the steps starting at ``v``."""
    rates = np.asarray(rates_deg_per_mm(v), float).reshape(-1, 3) * step_mm
    return Rotation.from_euler("ZXY", np.column_stack([-rates[:, 0], rates[:, 1], rates[:, 2]]),
                               degrees=True).as_matrix()


def relative_turn(rates_deg_per_mm: Rates, v_from: float, v_to: float, step_mm: float = 0.25) -> np.ndarray:
    """(3, 3) rotation of the rod's frame at ``v_to`` relative to its frame at ``v_from``, in the
    lower frame's (a, s, r) axes: what :func:`frames.cardan_angles` of the two frames decomposes.
    (Turning about an axis that itself turns couples the axes: a laterally bent lordotic rod
    also twists, so a single-axis rate does not give a single-axis relative angle.)"""
    out = np.eye(3)
    for inc in _increments(rates_deg_per_mm, np.arange(v_from, v_to - 1e-9, step_mm), step_mm):
        out = out @ inc
    return out


def uniform_bend(v_from: float, v_to: float, angles_deg: np.ndarray,
                 background: npt.ArrayLike = (0.0, 0.0, 0.0)) -> Rates:
    """Rates that turn the rod by ``angles_deg`` (flexion, lateral, twist) spread evenly over
    ``v_from..v_to`` mm, on top of a constant ``background`` rate (deg/mm) everywhere."""
    angles = np.asarray(angles_deg, float)

    def rates(v: np.ndarray) -> np.ndarray:
        inside = ((v >= v_from) & (v < v_to)).astype(float)[:, None]
        return np.asarray(background, float) + inside * angles / (v_to - v_from)

    return rates


def smooth_bend(v_from: float, v_to: float, angles_deg: np.ndarray,
                background: npt.ArrayLike = (0.0, 0.0, 0.0)) -> Rates:
    """Rates that turn the rod by ``angles_deg`` in total over ``v_from..v_to`` mm with a
    raised-cosine profile (zero at both ends, most in the middle), plus a constant
    ``background`` rate: a bend without curvature steps, like a spine's."""
    angles = np.asarray(angles_deg, float)
    length = v_to - v_from

    def rates(v: np.ndarray) -> np.ndarray:
        x = np.clip((v - v_from) / length, 0.0, 1.0)
        weight = ((v >= v_from) & (v < v_to)) * (1 - np.cos(2 * np.pi * x)) / length
        return np.asarray(background, float) + weight[:, None] * angles

    return rates


def write_bent_capture(folder, tape: TapeSpec, peak_flexion_deg: float, n_frames: int = 30,
                       fps: float = 50.0, lumbar_span_mm: tuple[float, float] = (0.0, 150.0),
                       background=(0.1, 0.0, 0.0), hidden_rows: tuple[int, ...] = (),
                       hidden_frames: slice = slice(0)) -> None:
    """A capture folder whose ``groundtruth.npz`` holds this rod's exact dots: a flexion rising
    to ``peak_flexion_deg`` and back (half a sine) spread over ``lumbar_span_mm`` on top of a
    constant ``background`` rate (deg/mm). ``hidden_rows`` (1-based) are NaN over
    ``hidden_frames`` (an occlusion). Two placeholder cameras make it a valid capture; it has no
    images, so only ``--source groundtruth`` can analyse it. For tests and benchmarks of the
    batch machinery."""
    from pathlib import Path

    from ..camera import Camera, Rig
    from ..capture import Capture

    folder = Path(folder)
    rig = Rig([Camera.look_at(f"cam{i}", (i * 800.0 - 400, 2000, 1200), (0, 0, 1100), (64, 48), 80)
               for i in range(2)])
    subject = folder.parts[-3] if len(folder.parts) >= 3 else folder.name
    Capture(root=folder, name=folder.name, fps=fps, n_frames=n_frames, rig=rig, tape=tape,
            subject={"id": subject, "up": [0, 0, 1], "facing": [0, -1, 0]}).save()
    amplitude = peak_flexion_deg * np.sin(np.linspace(0, np.pi, n_frames))
    dots = np.array([bent_tape_dots(tape, uniform_bend(*lumbar_span_mm, np.array([a, 0.0, 0.0]), background))
                     for a in amplitude])
    columns = [k for k, label in enumerate(tape.labels) if int(label[1:3]) in hidden_rows]
    if columns:
        dots[hidden_frames, columns] = np.nan
    with atomic_write(folder / "groundtruth.npz", "wb") as handle:
        np.savez(handle, labels=np.array(tape.labels), dots=dots)
