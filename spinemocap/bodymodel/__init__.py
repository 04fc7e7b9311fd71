"""Body models behind one interface (:class:`BodyModel`): ``anny`` (default, offline) and SMPL /
SMPL+H / SMPL-X through the optional ``smplx`` package and the user's own model files; a
MoSh-like marker fit (:mod:`.fit`), marker sets (:mod:`.markersets`), AMASS files (:mod:`.amass`)
and tapes laid on any body (:mod:`.tape`). Core-only imports.
"""

from __future__ import annotations

import os

from ..fileio import InputError
from .base import BodyModel, RestBody, SurfaceAnchors

MODELS = ("anny", "smpl", "smplh", "smplx")


def load_model(name: str = "anny", model_path: str | os.PathLike | None = None, gender: str = "neutral") -> BodyModel:
    """A body model by name (``anny`` needs nothing; the SMPL family needs ``model_path``)."""
    if name == "anny":
        from .anny_body import AnnyModel

        return AnnyModel()
    if name in MODELS:
        from .smpl_body import SmplModel

        return SmplModel(name, model_path, gender)
    raise InputError("model", f"unknown body model {name!r}; expected one of {MODELS}")


__all__ = ["MODELS", "BodyModel", "RestBody", "SurfaceAnchors", "load_model"]
