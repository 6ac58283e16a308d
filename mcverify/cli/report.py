"""``mcverify report``: regenerate a run folder's summary, tables, figures and report."""

from __future__ import annotations

import argparse
from pathlib import Path

from mcverify.cli import options


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("report", parents=parents,
                       help="regenerate summary.json, cells.parquet, tables, figures, report.md and report.html")
    p.add_argument("run_dir", type=Path)
    p.add_argument("--level", type=options.level, default=None,
                   help="confidence level of every interval (default 0.95; an estimate folder keeps its own)")
    p.add_argument("--method", choices=("clopper-pearson", "wilson"), default=None,
                   help="two-sided interval for the rates of a fixed-count run (default: exact Clopper-Pearson); "
                        "an estimate folder's rates carry its estimator's anytime-valid interval")
    p.add_argument("--bootstrap-resamples", type=options.positive_int, default=2000,
                   help="resamples of the (seeded) bootstrap interval of every mean (default 2000)")
    p.add_argument("--format", action="append", choices=("png", "svg", "pdf"), dest="formats", default=[],
                   help="also write every figure in this format beside the report's PNG (repeatable)")
    p.add_argument("--dpi", type=options.positive_int, default=None,
                   help="resolution of the --format files (default 300; the report's own PNGs stay at 100)")
    p.add_argument("--audit", action="store_true",
                   help="first re-simulate every unsafe episode not audited yet with the reference solver "
                        "(mcverify replay --backend ipopt; about a minute of CPU each) and say in the report "
                        "which are confirmed by it and which are solver-dependent")
    p.set_defaults(handler="report")


def command(args) -> int:
    from mcverify.reporting import run_report

    if args.dpi is not None and not args.formats:
        from mcverify.errors import RunError

        raise RunError("--dpi sets the resolution of the --format files: add --format png, svg or pdf")
    if args.audit:
        import sys

        from mcverify.campaign.audit import audit_unsafe

        audit_unsafe(args.run_dir, progress=lambda msg: print(msg, file=sys.stderr))
    path = run_report.write(
        args.run_dir, level=args.level, method=args.method, bootstrap_resamples=args.bootstrap_resamples,
        figure_formats=args.formats, figure_dpi=args.dpi or 300,
    )
    print(f"report: {path} (also report.html, summary.json, cells.parquet, tables/, figures/)")
    return 0
