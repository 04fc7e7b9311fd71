"""What the detector found, drawn over the image it looked at (``spinemocap detector run``).

:func:`draw_detections` outlines the tape mask (green), marks each dot with a red cross and a
circle whose size follows its confidence, and writes the counts (dots, tape regions, the mask's
share of the image) in a banner at the top, so that a lab sees at a glance whether a camera's
view shows the tape and nothing else.
"""

from __future__ import annotations

import cv2
import numpy as np

MASK_COLOUR = (0, 255, 0)  # BGR
DOT_COLOUR = (0, 0, 255)
TEXT_COLOUR = (255, 255, 255)


def draw_detections(image: np.ndarray, mask: np.ndarray, uv: np.ndarray, confidence: np.ndarray | None = None,
                    title: str = "") -> np.ndarray:
    """A copy of ``image`` (BGR uint8 (H, W, 3), or grey (H, W)) with the outline of ``mask``
    ((H, W) bool), the dots ``uv`` ((N, 2) px, x y; ``confidence`` (N,) in [0, 1]) and a banner
    ``title: N dots, K tape regions, mask P % of the image``. Line widths scale with the image."""
    out = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    h, w = out.shape[:2]
    thick = max(1, round(min(h, w) / 600))
    contours, _ = cv2.findContours(np.ascontiguousarray(mask, np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(out, contours, -1, MASK_COLOUR, thick)
    conf = np.ones(len(uv)) if confidence is None else np.asarray(confidence, float)
    size = max(7, round(min(h, w) / 80))
    for (u, v), c in zip(np.asarray(uv, float).reshape(-1, 2), conf):
        centre = (int(round(u)), int(round(v)))
        cv2.drawMarker(out, centre, DOT_COLOUR, cv2.MARKER_CROSS, size, thick)
        cv2.circle(out, centre, max(2, int(round(size * (0.3 + 0.4 * float(np.clip(c, 0, 1)))))), DOT_COLOUR, thick)
    share = 100.0 * float(np.count_nonzero(mask)) / max(mask.size, 1)
    label = f"{title + ': ' if title else ''}{len(uv)} dots, {len(contours)} tape regions, mask {share:.2f} % of the image"
    scale = max(0.4, min(h, w) / 900)
    (tw, th), base = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    cv2.rectangle(out, (0, 0), (min(w, tw + 10), th + base + 10), (0, 0, 0), -1)
    cv2.putText(out, label, (5, th + 5), cv2.FONT_HERSHEY_SIMPLEX, scale, TEXT_COLOUR, thick, cv2.LINE_AA)
    return out
