"""The output of ``python -m benchmarks.engine``: the terminal summary and its section of
``results/BENCHMARKS.md``.

:func:`render` prints the figures of :func:`benchmarks.engine.run`; :func:`markdown` is the section
(the latest run: command, commit, machine, the ratios with their intervals, the solve-class and cell
tables).
"""

from __future__ import annotations

import math
from typing import Any

from benchmarks import section
from benchmarks.sides import PAIRED_VALUES, SideResult
from benchmarks.solve_classes import SolveClass

LABELS = {"engine": "engine", "baseline": "compiled IPOPT loop", "naive": "naive Opti loop"}


def class_table(sides: dict[str, SideResult]) -> list[str]:
    """Markdown table: CPU-s per episode by solve class (and solves, ms per solve) for every side."""
    names = list(sides)
    lines = ["| solve class | " + " | ".join(f"{LABELS[s]}: CPU-s/episode (solves/episode, ms/solve)" for s in names)
             + " |", "|---|" + "---:|" * len(names)]
    classes = next(iter(sides.values())).classes.as_dict()
    for cls in classes:
        cells = []
        for s in names:
            d, n = sides[s].classes.as_dict()[cls], max(len(sides[s].rows), 1)
            cells.append(f"{d['cpu_s'] / n:.2f} ({d['solves'] / n:.1f}, {d['ms_per_solve']:.1f})")
        lines.append(f"| {cls} | " + " | ".join(cells) + " |")
    lines.append("| all solves | " + " | ".join(
        f"{sides[s].classes.total_cpu_s / max(len(sides[s].rows), 1):.2f}" for s in names) + " |")
    lines.append("| whole episode | " + " | ".join(f"{sides[s].cpu_s_per_episode:.2f}" for s in names) + " |")
    return lines


def cell_table(sides: dict[str, SideResult]) -> list[str]:
    """Markdown table: CPU-s per episode by cell for every side."""
    names = list(sides)
    lines = ["| cell | " + " | ".join(f"{LABELS[s]} CPU-s/episode" for s in names) + " |",
             "|---|" + "---:|" * len(names)]
    for cell in sides["engine"].per_cell:
        vals = []
        for s in names:
            n, c = sides[s].per_cell.get(cell, [0, 0.0])
            vals.append(f"{c / n:.2f}" if n else "-")
        lines.append(f"| {cell} | " + " | ".join(vals) + " |")
    return lines


def cell_class_table(sides: dict[str, SideResult]) -> list[str]:
    """Markdown table: per cell and side, the solves' CPU-s per episode by solve class, in the order of
    :class:`SolveClass` (where a cell's time goes)."""
    names = list(sides)
    order = list(SolveClass)
    head = " / ".join(c.value for c in order)
    lines = ["| cell | " + " | ".join(f"{LABELS[s]}: {head}" for s in names) + " |", "|---|" + "---|" * len(names)]
    for cell in sides["engine"].per_cell:
        vals = []
        for s in names:
            n = sides[s].per_cell.get(cell, [0, 0.0])[0]
            by_class = sides[s].per_cell_classes.get(cell, {})
            vals.append(" / ".join(f"{by_class.get(c, 0.0) / n:.2f}" for c in order) if n else "-")
        lines.append(f"| {cell} | " + " | ".join(vals) + " |")
    return lines


def ratio_text(result: dict[str, Any], side: str, bold: bool = False) -> str:
    """``engine / compiled IPOPT loop: 5.27x episodes per CPU-minute (95 % interval 4.6-6.0 ...)``."""
    r = result["ratios"][side]
    text = f"engine / {LABELS[side]}: {f'**{r:.2f}x**' if bold else f'{r:.2f}x'} episodes per CPU-minute"
    ci = result.get("ratio_intervals", {}).get(side)
    if ci is None:
        return text + " (no interval: the sides ran different episodes)"
    if math.isnan(ci.low):
        return text + " (no interval: fewer than 2 episodes per cell)"
    return (text + f" ({100 * ci.level:.0f} % interval {ci.low:.2f}-{ci.high:.2f} over the episodes drawn, "
            "ratio estimator; the machine's timing noise is not in it)")


def agreement_line(name: str, ag: dict[str, Any]) -> str:
    diffs = ", ".join(f"{c} {ag[f'{c}_absdiff_max']:.3g}" for c in PAIRED_VALUES)
    line = (f"{LABELS[name]} vs engine on {ag['paired']} paired episodes: safety verdict {ag['safe_agree']}/"
            f"{ag['paired']}, outcome {ag['outcome_agree']}/{ag['paired']}; largest differences: {diffs}")
    differ = [d["episode_id"] for d in ag["disagreements"]]
    return line + (f"; verdicts or outcomes differ for episode ids {differ}" if differ else "")


def render(result: dict[str, Any]) -> str:
    sides = result["sides"]
    lines = [f"bench on {result['machine']} (load average {result['load_average']})",
             f"  {result['campaign']}: {', '.join(result['cells'])}; engine backend {result['backend']}"]
    for s, side in sides.items():
        lines.append(f"  {LABELS[s]:>20}: {len(side.rows)} episodes, {side.cpu_s:.1f} CPU-s, "
                     f"{side.cpu_s_per_episode:.2f} CPU-s per episode, {side.cpu_ms_per_solve:.1f} CPU-ms per solve, "
                     f"{side.episodes_per_cpu_min:.3g} episodes per CPU-minute")
    for s in result["ratios"]:
        lines.append("  " + ratio_text(result, s))
    lines.append(f"  peak memory {result['peak_rss_mb']:.0f} MB (the whole process); one-off set-up "
                 f"{result['setup_cpu_s']:.1f} CPU-s (solver set-up, XLA compile; counted on no side)")
    lines += ["  " + ln for ln in phase_lines(sides["engine"], result.get("plant_transfer"))]
    lines += ["  " + ln for ln in [*class_table(sides), *cell_table(sides), *cell_class_table(sides)]]
    lines += ["  " + agreement_line(s, ag) for s, ag in result["agreement"].items()]
    lines += ["  " + ln for ln in attempt_lines(result.get("ipm_attempts", {}))]
    return "\n".join(lines)


def attempt_lines(attempts: dict[str, dict[str, float]]) -> list[str]:
    """The engine's IPM attempts (``warm1:Converged``: the first warm attempt converged) with their
    CPU, and the share spent in attempts that did not converge."""
    if not attempts:
        return []
    total = sum(a["cpu_s"] for a in attempts.values())
    failed = sum(a["cpu_s"] for k, a in attempts.items() if not k.endswith(":Converged"))
    parts = ", ".join(f"{k} {a['attempts']} ({a['cpu_s']:.1f} s)" for k, a in attempts.items())
    return [f"IPM attempts (engine, all episodes): {parts}; {failed:.1f} of {total:.1f} CPU-s in attempts "
            "that did not converge"]


def phase_lines(engine: SideResult, transfer: dict[str, float] | None) -> list[str]:
    """Where the engine's CPU went, per episode and per control step of the batch."""
    ph = engine.phases
    if not ph or not engine.rows:
        return []
    n, steps = len(engine.rows), max(ph["control_steps"], 1.0)
    parts = ", ".join(f"{k} {ph[k] / n:.2f} s ({100 * ph[k] / engine.cpu_s:.0f}%)"
                      for k in ("planner", "plant", "other"))
    lines = [f"engine CPU per episode: {parts}; the solves' own clock: {ph['solver_wall'] / n:.2f} s wall "
             "(the solver's share of the planner on an idle machine)",
             f"JAX plant: {1e3 * ph['plant'] / steps:.2f} CPU-ms per control step of the batches "
             "(observe + advance, transfers included); no host callbacks (the solver runs between jitted calls)"]
    if transfer:
        lines.append(f"of which device-to-host copies: {transfer['transfer_ms']:.3f} ms against "
                     f"{transfer['compute_ms']:.3f} ms of dispatch and XLA compute per control step "
                     f"(isolated, {int(transfer['batch'])} episodes, 200 steps)")
    return lines


def markdown(result: dict[str, Any]) -> str:
    """The section ``benchmarks.engine`` of results/BENCHMARKS.md (markers included): the command, the
    commit and the machine, the ratios, the solve-class and cell tables."""
    sides = result["sides"]
    ratios = "; ".join(ratio_text(result, s, bold=True) for s in result["ratios"])
    block = [
        "## The engine against the compiled IPOPT loop (`benchmarks.engine`)",
        "",
        section.provenance_line(result["command"]),
        "",
        f"Load average at the end {result['load_average']}. {result['campaign']}, "
        f"{len(result['cells'])} cell(s), engine backend {result['backend']}. Per side: "
        + "; ".join(f"{LABELS[s]} {len(d.rows)} episodes, {d.cpu_s_per_episode:.2f} CPU-s per episode"
                    for s, d in sides.items())
        + f". {ratios}. Peak memory {result['peak_rss_mb']:.0f} MB (the whole process).",
        "",
        *class_table(sides),
        "",
        *cell_table(sides),
        "",
        *cell_class_table(sides),
        "",
        *[agreement_line(s, ag) + "." for s, ag in result["agreement"].items()],
        "",
        *[ln + "." for ln in attempt_lines(result.get("ipm_attempts", {}))],
    ]
    return section.wrap("engine", "\n".join(block))
