"""``mcverify compare``: per-cell differences between two runs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mcverify.cli import options


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("compare", parents=parents,
                       help="per-cell differences between two runs (paired when they share episode keys)")
    p.add_argument("run_a", type=Path)
    p.add_argument("run_b", type=Path)
    p.add_argument("--level", type=options.level, default=0.95, help="confidence level of the intervals (default 0.95)")
    p.add_argument("--pair", nargs=2, action="append", metavar=("CELL_A", "CELL_B"),
                   help="compare these two cells (repeatable; default: cells with the same name)")
    p.add_argument("--out", type=Path, help="also write compare.md, compare.json and compare.tex here")
    p.set_defaults(handler="compare")


def command(args) -> int:
    from mcverify.reporting import compare

    result = compare.compare_runs(
        compare.load_run(args.run_a),
        compare.load_run(args.run_b),
        level=args.level,
        pairs=[tuple(p) for p in args.pair] if args.pair else None,
    )
    if not result["comparisons"]:
        from mcverify.errors import RunError

        raise RunError(
            f"no cell of {args.run_a} matches a cell of {args.run_b} by name "
            f"(A: {'; '.join(result['only_in_a']) or 'none'}; B: {'; '.join(result['only_in_b']) or 'none'}); "
            "give pairs with --pair CELL_A CELL_B"
        )
    print(compare.render_markdown(result))
    if args.out:
        for path in compare.write(args.out, result):
            print(f"wrote {path}", file=sys.stderr)
    return 0
