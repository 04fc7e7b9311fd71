"""``spinemocap export``: convert a results folder or marker file to TRC, C3D, CSV, Parquet or
any format a plugin registers (entry-point group ``spinemocap.exporters``)."""

from __future__ import annotations

import argparse
import inspect
from pathlib import Path

import exporters
from spinemocap.app.results import find_markers, record_replaced, tracked_set_file
from spinemocap.fileio import InputError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export", help="write marker trajectories as TRC (OpenSim), C3D (Nexus, Mokka ...), CSV, Parquet",
        description="Convert RESULTS (a marker file: csv/trc/c3d/parquet, or a results folder holding "
                    "markers.csv) into another format. Coordinates stay in the lab frame (Z up) unless "
                    "--opensim-axes is given; the TRC header states the frame either way.")
    p.add_argument("results", nargs="?", type=Path, help="marker file or results folder")
    p.add_argument("--format", "-f", default=None,
                   help="trc, c3d, csv, parquet or a plugin name (default: from --out's extension, else trc)")
    p.add_argument("--out", "-o", type=Path, default=None,
                   help="output file (default: beside RESULTS, named markers.<format>, or markers_<options>.<format> "
                        "where markers.<format> is a file of the tracked set)")
    p.add_argument("--force", action="store_true",
                   help="replace a file of a tracked set (markers.trc/.c3d/.csv beside markers.manifest.json); the "
                        "manifest then records the replacement")
    p.add_argument("--units", choices=("mm", "m"), default=None, help="length units of TRC/C3D output (default mm)")
    p.add_argument("--opensim-axes", action="store_true",
                   help="TRC: rotate from our Z-up lab frame to OpenSim's Y-up frame (stated in the header)")
    p.add_argument("--forward", default=None, choices=("+x", "-x", "+y", "-y"),
                   help="with --opensim-axes: lab axis the subject faces, becomes OpenSim +X "
                        "(default +x; write --forward=-y)")
    p.add_argument("--reference", type=Path, default=None,
                   help="C3D: reference/ground-truth marker file written alongside with a label prefix")
    p.add_argument("--reference-prefix", default="REF_", help="label prefix of --reference markers")
    p.add_argument("--list-formats", action="store_true", help="list the available formats and exit")
    p.set_defaults(func=run_export)


def _default_out(source: Path, fmt: str, options: dict) -> Path:
    """``markers.<ext>`` beside the source, or ``markers_<options>.<ext>`` (``markers_export``
    without options) where that is a file of the tracked set."""
    plain = source.with_name("markers" + _extension(fmt))
    if not tracked_set_file(plain):
        return plain
    parts = [name for name in ("opensim" if options.get("opensim_axes") else "", options.get("units", "")) if name]
    return source.with_name(f"markers_{'_'.join(parts) or 'export'}{_extension(fmt)}")


def _described(fmt: str, options: dict) -> str:
    return ", ".join([fmt, *(f"{k}={v}" for k, v in options.items() if k not in ("reference",))])


def _extension(fmt: str) -> str:
    extensions = tuple(getattr(exporters.get(fmt), "extensions", ()) or ())
    return extensions[0] if extensions else f".{fmt}"


def _accepted(exporter) -> set[str] | None:
    """Option names an exporter takes: its ``options`` attribute, else its ``write`` signature
    (None: it takes any keyword)."""
    if getattr(exporter, "options", None) is not None:
        return set(exporter.options)
    params = inspect.signature(exporter.write).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return None
    return set(params)


def _options(args: argparse.Namespace, fmt: str, source: Path) -> dict:
    """The options the user gave, checked against what the chosen exporter accepts."""
    if args.forward and not args.opensim_axes:
        raise InputError(source, "--forward only applies with --opensim-axes")
    given = {"units": args.units, "opensim_axes": args.opensim_axes or None, "forward": args.forward,
             "reference": args.reference}
    given = {k: v for k, v in given.items() if v is not None}
    accepted = _accepted(exporters.get(fmt))
    rejected = [k for k in given if accepted is not None and k not in accepted]
    if rejected:
        flags = ", ".join("--" + k.replace("_", "-") for k in rejected)
        raise InputError(source, f"{flags} does not apply to the {fmt} format")
    if "reference" in given:
        given["reference"] = exporters.read(args.reference)
        given["reference_prefix"] = args.reference_prefix
    return given


def run_export(args: argparse.Namespace) -> int:
    if args.list_formats:
        for name in exporters.available():
            try:
                exporter = exporters.get(name)
            except InputError as exc:
                print(f"{name:10s} (cannot load: {exc.problem})")
                continue
            print(f"{name:10s} {' '.join(getattr(exporter, 'extensions', ()))}  {getattr(exporter, 'description', '')}")
        return 0
    if args.results is None:
        raise InputError(None, "give a marker file or results folder to export (or --list-formats)")
    source = find_markers(args.results)
    fmt = (args.format or (exporters.format_for_path(args.out) if args.out else "trc")).lower()
    options = _options(args, fmt, source)
    out = args.out or _default_out(source, fmt, options)
    if out.resolve() == source.resolve():
        raise InputError(out, "output would overwrite the input; pass --out")
    replacing = tracked_set_file(out) and out.exists()
    if replacing and not args.force:
        raise InputError(out, "is a file of the tracker's result set (markers.manifest.json); choose another --out, "
                              "or pass --force to replace it (the manifest then records the replacement)")
    table = exporters.read(source)
    written = exporters.write(table, out, format=fmt, **options)
    if replacing:
        record_replaced(out, f"exported from {source.name} by spinemocap export ({_described(fmt, options)})")
    share = table.completeness()
    print(f"{written}: {table.n_frames} frames x {len(table.labels)} markers at {table.fps:g} Hz "
          f"({share['observed']:.0%} observed, {share['inferred']:.0%} inferred, {share['missing']:.0%} missing)")
    return 0


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export", help="exporters: TRC/C3D/CSV/Parquet write and read times, against OpenSim and ezc3d")
    p.add_argument("--frames", type=int, default=548, help="frames (paper's artificial sequence: 548)")
    p.add_argument("--markers", type=int, default=32, help="markers (paper's tape: 32 dots)")
    p.add_argument("--repeat", type=int, default=5, help="timed repetitions (median reported)")
    p.add_argument("--out", type=Path, default=Path("bench_out/export"), help="folder for the JSON numbers")
    p.set_defaults(func=run_bench_export)


def run_bench_export(args: argparse.Namespace) -> int:
    from ..bench.exporters import run_export_benchmark

    run_export_benchmark(args.frames, args.markers, args.repeat, args.out)
    return 0
