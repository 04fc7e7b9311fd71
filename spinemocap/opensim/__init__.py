"""OpenSim spine model and inverse kinematics from the tape markers (domain package).

Depends on the core modules only; the row-to-level map is passed in by the application layer.
``opensim`` (the optional extra ``spinemocap[opensim]``) is imported lazily:
:func:`~spinemocap.opensim.tools.require_opensim` says how to install it when absent.
"""

from .geometry import opensim_axes
from .pipeline import OpenSimResult, OpenSimSettings, run_opensim
from .summary import LabModelSummary, OpenSimSummary, SpineModelSummary, read_summary
from .tools import require_opensim

__all__ = ["LabModelSummary", "OpenSimResult", "OpenSimSettings", "OpenSimSummary", "SpineModelSummary",
           "opensim_axes", "read_summary", "require_opensim", "run_opensim"]
