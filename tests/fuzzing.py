"""A small seeded fuzz harness for the project's readers, shared by the format suites.

- Mutators take ``(data: bytes, rng)`` and return the damaged bytes: binary ones (bit flips,
  truncation, a float or a 16-bit integer overwritten with NaN / inf / huge / extreme values,
  a chunk deleted or duplicated) and text ones (a line deleted or duplicated, a number replaced
  by nan / inf / a huge value / nothing).
- :func:`cases` stacks 1-3 mutators per case, reproducibly from ``(seed, case index)``.
- :func:`run_fuzz` writes each case to a file, reads it with the reader under test and sorts the
  outcome: the project's :class:`InputError` naming the file (fine), data that passes the
  caller's validation (fine), anything else (a failure: another exception, a non-project warning,
  an error that does not name the file, data that fails validation).
- :func:`marker_table_problems` is the validation for marker tables.

Case counts: ``SPINEMOCAP_FUZZ_CASES`` overrides the default of a test (``make fuzz-c3d`` runs
the slow variants with >= 10,000 cases).
"""

from __future__ import annotations

import os
import struct
import traceback
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spinemocap.fileio import InputError

Mutator = Callable[[bytes, np.random.Generator], bytes]

HUGE = (float("nan"), float("inf"), float("-inf"), 1e38, -1e38, 3.4e38, 1e30, -1e20, 1e10)
EXTREME_INT16 = (0, -1, 1, 32767, -32768, 255, 256, 0x7FFF, -0x50)


# ---------------------------------------------------------------------------------- mutators
def _position(data: bytes, rng: np.random.Generator, align: int = 1) -> int:
    return int(rng.integers(0, max(len(data) // align, 1))) * align


def bit_flips(data: bytes, rng: np.random.Generator) -> bytes:
    """Flip 1-8 random bits."""
    out = bytearray(data)
    for _ in range(int(rng.integers(1, 9))):
        if out:
            at = _position(out, rng)
            out[at] ^= 1 << int(rng.integers(0, 8))
    return bytes(out)


def truncate(data: bytes, rng: np.random.Generator) -> bytes:
    """Cut the file anywhere (often near the end, where a copy stops)."""
    if rng.random() < 0.5:
        return data[: int(rng.integers(0, len(data) + 1))]
    return data[: max(len(data) - int(rng.integers(1, 2048)), 0)]


def float_value(data: bytes, rng: np.random.Generator) -> bytes:
    """Overwrite a 4-byte-aligned word with NaN / inf / a huge float (either byte order)."""
    out = bytearray(data)
    at = _position(out, rng, 4)
    value = HUGE[int(rng.integers(len(HUGE)))]
    out[at:at + 4] = struct.pack("<f" if rng.random() < 0.8 else ">f", value)[: len(out) - at]
    return bytes(out)


def int16_value(data: bytes, rng: np.random.Generator) -> bytes:
    """Overwrite a 2-byte-aligned word with an extreme 16-bit integer."""
    out = bytearray(data)
    at = _position(out, rng, 2)
    out[at:at + 2] = struct.pack("<h", EXTREME_INT16[int(rng.integers(len(EXTREME_INT16)))])[: len(out) - at]
    return bytes(out)


def chunk_delete(data: bytes, rng: np.random.Generator) -> bytes:
    """Delete 1-600 bytes somewhere."""
    at = _position(data, rng)
    return data[:at] + data[at + int(rng.integers(1, 601)):]


def chunk_duplicate(data: bytes, rng: np.random.Generator) -> bytes:
    """Repeat 1-600 bytes in place."""
    at = _position(data, rng)
    chunk = data[at:at + int(rng.integers(1, 601))]
    return data[:at] + chunk + data[at:]


def line_delete(data: bytes, rng: np.random.Generator) -> bytes:
    """Delete one line of a text file."""
    lines = data.splitlines(keepends=True)
    if lines:
        del lines[int(rng.integers(len(lines)))]
    return b"".join(lines)


def line_duplicate(data: bytes, rng: np.random.Generator) -> bytes:
    """Duplicate one line of a text file."""
    lines = data.splitlines(keepends=True)
    if lines:
        at = int(rng.integers(len(lines)))
        lines.insert(at, lines[at])
    return b"".join(lines)


def number_value(data: bytes, rng: np.random.Generator) -> bytes:
    """Replace one number of a text file by nan / inf / -inf / a huge value / nothing."""
    import re

    numbers = list(re.finditer(rb"-?\d+(\.\d*)?([eE][-+]?\d+)?", data))
    if not numbers:
        return data
    match = numbers[int(rng.integers(len(numbers)))]
    new = (b"nan", b"inf", b"-inf", b"1e38", b"1e400", b"", b"-0")[int(rng.integers(7))]
    return data[:match.start()] + new + data[match.end():]


BINARY_MUTATORS: dict[str, Mutator] = {
    "bit_flips": bit_flips, "truncate": truncate, "float_value": float_value, "int16_value": int16_value,
    "chunk_delete": chunk_delete, "chunk_duplicate": chunk_duplicate}
TEXT_MUTATORS: dict[str, Mutator] = {
    "bit_flips": bit_flips, "truncate": truncate, "line_delete": line_delete, "line_duplicate": line_duplicate,
    "number_value": number_value}


@dataclass(frozen=True)
class Case:
    """One fuzz case: which seed file, which mutators, and the damaged bytes."""

    index: int
    seed_name: str
    mutators: tuple[str, ...]
    data: bytes

    def __str__(self) -> str:
        return f"case {self.index} ({self.seed_name}: {' + '.join(self.mutators)})"


def cases(seeds: dict[str, bytes], n_cases: int, seed: int,
          mutators: dict[str, Mutator] = BINARY_MUTATORS) -> Iterator[Case]:
    """``n_cases`` damaged copies of the ``seeds`` files; case ``i`` depends on ``(seed, i)`` only."""
    names, ops = sorted(seeds), sorted(mutators)
    for i in range(n_cases):
        rng = np.random.default_rng([seed, i])
        name = names[int(rng.integers(len(names)))]
        data = seeds[name]
        chosen = tuple(ops[int(k)] for k in rng.integers(len(ops), size=int(rng.integers(1, 4))))
        for op in chosen:
            data = mutators[op](data, rng)
        yield Case(i, name, chosen, data)


def case_count(default: int) -> int:
    """The number of cases to run: ``SPINEMOCAP_FUZZ_CASES`` if set, else ``default``."""
    return int(os.environ.get("SPINEMOCAP_FUZZ_CASES", default))


# ---------------------------------------------------------------------------------- running
@dataclass
class FuzzReport:
    """Outcome counts and the failures (case, what went wrong)."""

    accepted: int = 0
    refused: int = 0
    failures: list[tuple[Case, str]] = field(default_factory=list)

    def check(self, show: int = 5) -> None:
        """Fail (assert) with the first ``show`` failures, each reproducible from its case."""
        detail = "\n\n".join(f"{case}: {problem}" for case, problem in self.failures[:show])
        assert not self.failures, (f"{len(self.failures)} of {self.total} fuzz cases failed "
                                   f"({self.accepted} accepted, {self.refused} refused):\n{detail}")

    @property
    def total(self) -> int:
        return self.accepted + self.refused + len(self.failures)


def run_fuzz(all_cases: Iterator[Case], folder: Path, suffix: str, read: Callable[[Path], object],
             problems: Callable[[object], Sequence[str]], allowed_warnings: tuple[type[Warning], ...] = (),
             file_name: str | None = None) -> FuzzReport:
    """Read every case from a file in ``folder``; sort the outcomes (see the module docstring).
    ``allowed_warnings``: warning classes a reader may give for damaged data (others fail).
    ``file_name``: the damaged file's name (default ``fuzz<suffix>``), for formats found by name."""
    report = FuzzReport()
    path = folder / (file_name or f"fuzz{suffix}")
    for case in all_cases:
        path.write_bytes(case.data)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result = read(path)
            except InputError as exc:
                if str(path) in str(exc):
                    report.refused += 1
                else:
                    report.failures.append((case, f"InputError without the file name: {exc}"))
                continue
            except Exception:  # noqa: BLE001 - any other exception is what the fuzzing looks for
                report.failures.append((case, traceback.format_exc(limit=4)))
                continue
        stray = [f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})" for w in caught
                 if not issubclass(w.category, allowed_warnings)]
        found = list(problems(result)) + [f"unexpected warning {w}" for w in stray]
        if found:
            report.failures.append((case, "; ".join(found)))
        else:
            report.accepted += 1
    return report


# ---------------------------------------------------------------------------------- validation
def marker_table_problems(table, max_abs_mm: float = 1e6, max_abs_other: float = 1e9) -> list[str]:
    """Why a :class:`MarkerTable` is not valid data (empty list: it is): shapes, finite and
    sane coordinates (markers within ``max_abs_mm`` mm, non-marker points listed in
    ``meta['point_types']`` within ``max_abs_other``), NaN exactly where missing, frames,
    times, rate, views and residuals."""
    out = []
    arrays = table.to_arrays()
    pos, status, frames = arrays.positions, arrays.status, arrays.frames
    F, D = len(frames), len(table.labels)
    if pos.shape != (F, D, 3) or status.shape != (F, D) or len(table.data) != F * D:
        out.append(f"inconsistent shapes: positions {pos.shape}, status {status.shape}, {len(table.data)} rows "
                   f"for {F} frames x {D} labels")
        return out
    if len(set(table.labels)) != D:
        out.append("duplicate labels")
    missing = status == "missing"
    if not np.isfinite(pos[~missing]).all():
        out.append(f"{int((~np.isfinite(pos[~missing])).sum())} non-finite coordinates in samples not missing")
    if not np.isnan(pos[missing]).all():
        out.append("missing samples with coordinates")
    others = set(table.meta.get("point_types") or {})
    bound = np.array([max_abs_other if label in others else max_abs_mm for label in table.labels])
    with np.errstate(invalid="ignore"):
        beyond = (np.abs(pos) > bound[None, :, None]).any(axis=2) & ~missing
    if beyond.any():
        out.append(f"{int(beyond.sum())} samples beyond the sane bound (markers {max_abs_mm:g} mm)")
    if F and (np.diff(frames) <= 0).any():
        out.append("frame numbers not increasing")
    fps = table.meta.get("fps")
    if fps is None or not np.isfinite(fps) or fps <= 0:
        out.append(f"frame rate {fps!r}")
    if not np.isfinite(table.data["time"].to_numpy()).all():
        out.append("non-finite times")
    if (arrays.n_views < 0).any():
        out.append("negative view counts")
    residual = arrays.residual
    if not (np.isnan(residual) | (np.isfinite(residual) & (residual >= 0))).all():
        out.append("residuals neither NaN nor finite non-negative")
    return out


# ---------------------------------------------------------------------------------- text formats
# Values a hand-edited or damaged settings file holds where a number or a list belongs.
WRONG_VALUES = (b'"fast"', b"[4]", b"[]", b"true", b"{}", b"nan", b"-inf", b"inf", b"0", b"-1", b"4.7",
                b"1e400", b"1e23", b"[0, 0, 0]", b'""', b"-0.0", b"[[1, 2], [3]]")


def toml_value(data: bytes, rng: np.random.Generator) -> bytes:
    """Replace the value of one ``key = value`` line (or one array element) of a TOML file."""
    import re

    spots = list(re.finditer(rb"(?m)(=\s*)([^\n#]*)", data)) + list(re.finditer(rb"[-+0-9.eE]+(?=[,\]])", data))
    if not spots:
        return data
    match = spots[int(rng.integers(len(spots)))]
    start = match.start(2) if match.re.groups >= 2 else match.start()
    end = match.end(2) if match.re.groups >= 2 else match.end()
    return data[:start] + WRONG_VALUES[int(rng.integers(len(WRONG_VALUES)))] + data[end:]


def xml_attribute(data: bytes, rng: np.random.Generator) -> bytes:
    """Replace one XML attribute value (or one of its space-separated numbers)."""
    import re

    spots = list(re.finditer(rb'="([^"]*)"', data))
    if not spots:
        return data
    match = spots[int(rng.integers(len(spots)))]
    value = match.group(1)
    parts = value.split(b" ")
    new = (b"nan", b"inf", b"-inf", b"0", b"-1", b"1e400", b"1e38", b"", b"x", b"0 0", b"1 2 3 4 5")[
        int(rng.integers(11))]
    if len(parts) > 1 and rng.random() < 0.6:
        parts[int(rng.integers(len(parts)))] = new
        new = b" ".join(parts)
    return data[:match.start(1)] + new + data[match.end(1):]


def invalid_utf8(data: bytes, rng: np.random.Generator) -> bytes:
    """Insert bytes that are not valid UTF-8 (a Latin-1 export, a damaged sector)."""
    at = _position(data, rng)
    return data[:at] + (b"\xff\xfe", b"\xe9", b"\xc3\x28", b"\x00")[int(rng.integers(4))] + data[at:]


TOML_MUTATORS: dict[str, Mutator] = {**TEXT_MUTATORS, "toml_value": toml_value, "invalid_utf8": invalid_utf8}
XML_MUTATORS: dict[str, Mutator] = {**TEXT_MUTATORS, "xml_attribute": xml_attribute, "invalid_utf8": invalid_utf8}
TABLE_TEXT_MUTATORS: dict[str, Mutator] = {**TEXT_MUTATORS, "invalid_utf8": invalid_utf8}


# ---------------------------------------------------------------------------------- validation
def camera_rig_problems(rig) -> list[str]:
    """Why a :class:`Rig` is not a valid calibration, checked here from the numbers (not through
    the package's own validation): finite positive focal lengths, finite K, distortion, pose,
    K's last row (0, 0, 1), R a rotation (|R R^T - I| and |det - 1| <= 1e-5), positive whole
    image sizes, unique non-empty names, at least one camera."""
    out = []
    names = [cam.name for cam in rig]
    if not names:
        out.append("no cameras")
    if len(set(names)) != len(names):
        out.append(f"duplicate names {names}")
    for cam in rig:
        K, R, t = np.asarray(cam.K), np.asarray(cam.R), np.asarray(cam.t)
        where = f"camera {cam.name!r}: "
        if not (isinstance(cam.name, str) and cam.name.strip()):
            out.append(where + "empty name")
        if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0 and list(K[2]) == [0, 0, 1]):
            out.append(where + f"bad K {K.tolist()}")
        if not np.isfinite(cam.dist).all():
            out.append(where + "non-finite distortion")
        if not (np.isfinite(R).all() and np.abs(R @ R.T - np.eye(3)).max() <= 1e-5 and abs(np.linalg.det(R) - 1) <= 1e-5):
            out.append(where + "R is not a rotation")
        if not np.isfinite(t).all():
            out.append(where + "non-finite translation")
        w, h = cam.size
        if not (isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0):
            out.append(where + f"bad size {cam.size}")
    return out


def capture_problems(capture) -> list[str]:
    """Why an opened :class:`Capture` is not valid: its rig (above), a finite positive frame
    rate, a whole frame count >= 1, finite non-zero up/facing directions, known media."""
    out = camera_rig_problems(capture.rig)
    if not (isinstance(capture.fps, float) and np.isfinite(capture.fps) and capture.fps > 0):
        out.append(f"fps {capture.fps!r}")
    if not (isinstance(capture.n_frames, int) and capture.n_frames >= 1):
        out.append(f"n_frames {capture.n_frames!r}")
    for name in ("up", "facing"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            v = np.asarray(getattr(capture, name), float)
        if not (v.shape == (3,) and np.isfinite(v).all() and abs(np.linalg.norm(v) - 1) < 1e-9):
            out.append(f"{name} {v}")
    if capture.media not in ("images", "video"):
        out.append(f"media {capture.media!r}")
    return out


def level_map_problems(levels, n_rows: int) -> list[str]:
    """Why a :class:`LevelMap` is not valid: >= 2 levels, rows finite floats within 1..n_rows,
    increasing from the sacral end."""
    rows = list(levels.rows.values())
    out = []
    if len(rows) < 2:
        out.append("fewer than two levels")
    if not all(isinstance(r, float) and np.isfinite(r) and 1 <= r <= n_rows for r in rows):
        out.append(f"rows {rows} outside 1..{n_rows}")
    if any(b <= a for a, b in zip(rows[:-1], rows[1:])):
        out.append(f"rows {rows} not increasing")
    return out
