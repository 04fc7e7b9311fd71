"""spinemocap: 3D spine motion capture from perforated kinesiology tape.

Public API (loaded on first use, so ``import spinemocap`` stays light)::

    import spinemocap
    table = spinemocap.track_capture("capture/", "out/")   # markers.csv/.trc/.c3d, MarkerTable (mm)
    capture = spinemocap.Capture.open("capture/")          # rig, tape, frames, ground truth
    rig = spinemocap.Rig.from_toml("rig.toml")
    result = spinemocap.run_batch("study/", "results/")    # every trial of a study: BatchResult
    failed = [t.summary.key for t in result.failed]        # (TrialOutcome: summary, skipped)

Layers (docs/ARCHITECTURE.md): core types in this package's top-level modules (:mod:`camera`,
:mod:`tape`, :mod:`markers`, :mod:`capture`, :mod:`views`, :mod:`geometry`, :mod:`fileio`,
:mod:`timing`) <- domain packages (:mod:`detect`, :mod:`track`, :mod:`synth`, :mod:`analysis`,
and the top-level ``calibration`` and ``exporters``) <- the application layer (:mod:`app`,
:mod:`bench`, :mod:`commands`).

Conventions: millimetres, world Z up, seconds, pixels; cameras are OpenCV pinhole models with
world->camera pose ``x_c = R x_w + t``.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from .version import __version__

if TYPE_CHECKING:  # the lazily loaded public names, visible to type checkers and IDEs
    from .app.batch import run_batch as run_batch
    from .app.report import write_report as write_report
    from .app.run import run_tracking as run_tracking
    from .app.run import track_capture as track_capture
    from .camera import Camera as Camera
    from .camera import Rig as Rig
    from .capture import Capture as Capture
    from .fileio import InputError as InputError
    from .markers import MarkerTable as MarkerTable
    from .tape import TapeSpec as TapeSpec
    from .track.config import TrackerConfig as TrackerConfig
    from .track.pipeline import FrameTracker as FrameTracker
    from .views import ViewDots as ViewDots

# public name -> module that defines it (imported on first access)
_PUBLIC = {
    "Camera": "spinemocap.camera",
    "Rig": "spinemocap.camera",
    "TapeSpec": "spinemocap.tape",
    "MarkerTable": "spinemocap.markers",
    "Capture": "spinemocap.capture",
    "ViewDots": "spinemocap.views",
    "InputError": "spinemocap.fileio",
    "TrackerConfig": "spinemocap.track.config",
    "FrameTracker": "spinemocap.track.pipeline",
    "track_capture": "spinemocap.app.run",
    "run_tracking": "spinemocap.app.run",
    "run_batch": "spinemocap.app.batch",
    "write_report": "spinemocap.app.report",
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str) -> Any:
    if name in _PUBLIC:
        return getattr(import_module(_PUBLIC[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
