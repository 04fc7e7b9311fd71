"""Plot of the inverse-kinematics spine angles (PNG bytes)."""

from __future__ import annotations

import io

import pandas as pd

from .summary import OpenSimSummary


def angles_plot_png(angles: pd.DataFrame, summary: OpenSimSummary) -> bytes:
    """Region angles (deg) over time, one panel per motion, marker RMS (mm) below; each flagged
    frame shaded over its frame interval (``1 / summary.fps`` s)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    t = angles["time"].to_numpy()
    for ax, motion in zip(axes, ("flexion", "lateral", "rotation")):
        for region, style in (("lumbar", "-"), ("thoracic", "--")):
            column = f"{region}_{motion}"
            if column in angles:
                ax.plot(t, angles[column], style, label=f"{region} (sum of driven joints)")
        ax.set_ylabel(f"{motion} (deg)")
        ax.axhline(0, color="0.7", lw=0.8)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper right", fontsize=8)
    axes[-1].plot(t, angles["marker_rms"], color="k", label="marker RMS")
    axes[-1].set_ylabel("marker RMS (mm)")
    axes[-1].set_xlabel("time (s)")
    flagged = angles["flag"].astype(str) != ""
    half_frame_s = 0.5 / summary.fps
    for ax in axes:
        for time_s in t[flagged.to_numpy()]:
            ax.axvspan(time_s - half_frame_s, time_s + half_frame_s, color="r", alpha=0.3, lw=0)
    axes[0].set_title(f"OpenSim IK: marker RMS {summary.marker_rms_mm:.2f} mm mean, "
                      f"{len(summary.flagged_frames)} flagged frames (red); zero = static posture")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return buffer.getvalue()
