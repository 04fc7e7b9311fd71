"""``spinemocap report DIR``: HTML report and CSV/XLSX tables of a batch output folder."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "report", help="HTML report with plots, CSV and XLSX summaries of a batch output folder",
        description="Read the per-trial results `spinemocap batch` wrote to DIR and write report.html "
                    "(self-contained, plots embedded), summary.csv, summary_by_subject.csv, "
                    "summary_by_condition.csv and summary.xlsx into DIR.")
    p.add_argument("dir", help="batch output folder")
    p.add_argument("--title", help="page title")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..app.report import write_report

    paths = write_report(args.dir, title=args.title)
    for name, path in paths.items():
        print(f"{name:>12}: {path}")
    return 0
