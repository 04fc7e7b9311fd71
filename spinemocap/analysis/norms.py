"""Published lumbar range of motion of asymptomatic adults, and a subject's values placed against
them (the report's reference ranges).

The values live in ``lumbar_rom_norms.toml`` beside this module, each with its source: the
citation, the source's measurement method and how it differs from spinemocap's, and the
source's own words for the figures. A subject's value is *placed* (below, within or above the
published span), never diagnosed: the sources measured other people with other instruments.

Each value has a ``scope``: ``band`` (the figures of one age group, and of one sex or both, as
the source tabulates them) or ``pooled`` (a span over the source's whole age range). A band
applies only to a subject whose age is known and inside it (and whose sex matches, unless the
band is for both sexes); a pooled value applies to any age in its range or an unknown age. Ages
compare in completed years, as sources tabulate them (a subject aged 29.5 is in "20-29"). The
most specific value that applies comes first (:meth:`Norms.for_subject`): a band before the
pooled fallback, one sex before both, a narrower age range before a wider one.

Subject metadata: ``[subject]`` in ``capture.toml`` may give ``age`` (years) and ``sex``
(``female`` / ``male``); :func:`subject_profile` reads them.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Literal, get_args

from ..fileio import InputError, read_toml

Movement = Literal["flexion", "extension", "lateral_bending", "axial_rotation"]
Sex = Literal["female", "male"]
Placement = Literal["below", "within", "above", "median only", "no reference", "no value"]
Scope = Literal["band", "pooled"]
MOVEMENTS: tuple[str, ...] = get_args(Movement)
SCOPES: tuple[str, ...] = get_args(Scope)
NORMS_FILE = "lumbar_rom_norms.toml"
SEX_WORDS = {"female": "female", "f": "female", "woman": "female", "male": "male", "m": "male", "man": "male"}
MAX_AGE = 120
#: A band names the table of its source it was read from ("Table 2"): figures come from a table's
#: text, never from a graph.
BAND_TABLE = re.compile(r"\bTable \d+")


@dataclass(frozen=True)
class Source:
    """A publication: ``citation``; ``method`` how it measured; ``differs`` how that differs from
    spinemocap's measurement."""

    key: str
    citation: str
    method: str
    differs: str


@dataclass(frozen=True)
class ReferenceValue:
    """One published span for ``movement`` (degrees, per direction): ``low_deg``..``high_deg``
    over ages ``age_min``..``age_max`` (years) for ``sex`` (``any``: both sexes); ``scope``
    ``band`` (one age group) or ``pooled`` (the source's whole age range); ``statistic`` what
    the span is; ``quote`` the source's words; ``source`` where it comes from."""

    movement: str
    sex: str
    age_min: float
    age_max: float
    low_deg: float
    high_deg: float
    statistic: str
    quote: str
    source: Source
    scope: str = "pooled"

    def covers(self, age: float | None, sex: str | None) -> bool:
        """True when this value applies to a subject of ``age`` (years) and ``sex`` (None:
        unknown). The age counts in completed years against both ends of the range (29.5 is in
        20-29, 30 is not). A band needs a known age inside it; a pooled value takes an unknown
        age too. A value for one sex needs the subject's sex to be that one."""
        if age is None:
            age_ok = self.scope == "pooled"
        else:
            age_ok = self.age_min <= math.floor(age) <= self.age_max
        sex_ok = self.sex == "any" or (sex is not None and self.sex == sex)
        return age_ok and sex_ok

    def applies_to(self) -> str:
        """Whom the value describes, in words ("female, 20-39 years (age band)" or "both sexes,
        16-90 years (pooled)")."""
        who = "both sexes" if self.sex == "any" else self.sex
        kind = "age band" if self.scope == "band" else "pooled"
        return f"{who}, {self.age_min:g}-{self.age_max:g} years ({kind})"

    def place(self, value_deg: float) -> Placement:
        """Where ``value_deg`` lies against the span ("median only" when the source gives a
        single median, which no value can be outside of in a meaningful way)."""
        if not value_deg == value_deg:  # NaN
            return "no value"
        if self.low_deg == self.high_deg:
            return "median only"
        if value_deg < self.low_deg:
            return "below"
        if value_deg > self.high_deg:
            return "above"
        return "within"


@dataclass(frozen=True)
class Finding:
    """A published finding without values (``about``: ``age`` or ``sex``) and its source."""

    about: str
    text: str
    source: Source


@dataclass(frozen=True)
class Norms:
    """The reference values and findings of a norms file."""

    sources: dict[str, Source]
    values: tuple[ReferenceValue, ...]
    findings: tuple[Finding, ...]
    path: str

    def for_subject(self, movement: str, age: float | None, sex: str | None) -> list[ReferenceValue]:
        """The values for ``movement`` that apply to the subject, the most specific first: age
        bands before pooled spans (the fallback), one sex before both, then the narrower age
        range; values equally specific keep the file's order."""
        matching = [v for v in self.values if v.movement == movement and v.covers(age, sex)]
        return sorted(matching, key=lambda v: (v.scope != "band", v.sex == "any", v.age_max - v.age_min))


def load_norms(path: str | os.PathLike | None = None) -> Norms:
    """The norms file (default: the one shipped with the package); :class:`InputError` naming
    it for a value without a known source, an unknown movement or sex, an empty span, or a band
    that does not name the source's table it was read from."""
    if path is None:
        with resources.as_file(resources.files(__package__).joinpath(NORMS_FILE)) as shipped:
            return _parse(read_toml(shipped), str(shipped))
    return _parse(read_toml(path), str(path))


def _parse(data: dict, path: str) -> Norms:
    try:
        sources = {s["key"]: Source(s["key"], s["citation"], s["method"], s["differs"]) for s in data["source"]}
        values = tuple(_reference(v, sources) for v in data.get("reference", []))
        findings = tuple(Finding(f["about"], f["text"], sources[f["source"]]) for f in data.get("finding", []))
    except KeyError as exc:
        raise InputError(path, f"missing or unknown key {exc} (every value needs movement, sex, ages, low_deg, "
                               "high_deg, statistic, quote, scope and a source key listed under [[source]])") from None
    except (TypeError, ValueError) as exc:
        raise InputError(path, f"malformed entry ({exc})") from None
    empty = [s.key for s in sources.values() if not (s.citation.strip() and s.method.strip() and s.differs.strip())]
    if empty:
        raise InputError(path, f"sources {empty} lack a citation, method or how they differ")
    return Norms(sources, values, findings, path)


def _reference(entry: dict, sources: dict[str, Source]) -> ReferenceValue:
    value = ReferenceValue(
        movement=str(entry["movement"]), sex=str(entry["sex"]), age_min=float(entry["age_min"]),
        age_max=float(entry["age_max"]), low_deg=float(entry["low_deg"]), high_deg=float(entry["high_deg"]),
        statistic=str(entry["statistic"]), quote=str(entry["quote"]), source=sources[entry["source"]],
        scope=str(entry["scope"]))
    if value.scope not in SCOPES:
        raise ValueError(f"scope {value.scope!r} must be 'band' (one age group) or 'pooled' (all ages)")
    if value.movement not in MOVEMENTS:
        raise ValueError(f"movement {value.movement!r} is not one of {MOVEMENTS}")
    if value.sex not in ("any", *get_args(Sex)):
        raise ValueError(f"sex {value.sex!r} must be 'any', 'female' or 'male'")
    if not (0 <= value.low_deg <= value.high_deg and value.age_min <= value.age_max) or not value.quote.strip():
        raise ValueError(f"{value.movement} from {value.source.key}: needs 0 <= low_deg <= high_deg, "
                         "age_min <= age_max and the source's words (quote)")
    if value.scope == "band" and not BAND_TABLE.search(f"{value.statistic} {value.quote}"):
        raise ValueError(f"band {value.movement} {value.sex} {value.age_min:g}-{value.age_max:g} from "
                         f"{value.source.key}: name the source's table its figures were read from "
                         "(e.g. 'Table 2') in statistic")
    return value


@dataclass(frozen=True)
class SubjectProfile:
    """A subject's ``age`` (years) and ``sex`` when the metadata gives them (None otherwise) and
    what was wrong with values that could not be used (``problems``)."""

    age: float | None
    sex: str | None
    problems: tuple[str, ...] = ()


def subject_profile(subject: dict) -> SubjectProfile:
    """Age and sex from a capture's ``[subject]`` table (``age`` in years, ``sex`` female/male
    or f/m); an unusable value is left out and named in ``problems``."""
    problems = []
    age = subject.get("age")
    if age is not None:
        if isinstance(age, bool) or not isinstance(age, (int, float)) or not 0 <= float(age) <= MAX_AGE:
            problems.append(f"age {age!r} is not a number of years in 0..{MAX_AGE}")
            age = None
        else:
            age = float(age)
    sex = subject.get("sex")
    if sex is not None:
        word = SEX_WORDS.get(str(sex).strip().lower())
        if word is None:
            problems.append(f"sex {sex!r} is not female or male")
        sex = word
    return SubjectProfile(age, sex, tuple(problems))


def norms_path() -> Path:
    """Where the shipped norms file is (for the report's note)."""
    return Path(str(resources.files(__package__).joinpath(NORMS_FILE)))
