"""The tape in 3D in the browser: one self-contained HTML file (``tape3d.html`` next to this
module is the page; the data goes in as JSON).

The page draws with the browser's 2D canvas and about 250 lines of its own JavaScript (a
perspective view turned by the mouse, a time slider and a play button): no library, no WebGL
(it draws the same in a headless browser without a GPU), no network (a Content-Security-Policy
forbids every fetch), nothing to install. Shown: the tracked dots in the video's colours
(:data:`~.tracked.CLASS_COLOURS_BGR`), the rows joined as lines, each dot's label, the cameras'
centres and optical axes, and the spine's levels (the capture's row-to-level map) beside the tape.

Every string from the user (subject, trial, camera names, labels) reaches the page either
escaped as HTML text or inside the JSON block, where ``<``, ``>``, ``&`` and the JavaScript line
separators are written as ``\\uXXXX`` escapes, so no name can end the script element; the
script shows names only through ``textContent`` and canvas text.
"""

from __future__ import annotations

import html
import json
import os
import re
from importlib import resources
from pathlib import Path

import numpy as np

from ...capture import Capture
from ...fileio import atomic_write
from .tracked import CLASS_COLOURS_BGR, CLASS_WORDS, TrackedDots, level_labels, read_tracked

TEMPLATE = "tape3d.html"
_JSON_ESCAPES = {"<": "\\u003c", ">": "\\u003e", "&": "\\u0026", "\u2028": "\\u2028", "\u2029": "\\u2029"}


def json_for_script(value) -> str:
    """``value`` as JSON that is safe inside an HTML ``<script>`` element (no ``</script>``,
    ``<!--`` or line separator can appear in it)."""
    text = json.dumps(value, ensure_ascii=False, allow_nan=False, separators=(",", ":"))
    return re.sub("[<>&\u2028\u2029]", lambda m: _JSON_ESCAPES[m.group(0)], text)


def viewer_data(capture: Capture, tracked: TrackedDots, frames: list[int]) -> dict:
    """The page's data for capture frames ``frames`` (all in ``tracked``): positions rounded to
    0.1 mm (null where missing), classes, flags, labels, rows, levels, cameras."""
    index = [tracked.index_of(f) for f in frames]
    positions = np.round(tracked.positions[index], 1).reshape(-1)
    levels, levels_from = level_labels(capture)
    cameras = [{"name": c.name, "centre": [round(float(v), 1) for v in c.center],
                "axis": [round(float(v), 4) for v in c.R[2]]} for c in capture.rig]
    subject = str(capture.subject.get("id", "") or "")
    return {
        "subtitle": (f"subject {subject}, " if subject else "") + f"{len(frames)} frames, {len(tracked.labels)} dots; "
                    f"levels from {os.path.basename(levels_from)}; drag to turn, wheel to zoom",
        "fps": playback_rate(tracked.times[index], capture.fps),
        "frames": [int(f) for f in frames],
        "times": [round(float(tracked.times[k]), 4) for k in index],
        "labels": list(tracked.labels),
        "row": [int(r) for r in tracked.row],
        "segments": tracked.row_segments().tolist(),
        "positions": [None if not np.isfinite(v) else float(v) for v in positions],
        "classes": tracked.classes[index].reshape(-1).astype(int).tolist(),
        "flagged": [bool(tracked.frame_flagged[k]) for k in index],
        "colours": {str(int(c)): "rgb({2},{1},{0})".format(*CLASS_COLOURS_BGR[c]) for c in CLASS_COLOURS_BGR},
        "classWords": {str(int(c)): CLASS_WORDS[c] for c in CLASS_WORDS},
        "levels": [[name, row] for name, row in levels.items()],
        "cameras": cameras,
        "up": [float(v) for v in capture.up],
        "facing": [float(v) for v in capture.facing],
    }


def playback_rate(times_s: np.ndarray, fps: float) -> float:
    """Frames per second that play ``times_s`` (the shown frames' times) at recorded speed;
    ``fps`` for a single frame."""
    span = float(times_s[-1] - times_s[0]) if len(times_s) > 1 else 0.0
    return (len(times_s) - 1) / span if span > 0 else fps


def render_page(title: str, data: dict) -> str:
    """The viewer page: the template with ``title`` (escaped) and ``data`` (script-safe JSON)."""
    template = resources.files(__package__).joinpath(TEMPLATE).read_text(encoding="utf-8")
    parts = {"TITLE": html.escape(title), "DATA": json_for_script(data)}
    return re.sub(r"__(TITLE|DATA)__", lambda m: parts[m.group(1)], template)


def write_viewer(capture_dir: str | os.PathLike, results: str | os.PathLike, out_path: str | os.PathLike,
                 frames: list[int] | None = None) -> Path:
    """Write the 3D viewer of ``results`` (a results folder or marker file) on the capture
    ``capture_dir`` to ``out_path`` (atomically); ``frames``: the capture frames to include
    (default every tracked frame). Returns the path."""
    capture = Capture.open(capture_dir)
    tracked = read_tracked(results, capture.tape)
    chosen = [int(f) for f in tracked.frames] if frames is None else list(frames)
    title = f"{capture.name}: tracked tape in 3D"
    page = render_page(title, viewer_data(capture, tracked, chosen))
    out = Path(out_path)
    with atomic_write(out) as handle:
        handle.write(page)
    return out

