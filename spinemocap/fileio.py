"""Small I/O helpers every package uses: one error type for bad input, the boundary that turns
a reader's failures into it, and atomic writes.

Outputs are always written to a temporary file beside the target and renamed into place, so
an interrupted or failing export never leaves a half-written file and never destroys the
previous version. The temporary file is flushed and fsynced before the rename, gets the mode a
plain ``open`` would give (``0o666`` minus the umask, or the replaced file's mode), and is named
``.~<target name>.<pid>.<random><suffix>``: one left behind by a killed process is removed the
next time the same target is written (:func:`clean_stale_temps`). The folder is listed for that
once per process (:func:`_stale_temps_by_target`), not on every write, so writing a long image
sequence into one folder does not slow down as the folder fills.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import stat
import tempfile
import threading
from pathlib import Path
from typing import IO, Iterator

TEMP_PREFIX = ".~"
_TEMP_NAME = re.compile(r"^\.~(?P<target>.+)\.(?P<pid>\d+)\.[0-9a-f]{8}(\.[^.]*)?$")

# What a reader's parsing code raises on damaged input; :func:`reading` converts these into
# :class:`InputError` naming the file. (InputError itself is a ValueError.)
READ_ERRORS: tuple[type[BaseException], ...] = (
    ValueError, TypeError, IndexError, KeyError, LookupError, OverflowError, ZeroDivisionError,
    UnicodeError, AttributeError, OSError, EOFError, ArithmeticError, MemoryError, RecursionError,
)


class InputError(ValueError):
    """Bad input data: the message names the file (or object) and the problem.

    ``source``: the file, object or parameter at fault (a parameter by its Python name, e.g.
    ``"fix_size"``; the command line shows its flag). ``problem``: what is wrong and how to fix it;
    a parameter it names is written in backticks, `name` or `name=value` (e.g. "use
    `method='motion'`"), which the command line shows as the flag (``--method motion``)."""

    def __init__(self, source: str | os.PathLike | None, problem: str):
        self.source = str(source) if source is not None else None
        self.problem = problem
        super().__init__(f"{self.source}: {problem}" if self.source else problem)


@contextlib.contextmanager
def reading(path: str | os.PathLike | None, what: str = "file") -> Iterator[None]:
    """The boundary of a reader: any parsing failure inside becomes :class:`InputError` naming
    ``path`` ("cannot read <what>: <exception>"). An InputError that already names a file passes
    unchanged; one without a file gets ``path``."""
    try:
        yield
    except InputError as exc:
        if exc.source is None and path is not None:
            raise InputError(path, exc.problem) from exc
        raise
    except READ_ERRORS as exc:
        detail = str(exc) or type(exc).__name__
        if isinstance(exc, (KeyError, LookupError)) and not isinstance(exc, UnicodeError):
            detail = f"{type(exc).__name__} {detail}"
        raise InputError(path, f"cannot read {what}: {detail}") from exc


class OutputError(InputError):
    """Results could not be written (the disk is full, the folder is read-only): the message
    names the folder, the problem and what to do; nothing half-written is left as complete.
    ``reason`` is the problem alone (e.g. "no space left on the device")."""

    def __init__(self, folder: str | os.PathLike, what: str, reason: str):
        self.reason = reason
        super().__init__(folder, f"cannot write the {what}: {reason}. Nothing partial was kept as a complete "
                                 "result: free space (or choose another output folder) and run the same "
                                 "command again")


# errno -> what the user is told when an output cannot be written
_OUTPUT_PROBLEMS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "the disk quota is exceeded",
    errno.EFBIG: "the file is larger than this file system allows",
    errno.EROFS: "the file system is read-only",
}


@contextlib.contextmanager
def writing(folder: str | os.PathLike, what: str = "results") -> Iterator[None]:
    """The boundary of a writer: a full disk, an exceeded quota or a read-only file system inside
    becomes :class:`OutputError` naming ``folder``. Other errors pass unchanged.

    Raises:
        OutputError: the write failed for one of the reasons above."""
    try:
        yield
    except OutputError as exc:      # from a nested writer: said again for the outermost folder
        raise OutputError(folder, what, exc.reason) from exc
    except OSError as exc:
        problem = _OUTPUT_PROBLEMS.get(exc.errno or 0)
        if problem is None:
            raise
        raise OutputError(folder, what, problem) from exc


# ---------------------------------------------------------------------------------- writing
def _creation_mode(target: Path) -> int:
    """The permission bits a new file at ``target`` should get: the replaced file's, else
    ``0o666`` minus the process umask (what ``open(..., 'w')`` gives; mkstemp's 0o600 is not)."""
    with contextlib.suppress(OSError):
        return stat.S_IMODE(target.stat().st_mode)
    return 0o666 & ~_umask()


def _umask() -> int:
    try:  # Linux: read it without changing it (os.umask would, for every thread, for a moment)
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def clean_stale_temps(folder: str | os.PathLike, target: str | None = None) -> list[Path]:
    """Remove temporary files (and staging folders) that a killed process left in ``folder``
    (only those of ``target`` when given): names ``.~NAME.PID.RANDOM[.ext]`` whose PID is not a
    live process. Returns what was removed."""
    import shutil

    removed: list[Path] = []
    folder = Path(folder)
    if not folder.is_dir():
        return removed
    for entry in folder.iterdir():
        match = _TEMP_NAME.match(entry.name)
        if not match or (target is not None and match["target"] != target) or _pid_alive(int(match["pid"])):
            continue
        with contextlib.suppress(OSError):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
            removed.append(entry)
    return removed


# Stale temporaries per folder, listed once per process: {(folder, device, inode): {target: paths}}.
# A temporary is stale only when its writer is dead, and a dead writer writes no more, so the
# first listing in this process sees every temporary left by processes dead by then; one left
# by a writer killed later is removed by the next process that writes there (or by an explicit
# :func:`clean_stale_temps`, as the results and batch writers call on their folders).
_STALE_BY_FOLDER: dict[tuple[str, int, int], dict[str, list[Path]]] = {}
_STALE_LOCK = threading.Lock()


def _stale_temps_by_target(folder: Path) -> dict[str, list[Path]]:
    """Stale temporaries in ``folder`` grouped by target name, listed on this process's first
    write into the folder (keyed by path and inode)."""
    info = folder.stat()
    key = (str(folder.absolute()), info.st_dev, info.st_ino)
    with _STALE_LOCK:
        found = _STALE_BY_FOLDER.get(key)
        if found is None:
            found = {}
            for entry in folder.iterdir():
                match = _TEMP_NAME.match(entry.name)
                if match and not _pid_alive(int(match["pid"])):
                    found.setdefault(match["target"], []).append(entry)
            _STALE_BY_FOLDER[key] = found
        return found


def _clean_stale_temps_of(path: Path) -> None:
    """Remove what killed processes left while writing ``path`` (folder listed once per process)."""
    import shutil

    stale = _stale_temps_by_target(path.parent)
    with _STALE_LOCK:
        entries = stale.pop(path.name, [])
    for entry in entries:
        with contextlib.suppress(OSError):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()


def temp_name(path: Path, suffix: str | None = None) -> Path:
    """A fresh temporary name beside ``path`` (see the module docstring)."""
    suffix = path.suffix if suffix is None else suffix
    return path.parent / f"{TEMP_PREFIX}{path.name}.{os.getpid()}.{secrets.token_hex(4)}{suffix}"


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(folder: Path) -> None:
    """Make a rename inside ``folder`` durable (no-op where directories cannot be opened)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _commit(tmp: Path, path: Path) -> None:
    """chmod to the normal creation mode, fsync, rename over ``path``, fsync the folder."""
    os.chmod(tmp, _creation_mode(path))
    _fsync_file(tmp)
    os.replace(tmp, path)
    fsync_dir(path.parent)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", **open_kwargs) -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success fsync it and rename it over ``path``.

    On any exception (KeyboardInterrupt included) the temporary file is removed and ``path`` is
    left untouched; a full disk or read-only file system raises :class:`OutputError`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _clean_stale_temps_of(path)
    tmp = temp_name(path, ".tmp")
    try:
        with writing(path.parent, path.name), open(tmp, "x" + mode.replace("w", ""), **open_kwargs) as handle:
            yield handle
            handle.flush()
            _commit(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path (same folder, same suffix) for libraries that write by file name;
    fsync it and rename it over ``path`` on success, delete it on failure."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _clean_stale_temps_of(path)
    tmp = temp_name(path)
    try:
        with writing(path.parent, path.name):
            yield tmp
            _commit(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def check_writable(folder: str | os.PathLike, what: str = "output folder") -> Path:
    """Create ``folder`` if needed and prove a file can be written there, before any long work;
    :class:`InputError` naming the folder otherwise."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise InputError(folder, f"cannot write to the {what} ({exc.strerror or exc})") from exc
    return folder


def read_toml(path: str | os.PathLike) -> dict:
    """Read a TOML file, turning syntax errors, bad UTF-8 and absence into :class:`InputError`."""
    import tomllib

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(path, f"not valid TOML ({exc})") from exc
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not valid UTF-8 text ({exc})") from exc
    except (OSError, RecursionError, MemoryError) as exc:
        raise InputError(path, f"cannot read TOML ({exc})") from exc


def write_toml(path: str | os.PathLike, data: dict) -> None:
    """Write ``data`` as TOML atomically."""
    import tomli_w

    with atomic_write(path, "wb") as handle:
        tomli_w.dump(data, handle)


def strict_json(data, indent: int | None = 1) -> str:
    """``data`` as JSON that strict parsers read (``allow_nan=False``): NaN and infinities become
    null, numpy scalars and arrays plain numbers and lists, paths strings."""
    import json

    return json.dumps(_json_ready(data), indent=indent, allow_nan=False)


def _json_ready(value):
    import numpy as np

    if isinstance(value, dict):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return _json_ready(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value
