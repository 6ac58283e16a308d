"""Solver policies compared (``mpc.infeasibility`` and others): paired closed loops and replayed recorded solves.

Two measurements, written together into a generated section of results/BENCHMARKS.md
(:func:`mcverify.store.replace_section`):

1. **Paired episodes** (:func:`compare_policies`): ``mcverify bench``'s engine side
   (:func:`mcverify.bench.engine.run`, no baseline) on the same (seed, cell, episode id) with the
   default settings and with one :data:`VARIANTS` entry: "phase1" (``mpc.infeasibility``: the C
   phase-1 certificate from every start, IPOPT as scheduled auditor), "phase1_mpcdc" (the same for the
   MPC-DC baselines only), "restoration"
   (``mpc.ipm_restoration``: the IPM attempts with the restoration phase), both, "q2_when_needed" or
   "q2_fast_when_unneeded" (``mpc.q2_solve``: a Q2 the step's decision ignores not solved, or given
   the fast path only), "central_off", "central_mpcdc" or "central_all" (``mpc.ipm_central_attempt``,
   whose default is ``mpcdc``), "central_first_off" or "central_first_mpcdc" (``mpc.ipm_central_first``,
   likewise), "central_retry_off" or "central_retry_mpcdc" (``mpc.ipm_central_retry``, likewise),
   "after_hard_central" or "after_hard_lower_mu" (``mpc.ipm_after_hard_attempt``), "after_hard_solves_1" or
   "after_hard_solves_2" (``mpc.ipm_after_hard_solves``): CPU per episode
   by solve class, the audit counters, and the
   episode-by-episode agreement of safety verdicts and outcomes.
2. **Recorded solves** (:func:`replay_verdicts`): every solve of a recording
   (:mod:`mcverify.bench.recorded_ipm`) the IPM did not converge on, replayed under phase 1 from the
   warm and the cold start and under the restoration-enabled attempts: how the start-independent
   verdict compares with what IPOPT made of the same problem.

Run: ``python -m mcverify.bench.infeasibility --variant phase1 --episodes 1 [--base VARIANT]
[--recording FILE ...] [--no-write]`` (each variant has its own generated section; ``--base`` pairs the
variant with another variant instead of the defaults, in a section of its own).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from mcverify import store
from mcverify.bench import engine, recorded_ipm
from mcverify.bench.agreement import agreement
from mcverify.bench.engine import PAIRED_VALUES
from mcverify.bench.engine_report import BENCHMARKS_MD
from mcverify.bench.solve_classes import SolveClass

#: Settings compared with the default (dotted keys of the model).
VARIANTS: dict[str, dict[str, Any]] = {
    "phase1": {"mpc.infeasibility": "phase1"},
    "phase1_mpcdc": {"mpc.infeasibility": "phase1_mpcdc"},
    "restoration": {"mpc.ipm_restoration": "all"},
    "restoration_mpcdc": {"mpc.ipm_restoration": "mpcdc"},
    "phase1+restoration": {"mpc.infeasibility": "phase1", "mpc.ipm_restoration": "all"},
    "q2_when_needed": {"mpc.q2_solve": "when_needed"},
    "q2_fast_when_unneeded": {"mpc.q2_solve": "fast_when_unneeded"},
    "central_off": {"mpc.ipm_central_attempt": "off"},
    "central_mpcdc": {"mpc.ipm_central_attempt": "mpcdc"},
    "central_all": {"mpc.ipm_central_attempt": "all"},
    "central_first_off": {"mpc.ipm_central_first": "off"},
    "central_first_mpcdc": {"mpc.ipm_central_first": "mpcdc"},
    "central_retry_off": {"mpc.ipm_central_retry": "off"},
    "central_retry_mpcdc": {"mpc.ipm_central_retry": "mpcdc"},
    "after_hard_central": {"mpc.ipm_after_hard_attempt": "central"},
    "after_hard_lower_mu": {"mpc.ipm_after_hard_attempt": "lower_mu"},
    "after_hard_solves_1": {"mpc.ipm_after_hard_solves": 1},
    "after_hard_solves_2": {"mpc.ipm_after_hard_solves": 2},
}
#: The heading of a variant's section (default: the infeasibility certificates').
HEADINGS: dict[str, str] = {"q2_when_needed": "Q2 solved only when Algorithm 1 reads it (`mpc.q2_solve`)",
                            "q2_fast_when_unneeded": "An unread Q2 on the fast path only (`mpc.q2_solve`)",
                            "central_mpcdc": "A central IPM attempt before IPOPT's rescue, MPC-DC only "
                                             "(`mpc.ipm_central_attempt`)",
                            "central_all": "A central IPM attempt before IPOPT's rescue, every controller "
                                           "(`mpc.ipm_central_attempt`)",
                            "central_first_mpcdc": "The central IPM attempt first after a hard solve, MPC-DC only "
                                                   "(`mpc.ipm_central_first`)",
                            "central_first_off": "Without the central IPM attempt first after a hard solve "
                                                 "(`mpc.ipm_central_first = off`)",
                            "central_retry_mpcdc": "A central IPM retry before IPOPT's rescue, MPC-DC only "
                                                   "(`mpc.ipm_central_retry`)",
                            "central_retry_off": "Without the central IPM retry before IPOPT's rescue "
                                                 "(`mpc.ipm_central_retry = off`)",
                            "after_hard_central": "The central attempt first after a hard solve "
                                                  "(`mpc.ipm_after_hard_attempt = central`)",
                            "after_hard_lower_mu": "The lower-mu attempt first after a hard solve "
                                                   "(`mpc.ipm_after_hard_attempt = lower_mu`)",
                            "after_hard_solves_1": "The after-hard attempt first after every hard solve "
                                                   "(`mpc.ipm_after_hard_solves = 1`)",
                            "after_hard_solves_2": "The after-hard attempt first after two hard solves in a row "
                                                   "(`mpc.ipm_after_hard_solves = 2`)"}
#: The default side's label.
DEFAULT = "default"
BEGIN_MARK = "<!-- BEGIN mcverify bench infeasibility (generated) -->"
END_MARK = "<!-- END mcverify bench infeasibility -->"


def section_key(paired: dict[str, Any] | None) -> str:
    """Whose generated section a result fills: "replay", the variant, or "VARIANT over BASE"."""
    if paired is None:
        return "replay"
    base = paired.get("base", DEFAULT)
    return paired["variant"] if base == DEFAULT else f"{paired['variant']} over {base}"


def marks(variant: str) -> tuple[str, str]:
    """The generated section's markers for one variant (or "replay", or "VARIANT over BASE")."""
    return (BEGIN_MARK.replace("infeasibility", f"infeasibility {variant}"),
            END_MARK.replace("infeasibility", f"infeasibility {variant}"))


def compare_policies(campaign: str, cell_name: str, episodes: int, variant: str = "phase1",
                     progress=print, seed: int | None = None, base: str = DEFAULT) -> dict[str, Any]:
    """The engine run on episodes 0 .. episodes - 1 of every chosen cell with the ``base`` settings
    (the default, or another variant) and with ``variant``, and their agreement (rows paired by
    ``episode_id``, unique in a run)."""
    if base == variant:
        raise ValueError(f"the variant and its base are both {variant!r}")
    runs = {}
    for name, overrides in ((base, VARIANTS.get(base, {})), (variant, VARIANTS[variant])):
        progress(f"settings {name}")
        runs[name] = engine.run(campaign=campaign, cell_name=cell_name, engine_episodes=episodes,
                                baseline_episodes=0, write=False, progress=progress,
                                overrides=overrides, seed=seed)["sides"]["engine"]
    ref, new = runs[base], runs[variant]
    ag = agreement(ref.rows, new.rows, key="episode_id", values=PAIRED_VALUES)
    per_cell = {}
    for cell in dict.fromkeys(r["cell"] for r in ref.rows):
        a = agreement([r for r in ref.rows if r["cell"] == cell], [r for r in new.rows if r["cell"] == cell],
                      key="episode_id", values=PAIRED_VALUES)
        per_cell[cell] = {k: a[k] for k in ("paired", "safe_agree", "outcome_agree")}
    audits = {k: sum(int(r[k]) for r in new.rows) for k in ("infeasibility_audits",
                                                              "infeasibility_audit_disagreements")}
    return {"variant": variant, "base": base, "runs": runs, "agreement": ag, "per_cell": per_cell, "audits": audits}


def replay_verdicts(paths: Sequence[str | Path], tol: float, progress=print) -> dict[str, Any]:
    """The verdict table (:func:`mcverify.bench.recorded_ipm.verdict_table`) over the recordings."""
    from mcverify.solver import kernels

    rows = []
    solves = 0
    cpu0 = time.process_time()
    for path in paths:
        rec = recorded_ipm.load(path)
        rp = recorded_ipm.Replayer(rec, kernels.get_runtime_library("ipm").so_path)
        solves += len(rec.solves)
        todo = [s for s in rec.solves if recorded_ipm.engine_class(s) != "converged"]
        progress(f"replay {path}: {len(todo)} of {len(rec.solves)} solves not converged by the IPM")
        rows += [recorded_ipm.verdicts(rp, s, tol) for s in todo]
    return {"solves": solves, "table": recorded_ipm.verdict_table(rows), "cpu_s": time.process_time() - cpu0,
            "phase1_ms": {c: 1e3 * _mean([v.phase1_cpu_s for v in rows if v.engine == c]) for c in
                          dict.fromkeys(v.engine for v in rows)}}


def _mean(xs: list[float]) -> float:
    return sum(xs) / len(xs) if xs else float("nan")


def markdown(paired: dict[str, Any] | None, replay: dict[str, Any] | None, command: str) -> str:
    """The generated section (both markers of its variant included)."""
    variant = paired["variant"] if paired is not None else "replay"
    begin, end = marks(section_key(paired))
    base = paired.get("base", DEFAULT) if paired is not None else DEFAULT
    base_words = "the default settings" if base == DEFAULT else base
    title = "recorded solves replayed" if paired is None else f"{variant} against {base_words}"
    heading = HEADINGS.get(variant, "The C restoration phase and infeasibility certificates")
    lines = [begin, "", f"## {heading}: {title}", "",
             f"### {datetime.now(timezone.utc):%Y-%m-%d}: `{command}`", "",
             f"{engine.machine()}, load average {engine._load()}."]
    if paired is not None:
        lines += ["", f"Paired episodes, engine only, {base_words} against {variant} "
                  f"({', '.join(f'`{k} = {v}`' for k, v in VARIANTS[variant].items())}). CPU-s per "
                  "episode by solve class (solves per episode):", "",
                  "| settings | episodes | CPU-s / episode | " + " | ".join(c.value for c in SolveClass) + " |",
                  "|---|---|---|" + "---|" * len(SolveClass)]
        for policy, side in paired["runs"].items():
            n = max(len(side.rows), 1)
            cells = " | ".join(f"{side.classes.cpu_s[c] / n:.2f} ({side.classes.count[c] / n:.1f})"
                               for c in SolveClass)
            lines.append(f"| {policy} | {len(side.rows)} | {side.cpu_s_per_episode:.2f} | {cells} |")
        ag = paired["agreement"]
        lines += ["", f"Agreement ({variant} against {base}): {ag['paired']} paired episodes, safety verdicts "
                  f"{ag['safe_agree']}/{ag['paired']} (95% CI {_ci(ag['safe_agree_ci'])}), outcomes "
                  f"{ag['outcome_agree']}/{ag['paired']} (95% CI {_ci(ag['outcome_agree_ci'])}); "
                  f"min distance to veh_f differs by at most {ag['min_dist_front_m_absdiff_max']:.3g} m. Per cell: "
                  + "; ".join(f"{c} {d['safe_agree']}/{d['outcome_agree']} of {d['paired']}"
                              for c, d in paired["per_cell"].items())
                  + f". Audits by IPOPT: {paired['audits']['infeasibility_audits']}, disagreements "
                  f"{paired['audits']['infeasibility_audit_disagreements']}."]
        for d in ag["disagreements"]:
            lines.append(f"- differs: {d['cell']} episode {d['episode_id']}: safe {d['safe_ref']} -> {d['safe_new']}, "
                         f"outcome {d['outcome_ref']} -> {d['outcome_new']}")
    if replay is not None:
        lines += ["", f"Recorded solves replayed ({replay['solves']} engine solves, {replay['cpu_s']:.0f} CPU-s): "
                  "the solves the IPM did not converge on, by what the engine made of them, against the "
                  "start-independent phase-1 verdict (infeasible: phase 1 certified from the warm start and from "
                  "the cold guess; feasible: one found a feasible point; undecided: neither) and the engine's "
                  "attempts rerun with the restoration phase on, and the central warm attempt "
                  "(`mpc.ipm_central_attempt`) on those with a warm start:", "",
                  "| engine (IPOPT as fallback) | solves | phase 1: infeasible | feasible | undecided | "
                  "warm-only certificate | converged with restoration | converged by the central attempt "
                  "(of warm-started) | phase-1 ms / solve |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for cls, d in replay["table"].items():
            lines.append(f"| {cls} | {d['solves']} | {d['infeasible']} | {d['feasible']} | {d['undecided']} | "
                         f"{d['warm_only_infeasible']} | {d['resto_converged']} | "
                         f"{d['central_converged']} ({d['warm_started']}) | "
                         f"{replay['phase1_ms'][cls]:.0f} |")
    lines += ["", end, ""]
    return "\n".join(lines)


def _ci(ci) -> str:
    return "n/a" if ci is None else f"{ci[0]:.2f}-{ci[1]:.2f}"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mcverify.bench.infeasibility", description=__doc__.split("\n")[0])
    ap.add_argument("--campaign", default=engine.DEFAULT_CAMPAIGN)
    ap.add_argument("--cell", default=engine.ALL_CELLS)
    ap.add_argument("--episodes", type=int, default=1, help="paired episodes per cell (0: replay only)")
    ap.add_argument("--variant", choices=tuple(VARIANTS), default="phase1", help="settings compared with the default")
    ap.add_argument("--base", choices=(DEFAULT, *VARIANTS), default=DEFAULT,
                    help="the settings the variant is paired with (default: the model's defaults)")
    ap.add_argument("--seed", type=int, help="campaign seed instead of the file's (episodes a recording has not seen)")
    ap.add_argument("--recording", action="append", default=[], help="a recorded_ipm pickle to replay")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    say = lambda m: print(m, file=sys.stderr)  # noqa: E731
    if args.base == args.variant:
        ap.error(f"--base and --variant are both {args.variant}")
    paired = (compare_policies(args.campaign, args.cell, args.episodes, args.variant, say, args.seed, args.base)
              if args.episodes else None)
    from mcverify.model import ModelParams

    replay = replay_verdicts(args.recording, ModelParams().mpc.tol, say) if args.recording else None
    command = "python -m mcverify.bench.infeasibility " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    text = markdown(paired, replay, command.strip())
    print(text)
    if not args.no_write:
        store.replace_section(Path(BENCHMARKS_MD), text, *marks(section_key(paired)))
        say(f"wrote {BENCHMARKS_MD}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
