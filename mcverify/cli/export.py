"""``mcverify export``: a run folder's tables as CSV files."""

from __future__ import annotations

import argparse
from pathlib import Path


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("export", parents=parents,
                       help="write a run folder's episodes, cells and counterexamples as CSV files")
    p.add_argument("run_dir", type=Path)
    p.add_argument("--csv", action="store_true", required=True,
                   help="CSV files (episodes.csv, cells.csv, counterexamples.csv; the only format so far)")
    p.add_argument("--out", type=Path, help="folder for the files (default: the run folder)")
    p.set_defaults(handler="export")


def command(args) -> int:
    from mcverify.reporting import export

    for path in export.export_csv(args.run_dir, args.out):
        print(f"written: {path}")
    return 0
