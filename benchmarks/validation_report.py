"""The output of ``python -m benchmarks.validation``: its section of ``results/BENCHMARKS.md`` and
the figure of every repetition's interval against the reference (from :func:`benchmarks.validation.run`'s
plain data)."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any

from benchmarks import section


def _num(x: float, fmt: str) -> str:
    return format(x, fmt) if math.isfinite(x) else "-"


def _pct(x: float) -> str:
    return f"{x:.0%}" if math.isfinite(x) else "-"


def markdown(res: dict[str, Any], command: str) -> str:
    ref = res["reference"]
    lines = ["## Rare events: the estimators against crude Monte Carlo on the closed loop", "",
             section.provenance_line(command), "",
             f"Cell `{ref['cell']}` of `{ref['campaign']}`, target "
             f"`{ref['target']}`.", "",
             f"- crude reference: {ref['k']} events in {ref['n']:,} episodes (pre-assigned order, {ref['errors']} "
             f"errors left out), p = {ref['p']:.4f}, {res['level']:.0%} Clopper-Pearson "
             f"[{ref['low']:.4f}, {ref['high']:.4f}]; {ref['mean_episode_steps']:.0f} control steps per episode", "",
             "| estimator | repetitions | coverage of p (95 % CI) "
             "| coverage if p were at the reference's low / high end "
             "| bias (± s.e.) | relative error | mean rel. half-width (estimates > 0) | repetitions warned "
             "| steps per repetition | CPU-s per repetition | crude steps, same width |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in res["estimators"]:
        lo, hi = s["coverage_interval"]
        lines.append(
            f"| {s['estimator']} | {s['repetitions']} | {s['covered']}/{s['repetitions']} = {_pct(s['coverage'])} "
            f"({_pct(lo)}-{_pct(hi)}) | {_pct(s['coverage_at_reference_low'])} / "
            f"{_pct(s['coverage_at_reference_high'])} | {s['bias']:+.1%} (± {s['bias_standard_error']:.1%}) | "
            f"{_num(s['relative_error'], '.2f')} | {_num(s['mean_relative_halfwidth'], '.2f')} | "
            f"{s['with_warnings']} | {_num(s['steps_per_repetition'], ',.0f')} | "
            f"{_num(s['cpu_s_per_repetition'], '.0f')} | {_num(s['crude_steps_same_width'], ',.0f')} |")
    if any(s.get("leave_out_reference") for s in res["estimators"]):
        lines += ["", "- mc rows: consecutive runs of `mcverify estimate --method mc --until-halfwidth H` over the "
                  "reference's own episodes in their pre-assigned order, each checked against the reference without "
                  "its episodes (leave-out, independent of it); CPU is not split per run (-)."]
    pools = res["pooled_runs"]
    if pools:
        lines.append("")
    lines += [_pooled_line(pooled) for pooled in pools]
    if res.get("importance"):
        lines += ["", _importance_line(res["importance"])]
    return "\n".join(lines)


def _pooled_line(pooled: dict[str, Any]) -> str:
    """One pool's runs taken one by one."""
    if pooled["method"] == "splitting":
        what = (f"splitting ({pooled['score']}), the {pooled['runs']} AMS runs of {pooled['particles']} particles one "
                "by one (each unbiased)")
    else:
        what = (f"subset ({pooled['performance']}), the {pooled['runs']} runs of {pooled['samples']} per stage one by "
                "one (each biased by order 1/N at most)")
    return (f"- {what}: mean {pooled['mean']:.4f} ± {pooled['standard_error']:.4f} (s.e.), bias {pooled['bias']:+.1%} "
            f"± {pooled['bias_standard_error']:.1%} against the reference; {pooled['zero_runs']} runs estimate 0"
            + (f", {pooled['capped_runs']} stopped by --max-iterations left out" if pooled.get("capped_runs") else "")
            + f"; relative standard deviation of a run {pooled['run_relative_sd']:.2f}; "
            f"{pooled['steps_per_run']:,.0f} control steps and {pooled['cpu_s_per_run']:.0f} CPU-s per run; for the "
            f"same width crude Monte Carlo needs {pooled['steps_ratio_vs_crude']:.2f}x the control steps (from the "
            "runs' variance)")


def _importance_line(imp: dict[str, Any]) -> str:
    fails, ess = imp["failures_median_min_max"], imp["ess_median_min_max"]
    line = (f"- importance, the {imp['repetitions']} estimates: failing samples per estimate median {fails[0]:.0f} "
            f"({fails[1]:.0f}-{fails[2]:.0f}), their effective sample size median {ess[0]:.1f} "
            f"({ess[1]:.1f}-{ess[2]:.1f})")
    if imp["with_anytime_lower"]:
        line += (f"; the one-sided anytime-valid lower bound is at or below p in {imp['anytime_lower_held']} of "
                 f"{imp['with_anytime_lower']} (median {imp['anytime_lower_median']:.4f})")
    return line


def _log_floor(rows: list[dict[str, Any]]) -> float | None:
    """Where the estimates span more than two decades, the left end of a log axis (a third of the smallest
    positive estimate or interval end); None keeps the axis linear."""
    values = [v for row in rows for rep in row["intervals"] for v in rep if v > 0 and math.isfinite(v)]
    if not values or max(values) / min(values) <= 100:
        return None
    return min(values) / 3


def figure(res: dict[str, Any], path: Path) -> Path:
    """One panel per estimator row: every repetition's interval (sorted by estimate; red where it
    misses the reference's p) against the reference's p and its interval (grey band)."""
    from mcverify.reporting.figure_common import subplots  # noqa: PLC0415 - matplotlib only when drawing

    ref, rows = res["reference"], res["estimators"]
    floor = _log_floor(rows)
    fig, axes = subplots(1, len(rows), figsize=(3.2 * len(rows), 4.2), sharex=True, squeeze=False)
    for ax, row in zip(axes[0], rows, strict=True):
        targets = row.get("reference_ps") or [ref["p"]] * len(row["intervals"])
        reps = sorted(zip(row["intervals"], targets, strict=True))
        for i, ((est, low, high), target) in enumerate(reps):
            colour = "tab:blue" if low <= target <= high else "tab:red"
            if floor is not None:  # log scale: a value under the floor (0 included) is drawn at it, as "<"
                if min(low, est) < floor:
                    ax.plot([floor], [i], "<", color=colour, ms=3)
                low, est = max(low, floor), max(est, floor)
            ax.plot([low, high], [i, i], color=colour, lw=1.2)
            ax.plot([est], [i], "o", color=colour, ms=2.5)
        ax.axvspan(ref["low"], ref["high"], color="0.85", zorder=0)
        ax.axvline(ref["p"], color="k", lw=1)
        if floor is not None:
            ax.set_xscale("log")
        ax.set_title(f"{textwrap.fill(row['estimator'], 40)}\ncoverage {row['covered']}/{row['repetitions']}",
                     fontsize=8)
        ax.set_xlabel(f"P({ref['target']})")
        ax.set_yticks([])
    axes[0][0].set_ylabel("repetitions, sorted by estimate")
    fig.suptitle(f"{ref['campaign']}: intervals against the crude reference "
                 f"({ref['k']}/{ref['n']}, grey: its 95 % interval)", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return path
