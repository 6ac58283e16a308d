"""P(collision) and P(ellipse violation) against the VL-CBF level ε, from a finished run of
``campaigns/eps_sweep.toml`` (or any run with an ε axis): the table of its generated section of
``results/BENCHMARKS.md``, read from the run's stored summary, never typed in.

    python -m benchmarks.eps_curve RUN_DIR [--no-write]

Per cell the events k/n with the exact two-sided interval (Clopper-Pearson), or, where no event occurred,
the exact one-sided upper bound (a bound, not an estimate); per noise level the ε from which crude Monte
Carlo at this size sees no event, i.e. where the curve leaves its reach. The figure is the run's own
``figures/rate-vs-epsilon.png`` (``mcverify report RUN_DIR``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from benchmarks import section
from mcverify import store
from mcverify.errors import UserError

NAME = "eps_curve"
#: The events of the curve: (summary rate name, column heading).
EVENTS: tuple[tuple[str, str], ...] = (("collision", "P(collision)"), ("ellipse_violation", "P(ellipse violation)"))


def rate_text(r: Mapping[str, Any]) -> str:
    """``k/n = p [low, high]`` with events, ``0/n (≤ u)`` without (u the exact one-sided bound)."""
    k, n = int(r["k"]), int(r["n"])
    if k == 0:
        return f"0/{n} (≤ {r['upper_one_sided']:.2g})"
    return f"{k}/{n} = {r['rate']:.2g} [{r['low']:.2g}, {r['high']:.2g}]"


def _group(cell: Mapping[str, Any]) -> str:
    """The cell's labels but ε (their values alone where one axis is left, e.g. the noise level)."""
    others = {a: v for a, v in cell["labels"].items() if a != "epsilon"}
    if len(others) == 1:
        return str(next(iter(others.values())))
    return ", ".join(f"{a} {v}" for a, v in others.items()) or "all"


def rows(cells: Sequence[Mapping[str, Any]]) -> list[list[str]]:
    """One row per cell, by group (in the campaign's order) then ε."""
    order = {g: i for i, g in enumerate(dict.fromkeys(_group(c) for c in cells))}
    ordered = sorted(cells, key=lambda c: (order[_group(c)], float(c["epsilon"])))
    return [[_group(c), f"{float(c['epsilon']):g}", *(rate_text(c["rates"][m]) for m, _ in EVENTS),
             str(c["outcomes"].get("went_back", 0))] for c in ordered]


def reach(cells: Sequence[Mapping[str, Any]]) -> list[str]:
    """Per group and event: the smallest ε from which no cell saw an event (crude Monte Carlo's reach ends)."""
    out = []
    for group in dict.fromkeys(_group(c) for c in cells):
        mine = sorted((c for c in cells if _group(c) == group), key=lambda c: float(c["epsilon"]))
        for metric, heading in EVENTS:
            seen = [float(c["epsilon"]) for c in mine if c["rates"][metric]["k"] > 0]
            silent = [c for c in mine if not seen or float(c["epsilon"]) > max(seen)]
            if not silent:
                out.append(f"{group}: {heading} is seen up to the largest ε.")
                continue
            worst = max(c["rates"][metric]["upper_one_sided"] for c in silent)
            out.append(f"{group}: no {metric.replace('_', ' ')} from ε = {float(silent[0]['epsilon']):g} on "
                       f"({silent[0]['rates'][metric]['n']} episodes per cell): {heading} ≤ {worst:.2g} there; below "
                       "that, crude Monte Carlo at this size says nothing more (a rare-event estimator's ground).")
    return out


def _wall_s(manifest: Mapping[str, Any]) -> float:
    start = min(datetime.fromisoformat(s["started_utc"]) for s in manifest["sessions"])
    return (datetime.fromisoformat(manifest["finished_utc"]) - start).total_seconds()


def build(run_dir: Path, cmd: str) -> str:
    manifest = store.read_manifest(run_dir)
    if not manifest.get("finished_utc"):
        raise UserError(f"{run_dir} is not finished: `mcverify run --resume {run_dir}` first")
    summary = store.read_json(Path(run_dir) / "summary.json")
    cells = summary["cells"]
    if not cells or any(c.get("epsilon") is None for c in cells):
        raise UserError(f"{run_dir}: every cell needs an ε (barrier.epsilon) for the curve")
    camp, env = manifest["campaign"], manifest["environment"]
    workers = max(s.get("workers") or 1 for s in manifest["sessions"])
    head = ["noise", "ε", *(h for _, h in EVENTS), "went back"]
    table = "\n".join(["| " + " | ".join(head) + " |", "|" + "---|" * len(head),
                       *("| " + " | ".join(r) + " |" for r in rows(cells))])
    wall_h = _wall_s(manifest) / 3600.0
    return "\n".join([
        "## P(collision) and P(ellipse violation) against ε (`python -m benchmarks.eps_curve`)", "",
        section.provenance_line(cmd), "",
        f"Run: `mcverify run {camp['source']} --episodes {camp['episodes_per_cell']}` (the file as the run "
        f"recorded it; campaign {camp['name']}, seed "
        f"{camp['seed']}, common random numbers {camp['common_random_numbers']}) at commit "
        f"`{str(env.get('git_commit', 'unknown'))[:7]}`, {len(cells)} cells x {camp['episodes_per_cell']} episodes at "
        f"the paper's 50 Hz, wall {wall_h:.2f} h on {workers} local workers of a {env.get('cpu_count')}-core machine "
        f"(CPU at most {workers * wall_h:.1f} h; the machine was shared). Intervals: exact two-sided 95 % "
        "(Clopper-Pearson) where events occurred, the exact one-sided 95 % upper bound where none did. Figure: the "
        "run's `figures/rate-vs-epsilon.png` (`mcverify report RUN_DIR`).", "",
        table, "", *(f"- {line}" for line in reach(cells)),
    ])


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        p = section.parser(NAME, __doc__.splitlines()[0])
        p.add_argument("run_dir", type=Path, help="a finished run folder whose cells have an ε")
        section.add_output_options(p)
        args = p.parse_args(argv)
        if not (args.run_dir / store.MANIFEST).is_file():
            raise UserError(f"run folder not found: {args.run_dir}")
        section.publish(NAME, section.wrap(NAME, build(args.run_dir, section.command(NAME, argv))), args)
        return 0

    return section.run_main(NAME, body)


if __name__ == "__main__":
    raise SystemExit(main())

