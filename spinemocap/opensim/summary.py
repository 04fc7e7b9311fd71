"""What ``spinemocap opensim`` writes to ``summary.json``: :class:`SpineModelSummary` for the
project's spine model (:func:`spinemocap.opensim.pipeline.run_opensim`), :class:`LabModelSummary`
for a lab's own model (:func:`spinemocap.opensim.labmodel.run_lab_model`), both an
:class:`OpenSimSummary`.

``to_dict`` gives the JSON object written (keys in a fixed order; NaN is written as null by
:func:`spinemocap.fileio.strict_json`); ``from_dict`` reads one back and :func:`read_summary` reads
a written ``summary.json``. Units: lengths mm, angles deg, times ms or s as named; frames 0-based.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, cast

from ..fileio import InputError, reading
from .skin_model import SlipFromTape

JsonObject = dict[str, Any]
# what parsing a file that is no summary raises (turned into InputError)
_SUMMARY_ERRORS = (KeyError, TypeError, ValueError, AttributeError)
#: What ``skin_model.slip`` says when every marker is fixed to its vertebra (no slip).
NO_SLIP = "none: every marker fixed to its vertebra"


def _number(value: float | None) -> float:
    """A JSON number; null (written for NaN) back to NaN."""
    return math.nan if value is None else float(value)


def _numbers(values: Mapping[str, float | None]) -> dict[str, float]:
    return {str(key): _number(value) for key, value in values.items()}


@dataclass(frozen=True)
class Placement:
    """How far MarkerPlacer put the tape markers from their anatomical places over the spine (mm,
    over the placed markers): beside the spine (``lateral``, body Z), in front of / behind it
    (``depth``, body X), along it (``vertical``, body Y)."""

    lateral_median_mm: float
    lateral_max_mm: float
    depth_median_mm: float
    depth_max_mm: float
    vertical_median_mm: float

    def to_dict(self) -> JsonObject:
        return {"lateral_median_mm": self.lateral_median_mm, "lateral_max_mm": self.lateral_max_mm,
                "depth_median_mm": self.depth_median_mm, "depth_max_mm": self.depth_max_mm,
                "vertical_median_mm": self.vertical_median_mm}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Placement:
        return cls(lateral_median_mm=_number(data["lateral_median_mm"]), lateral_max_mm=_number(data["lateral_max_mm"]),
                   depth_median_mm=_number(data["depth_median_mm"]), depth_max_mm=_number(data["depth_max_mm"]),
                   vertical_median_mm=_number(data["vertical_median_mm"]))


@dataclass(frozen=True)
class Depth:
    """Where the joint centres sit under the skin: ``scale_on_published`` the factor on the
    published skin-to-vertebral-body depths (scaled to the subject by the tape), ``source`` where
    that factor comes from, ``depth_mm`` vertebra name -> depth used (mm, rounded to 0.1)."""

    scale_on_published: float
    source: str
    depth_mm: dict[str, float]

    def to_dict(self) -> JsonObject:
        return {"scale_on_published": self.scale_on_published, "source": self.source, "depth_mm": dict(self.depth_mm)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Depth:
        return cls(scale_on_published=_number(data["scale_on_published"]), source=str(data["source"]),
                   depth_mm=_numbers(data["depth_mm"]))


@dataclass(frozen=True)
class SlipSummary:
    """The rows' skin slip as modelled and solved: ``model`` the slip model in words, ``from_tape``
    how IK used the slip the tape shows, ``held_share`` the share (0..1) of (frame, slipping row)
    pairs whose slip was held at the tape's, ``pinned_rows`` the rows without slip (``R01`` ...),
    ``prior`` the prior in words, ``prior_weight_per_m2`` / ``estimate_weight_per_m2`` the IK goal
    weights (per m^2) where the tape does not / does show the slip, ``at_peak_mm`` slip coordinate
    -> the slip (mm, signed) in the frame where its magnitude peaks."""

    model: str
    from_tape: SlipFromTape
    held_share: float
    pinned_rows: list[str]
    prior: str
    prior_weight_per_m2: float
    estimate_weight_per_m2: float
    at_peak_mm: dict[str, float]

    def to_dict(self) -> JsonObject:
        return {"model": self.model, "from_tape": self.from_tape, "held_share": self.held_share,
                "pinned_rows": list(self.pinned_rows), "prior": self.prior,
                "prior_weight_per_m2": self.prior_weight_per_m2, "estimate_weight_per_m2": self.estimate_weight_per_m2,
                "at_peak_mm": dict(self.at_peak_mm)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SlipSummary:
        if data["from_tape"] not in ("held", "goal", "off"):
            raise ValueError(f"skin_model.slip.from_tape {data['from_tape']!r} is not held, goal or off")
        return cls(model=str(data["model"]), from_tape=cast(SlipFromTape, data["from_tape"]),
                   held_share=_number(data["held_share"]), pinned_rows=[str(r) for r in data["pinned_rows"]],
                   prior=str(data["prior"]), prior_weight_per_m2=_number(data["prior_weight_per_m2"]),
                   estimate_weight_per_m2=_number(data["estimate_weight_per_m2"]), at_peak_mm=_numbers(data["at_peak_mm"]))


@dataclass(frozen=True)
class SkinModelSummary:
    """The skin model's assumptions and what IK made of them: ``row_tilt`` in words,
    ``tilt_correction_max_deg`` row (``R01`` ...) -> the largest in-plane turn applied to it (deg;
    None when the tilt was kept as measured), ``slip`` the rows' slip (None: every marker fixed to
    its vertebra, written as :data:`NO_SLIP`)."""

    row_tilt: str
    tilt_correction_max_deg: dict[str, float] | None
    slip: SlipSummary | None

    def to_dict(self) -> JsonObject:
        out: JsonObject = {"row_tilt": self.row_tilt}
        if self.tilt_correction_max_deg is not None:
            out["tilt_correction_max_deg"] = dict(self.tilt_correction_max_deg)
        out["slip"] = self.slip.to_dict() if self.slip is not None else NO_SLIP
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SkinModelSummary:
        tilt = data.get("tilt_correction_max_deg")
        slip = data["slip"]
        return cls(row_tilt=str(data["row_tilt"]), tilt_correction_max_deg=None if tilt is None else _numbers(tilt),
                   slip=None if isinstance(slip, str) else SlipSummary.from_dict(slip))


@dataclass(frozen=True, kw_only=True)
class OpenSimSummary:
    """What every ``spinemocap opensim`` run reports: ``frames`` solved at ``fps``; the marker
    error (distance of a model marker from its measured dot, mm) as ``marker_rms_mm`` (the mean
    over frames of each frame's RMS over its markers) and ``marker_rms_mm_max`` (the worst frame's
    RMS); ``ms_per_frame`` the inverse kinematics' wall time per frame (ms); ``flagged_frames`` the
    frames the result cannot vouch for, ``flag_reasons`` reason -> number of frames; ``warnings``;
    ``driven_joints`` the joints IK solved; ``markers_by_body`` model body -> the tape labels on it;
    ``facing_error_deg`` the angle between the declared facing and the tape's (deg);
    ``marker_weights`` label -> its mean IK weight over the frames."""

    frames: int
    fps: float
    marker_rms_mm: float
    marker_rms_mm_max: float
    ms_per_frame: float
    flagged_frames: list[int]
    flag_reasons: dict[str, int]
    warnings: list[str]
    driven_joints: list[str]
    markers_by_body: dict[str, list[str]]
    facing_error_deg: float
    marker_weights: dict[str, float]


def _common_fields(data: Mapping[str, Any]) -> JsonObject:
    """:class:`OpenSimSummary`'s fields as keyword arguments from a parsed summary."""
    return {"frames": int(data["frames"]), "fps": _number(data["fps"]),
            "marker_rms_mm": _number(data["marker_rms_mm"]), "marker_rms_mm_max": _number(data["marker_rms_mm_max"]),
            "ms_per_frame": _number(data["ms_per_frame"]),
            "flagged_frames": [int(f) for f in data["flagged_frames"]],
            "flag_reasons": {str(k): int(v) for k, v in data["flag_reasons"].items()},
            "warnings": [str(w) for w in data["warnings"]],
            "driven_joints": [str(j) for j in data["driven_joints"]],
            "markers_by_body": {str(body): [str(label) for label in labels]
                                for body, labels in data["markers_by_body"].items()},
            "facing_error_deg": _number(data["facing_error_deg"]),
            "marker_weights": _numbers(data["marker_weights"])}


def _not_a_summary(source: str | os.PathLike[str], exc: Exception) -> InputError:
    detail = f"key {exc} missing" if isinstance(exc, KeyError) else f"{type(exc).__name__}: {exc}"
    return InputError(source, f"not a spinemocap opensim summary ({detail}); run `spinemocap opensim` again to "
                              "write it anew")


@dataclass(frozen=True, kw_only=True)
class SpineModelSummary(OpenSimSummary):
    """The project's spine model (:func:`spinemocap.opensim.pipeline.run_opensim`), besides
    :class:`OpenSimSummary`: ``marker_rms_observed_mm`` the mean frame RMS over the measured
    (observed) dots only, ``marker_max_mm`` the largest single marker error (mm);
    ``welded_joints`` the joints outside the taped span; ``couplers`` (dependent coordinate,
    independent coordinate, ratio); ``coordinates`` the model's spine coordinates;
    ``markers_not_placed`` tape labels without a static position; ``levels_mapped`` the vertebrae
    the level map places; ``scale_to_generic`` subject / generic column length; ``placement``
    (:class:`Placement`); ``region_ranges_deg`` region angle column -> (min, max) over the frames
    (deg, project signs); ``ik_accuracy`` the IK solver's accuracy and ``ik_accuracy_note`` where
    it was looser; ``ik`` the solve in words; ``opensim_version``; ``depth`` (:class:`Depth`);
    ``skin_model`` (:class:`SkinModelSummary`). ``units`` and ``signs`` are written from
    :attr:`UNITS` and :attr:`SIGNS`."""

    #: The units of the summary, the angle table and the TRC (written as ``units``).
    UNITS: ClassVar[dict[str, str]] = {"angles": "deg", "marker errors": "mm", "trc": "m"}
    #: The angle table's signs (written as ``signs``).
    SIGNS: ClassVar[str] = "flexion forward +, lateral toward right +, rotation toward left +, zero = static posture"

    marker_rms_observed_mm: float
    marker_max_mm: float
    welded_joints: list[str]
    couplers: list[tuple[str, str, float]]
    coordinates: list[str]
    markers_not_placed: list[str]
    levels_mapped: list[str]
    scale_to_generic: float
    placement: Placement
    region_ranges_deg: dict[str, tuple[float, float]]
    ik_accuracy: float
    ik_accuracy_note: str
    ik: str
    opensim_version: str
    depth: Depth
    skin_model: SkinModelSummary

    def to_dict(self) -> JsonObject:
        """The JSON object of ``summary.json``."""
        return {
            "frames": self.frames, "fps": self.fps,
            "marker_rms_mm": self.marker_rms_mm, "marker_rms_mm_max": self.marker_rms_mm_max,
            "marker_rms_observed_mm": self.marker_rms_observed_mm, "marker_max_mm": self.marker_max_mm,
            "ms_per_frame": self.ms_per_frame, "flagged_frames": list(self.flagged_frames),
            "flag_reasons": dict(self.flag_reasons), "warnings": list(self.warnings),
            "driven_joints": list(self.driven_joints), "welded_joints": list(self.welded_joints),
            "couplers": [{"dependent": d, "independent": i, "ratio": r} for d, i, r in self.couplers],
            "coordinates": list(self.coordinates), "markers_by_body": dict(self.markers_by_body),
            "markers_not_placed": list(self.markers_not_placed), "marker_weights": dict(self.marker_weights),
            "levels_mapped": list(self.levels_mapped), "scale_to_generic": self.scale_to_generic,
            "facing_error_deg": self.facing_error_deg, "placement": self.placement.to_dict(),
            "region_ranges_deg": {name: list(limits) for name, limits in self.region_ranges_deg.items()},
            "ik_accuracy": self.ik_accuracy, "ik_accuracy_note": self.ik_accuracy_note, "ik": self.ik,
            "opensim_version": self.opensim_version, "units": dict(self.UNITS), "signs": self.SIGNS,
            "depth": self.depth.to_dict(), "skin_model": self.skin_model.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str | os.PathLike[str]) -> SpineModelSummary:
        """The summary in ``data`` (a parsed ``summary.json``; ``source`` names the file in errors).

        Raises:
            InputError: a key is missing or holds the wrong kind of value."""
        try:
            return cls(**_common_fields(data),
                       marker_rms_observed_mm=_number(data["marker_rms_observed_mm"]),
                       marker_max_mm=_number(data["marker_max_mm"]),
                       welded_joints=[str(j) for j in data["welded_joints"]],
                       couplers=[(str(c["dependent"]), str(c["independent"]), float(c["ratio"])) for c in data["couplers"]],
                       coordinates=[str(c) for c in data["coordinates"]],
                       markers_not_placed=[str(label) for label in data["markers_not_placed"]],
                       levels_mapped=[str(level) for level in data["levels_mapped"]],
                       scale_to_generic=_number(data["scale_to_generic"]),
                       placement=Placement.from_dict(data["placement"]),
                       region_ranges_deg={str(name): (_number(low), _number(high))
                                          for name, (low, high) in data["region_ranges_deg"].items()},
                       ik_accuracy=_number(data["ik_accuracy"]), ik_accuracy_note=str(data["ik_accuracy_note"]),
                       ik=str(data["ik"]), opensim_version=str(data["opensim_version"]),
                       depth=Depth.from_dict(data["depth"]), skin_model=SkinModelSummary.from_dict(data["skin_model"]))
        except _SUMMARY_ERRORS as exc:
            raise _not_a_summary(source, exc) from exc


@dataclass(frozen=True, kw_only=True)
class LabModelSummary(OpenSimSummary):
    """A lab's own model (:func:`spinemocap.opensim.labmodel.run_lab_model`), besides
    :class:`OpenSimSummary`: ``model`` the ``.osim`` file as given, ``bodies_map`` vertebra ->
    the model body it names; ``driven_joints`` are the model's own coordinates. ``units`` is
    written from :attr:`UNITS`."""

    #: The units of the summary and the angle table (written as ``units``).
    UNITS: ClassVar[dict[str, str]] = {"angles": "deg (the lab model's rotational coordinates, OpenSim signs)",
                                       "marker errors": "mm"}

    model: str
    bodies_map: dict[str, str]

    def to_dict(self) -> JsonObject:
        """The JSON object of ``summary.json``."""
        return {
            "frames": self.frames, "fps": self.fps, "model": self.model, "bodies_map": dict(self.bodies_map),
            "marker_rms_mm": self.marker_rms_mm, "marker_rms_mm_max": self.marker_rms_mm_max,
            "ms_per_frame": self.ms_per_frame, "flagged_frames": list(self.flagged_frames),
            "flag_reasons": dict(self.flag_reasons), "warnings": list(self.warnings),
            "driven_joints": list(self.driven_joints), "markers_by_body": dict(self.markers_by_body),
            "facing_error_deg": self.facing_error_deg, "marker_weights": dict(self.marker_weights),
            "units": dict(self.UNITS),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str | os.PathLike[str]) -> LabModelSummary:
        """The summary in ``data`` (a parsed ``summary.json``; ``source`` names the file in errors).

        Raises:
            InputError: a key is missing or holds the wrong kind of value."""
        try:
            return cls(**_common_fields(data), model=str(data["model"]),
                       bodies_map={str(k): str(v) for k, v in data["bodies_map"].items()})
        except _SUMMARY_ERRORS as exc:
            raise _not_a_summary(source, exc) from exc


def read_summary(path: str | os.PathLike[str]) -> SpineModelSummary | LabModelSummary:
    """The ``summary.json`` at ``path`` written by ``spinemocap opensim`` (a lab model's when it
    names ``bodies_map``).

    Raises:
        InputError: the file is missing, not JSON, or not a summary (a key missing, a value of the
            wrong kind); the message names the file."""
    with reading(path, "OpenSim summary"):
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    if not isinstance(data, dict):
        raise InputError(path, "not a spinemocap opensim summary (not a JSON object)")
    if "bodies_map" in data:
        return LabModelSummary.from_dict(data, path)
    return SpineModelSummary.from_dict(data, path)
