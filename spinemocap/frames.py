"""The one frame-selection syntax of every command and workflow that picks frames of a capture.

A selection is a comma-separated list of parts; each part is

- ``N``: the single frame ``N`` (0-based);
- ``A:B``: frames ``A <= f < B`` (a Python slice: ``B`` exclusive; ``A`` defaults to 0, ``B`` to
  the end of the capture);
- ``A:B:S``: every ``S``-th frame of ``A:B`` (``S >= 1``).

Examples: ``0:100``, ``:50``, ``200:``, ``0:300:10``, ``0,5,9``, ``0:10,20:30,99``. Spaces are
ignored. The result is the union of the parts, ascending and without repeats. With the number of
frames known, slices are cut to the capture (as Python slices are) and a single frame beyond it is
an error; a selection that keeps no frame is an error.
"""

from __future__ import annotations

from .fileio import InputError

SYNTAX = "N, A:B (B exclusive), A:B:S (every S-th), or a comma list of these, e.g. 0:100 or 0,5,9"


def parse_frames(spec: str, n_frames: int | None = None, parameter: str = "frames") -> list[int]:
    """Frame indices (ascending, unique) selected by ``spec`` (see the module docstring).

    ``n_frames``: frames in the capture (``None``: unknown, then a slice needs its end ``B``).
    ``parameter``: the name the errors give the selection (a function argument or a CLI flag).
    Raises :class:`~spinemocap.fileio.InputError` naming ``parameter`` when ``spec`` is not of the
    syntax, names a frame outside the capture, or selects nothing."""
    selected: set[int] = set()
    parts = spec.replace(" ", "").split(",")
    if not any(parts):
        raise InputError(parameter, f"empty frame selection; write {SYNTAX}")
    for part in parts:
        if not part:
            raise InputError(parameter, f"empty part in frame selection {spec!r}; write {SYNTAX}")
        selected.update(_frames_of_part(part, spec, n_frames, parameter))
    if not selected:
        within = f" of the {n_frames} in the capture" if n_frames is not None else ""
        raise InputError(parameter, f"frame selection {spec!r} selects no frame{within}")
    return sorted(selected)


def _frames_of_part(part: str, spec: str, n_frames: int | None, parameter: str) -> range:
    fields = part.split(":")
    if len(fields) > 3:
        raise InputError(parameter, f"cannot read {part!r} in frame selection {spec!r}; write {SYNTAX}")
    try:
        numbers = [int(field) if field else None for field in fields]
    except ValueError:
        raise InputError(parameter, f"cannot read {part!r} in frame selection {spec!r}; write {SYNTAX}") from None
    if any(number is not None and number < 0 for number in numbers):
        raise InputError(parameter, f"negative frame in {part!r} of frame selection {spec!r}; frames count from 0")
    if len(numbers) == 1:
        frame = numbers[0]
        assert frame is not None  # a single field that is empty was rejected above
        if n_frames is not None and frame >= n_frames:
            raise InputError(parameter, f"frame {frame} in selection {spec!r} is beyond the capture's {n_frames} frames "
                                        f"(0..{n_frames - 1})")
        return range(frame, frame + 1)
    start, stop, step = numbers + [None] * (3 - len(numbers))
    if step is not None and step < 1:
        raise InputError(parameter, f"step {step} in {part!r} of frame selection {spec!r} must be >= 1")
    if stop is None:
        if n_frames is None:
            raise InputError(parameter, f"{part!r} in frame selection {spec!r} needs its end B (A:B)")
        stop = n_frames
    if n_frames is not None:
        stop = min(stop, n_frames)
    return range(start or 0, stop, step or 1)
