"""The inverse-kinematics plot: a PNG of the region angles and the marker RMS, flagged frames
shaded red, whatever angle columns the model drives."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd

from spinemocap.opensim.plot import angles_plot_png
from spinemocap.opensim.summary import LabModelSummary


def _summary(flagged: list[int]) -> LabModelSummary:
    return LabModelSummary(frames=20, fps=10.0, marker_rms_mm=0.8, marker_rms_mm_max=1.4, ms_per_frame=30.0,
                           flagged_frames=flagged, flag_reasons={"marker RMS > 4 mm": len(flagged)} if flagged else {},
                           warnings=[], driven_joints=["L4_L5"], markers_by_body={"L4": ["R01L"]},
                           facing_error_deg=1.0, marker_weights={"R01L": 1.0}, model="lab.osim",
                           bodies_map={"L4": "lumbar4"})


def _angles(flagged: list[int], columns: tuple[str, ...]) -> pd.DataFrame:
    t = np.arange(20) / 10.0
    table = pd.DataFrame({"time": t, **{c: 10 * np.sin(t + k) for k, c in enumerate(columns)},
                          "marker_rms": 0.8 + 0.1 * np.cos(t), "flag": ""})
    table.loc[flagged, "flag"] = "marker RMS > 4 mm"
    return table


def _red_pixels(png: bytes) -> int:
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    b, g, r = (image[..., k].astype(int) for k in range(3))
    return int(((r > 200) & (g < 190) & (b < 190) & (r - g > 40)).sum())


def test_a_png_with_flagged_frames_shaded():
    columns = ("lumbar_flexion", "thoracic_flexion", "lumbar_lateral", "lumbar_rotation")
    clean = angles_plot_png(_angles([], columns), _summary([]))
    flagged = angles_plot_png(_angles([5, 12], columns), _summary([5, 12]))
    image = cv2.imdecode(np.frombuffer(clean, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (990, 990, 3)  # 9 x 9 in at 110 dpi
    assert _red_pixels(flagged) > _red_pixels(clean) + 5000  # a band a frame wide, not a hairline


def test_a_model_without_thoracic_columns_is_plotted():
    png = angles_plot_png(_angles([], ("lumbar_flexion",)), _summary([]))
    assert png.startswith(b"\x89PNG")
