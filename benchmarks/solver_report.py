"""The output of ``python -m benchmarks.solver``: the Markdown section of ``results/BENCHMARKS.md`` and the JSON.

:func:`markdown` renders the results of :func:`benchmarks.solver.run` as the section (markers
included); :func:`to_json` writes everything but the row lists.
"""

from __future__ import annotations

import json
import math
from datetime import datetime, timezone
from typing import Any

import numpy as np

from benchmarks import section

BEGIN_MARK, END_MARK = section.markers("solver")


def _fmt(x: float, nd: int = 2) -> str:
    return "nan" if not isinstance(x, (int, float)) or not math.isfinite(x) else f"{x:.{nd}f}"


def markdown(results: dict[str, Any], command: str) -> str:
    """The generated section of results/BENCHMARKS.md (markers included)."""
    m = results["machine"]
    lines = [
        BEGIN_MARK,
        "",
        f"## Solver benchmark ({datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}, commit "
        f"`{m.get('git_commit', '')}`)",
        "",
        f"Command: `{command}`",
        "",
        f"Machine: {m.get('cpu_model', '?')}, {m.get('cpus', '?')} CPUs ({m.get('cpus_usable')} usable); "
        f"load average at the start {m.get('load_average')} (the machine is shared: absolute times vary with "
        f"the load, ratios are taken within this run); Python {m['python']}, CasADi {m['casadi']}, JAX {m['jax']}.",
        "",
    ]
    lines += _replay_lines(results) + _paired_lines(results) + _jax_lines(results["jax_step"])
    lines += ["", END_MARK, ""]
    return "\n".join(lines)


def _replay_lines(results: dict[str, Any]) -> list[str]:
    """Per-solve CPU of every backend on the recorded states, warm and cold."""
    lines = [
        f"### Per-solve CPU on recorded states ({results['campaign']}, cell `{results['replays'][0]['cell']}`)",
        "",
        "Every solve of an IPOPT-reference closed loop, re-solved warm (from the reference's warm start) and "
        "cold; CPU time of the calling thread, everything in `MpcSolver.solve` included. dT, du0: differences "
        "of the planned time T (s) and of the first input u_0 from the IPOPT re-solve of the same problem.",
        "",
        "| states | backend | start | solves | ms mean | ms median | ms p90 | ms max | iterations | success | "
        "fallback to IPOPT | dT median / max (s) | du0 median / p99 |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |",
    ]
    for r in results["replays"]:
        diffs = (f"{r['dT_s_median']:.1e} / {r['dT_s_max']:.1e}", f"{r['du0_median']:.1e} / {r['du0_p99']:.1e}") \
            if "dT_s_median" in r else ("-", "-")
        lines.append(
            f"| {r['states']} | {r['backend']} | {'warm' if r['warm'] else 'cold'} | {r['solves']} | "
            f"{_fmt(r['cpu_ms_mean'])} | {_fmt(r['cpu_ms_median'])} | {_fmt(r['cpu_ms_p90'])} | "
            f"{_fmt(r['cpu_ms_max'], 1)} | {_fmt(r['iterations_mean'], 1)} | {100 * r['success_rate']:.1f}% | "
            f"{100 * r['fallback_rate']:.1f}% | {diffs[0]} | {diffs[1]} |"
        )
    warm = {(r["states"], r["backend"]): r for r in results["replays"] if r["warm"]}
    ratios = []
    for (states, b), r in warm.items():
        if b != "ipopt" and (states, "ipopt") in warm:
            ratio = warm[(states, "ipopt")]["cpu_ms_mean"] / r["cpu_ms_mean"]
            ratios.append(f"{b}, {states}: {ratio:.1f}x")
    if ratios:
        lines += ["", "Warm-solve speed-up over IPOPT (mean CPU): " + ", ".join(ratios) + "."]
    return lines


def _paired_lines(results: dict[str, Any]) -> list[str]:
    """Throughput of the paired closed-loop episodes and the agreement of every backend with IPOPT."""
    p = results["paired"]
    lines = [
        "",
        f"### Paired closed-loop episodes ({results['campaign']}, {results['episodes_per_cell']} per cell, "
        f"{p['workers']} worker(s), chunks of {p['chunk_size']}, interleaved)",
        "",
        "| backend | episodes | CPU s / episode | episodes per CPU-minute | peak RSS of a worker (MB) |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for b, t in p["throughput"].items():
        lines.append(f"| {b} | {t['episodes']} | {_fmt(t['cpu_s_per_episode'])} | "
                     f"{_fmt(t['episodes_per_cpu_minute'], 1)} | {_fmt(t['maxrss_mb'], 0)} |")
    if "ipopt" in p["throughput"]:
        base = p["throughput"]["ipopt"]["episodes_per_cpu_minute"]
        for b, t in p["throughput"].items():
            if b != "ipopt":
                lines += ["", f"Throughput ratio {b} / ipopt: **{t['episodes_per_cpu_minute'] / base:.2f}x** "
                          f"(same episodes, same run; wall time of the whole paired run {p['wall_s']:.0f} s)."]
    for b, a in p["agreement"].items():
        lines += _agreement_lines(b, a)
    return lines


def _agreement_lines(b: str, a: dict[str, Any]) -> list[str]:
    """One backend's agreement with IPOPT on the paired episodes, its disagreements listed."""
    n = a["paired"]
    lines = [
        "",
        f"Agreement {b} vs ipopt on {n} paired episodes (95% Clopper-Pearson intervals):",
        "",
        f"- safety verdict (`safe`): {a['safe_agree']}/{n} = {100 * a['safe_agree'] / max(n, 1):.1f}% "
        f"[{100 * a['safe_agree_ci'][0]:.1f}%, {100 * a['safe_agree_ci'][1]:.1f}%]",
        f"- outcome (overtook / went back / timeout): {a['outcome_agree']}/{n} = "
        f"{100 * a['outcome_agree'] / max(n, 1):.1f}% [{100 * a['outcome_agree_ci'][0]:.1f}%, "
        f"{100 * a['outcome_agree_ci'][1]:.1f}%]",
        f"- min distance to veh_f: |difference| median {a['min_dist_front_m_absdiff_median']:.2e} m, "
        f"max {a['min_dist_front_m_absdiff_max']:.2e} m",
        f"- overtaking time: |difference| median {a['overtake_time_s_absdiff_median']:.2e} s, "
        f"max {a['overtake_time_s_absdiff_max']:.2e} s",
        f"- solver statuses of {b}: {a['new_statuses']}",
    ]
    if a["disagreements"]:
        lines += ["", "Disagreements:", "", "| episode | cell | safe (ipopt / new) | outcome (ipopt / new) | "
                  "min dist m (ipopt / new) | overtake s (ipopt / new) |", "| ---: | --- | --- | --- | --- | --- |"]
        for d in a["disagreements"]:
            lines.append(
                f"| {d['episode_id']} | {d['cell']} | {d['safe_ref']} / {d['safe_new']} | {d['outcome_ref']} / "
                f"{d['outcome_new']} | {d['min_dist_front_m_ref']:.3f} / {d['min_dist_front_m_new']:.3f} | "
                f"{_fmt(d['overtake_time_s_ref'])} / {_fmt(d['overtake_time_s_new'])} |")
    else:
        lines += ["", "No disagreement in safety verdict or outcome."]
    return lines


def _jax_lines(j: dict[str, Any]) -> list[str]:
    """CPU per control step of the JAX side with a stub solver."""
    lines = [
        "",
        "### JAX side of a control step",
        "",
        "`run_episodes` with a stub solver (constant input, no solve): CPU per control step of the vmapped "
        "`observe`/`advance` calls and the host transfers around them, after a first run that compiles.",
        "",
        "| batch (episodes) | CPU ms per control step | per episode-step | first run (compiles) CPU s |",
        "| ---: | ---: | ---: | ---: |",
    ]
    for b, d in j.items():
        lines.append(f"| {b} | {_fmt(d['cpu_ms_per_step'], 3)} | {_fmt(d['cpu_ms_per_step'] / int(b), 3)} | "
                     f"{_fmt(d['first_run_cpu_s'], 2)} |")
    return lines


def to_json(results: dict[str, Any]) -> str:
    def clean(o):
        if isinstance(o, dict):
            return {str(k): clean(v) for k, v in o.items() if not str(k).startswith("_")}
        if isinstance(o, (list, tuple)):
            return [clean(v) for v in o]
        if isinstance(o, (np.floating, np.integer)):
            return o.item()
        if isinstance(o, np.bool_):
            return bool(o)
        return o

    return json.dumps(clean(results), indent=2, default=str)
