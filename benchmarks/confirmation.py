"""The confirmation rule measured on a run made before it: every turn-back that the run decided on a
presumed Q1 failure (column ``went_back_q1_failure``), re-simulated with this code on the same noise and
draws, before and after, with the reference solver's audits of the run beside them.

    python -m benchmarks.confirmation RUN_DIR [--workers W] [--check-unchanged K] [--no-write]

The rule (:meth:`mcverify.control.planner.Planner._switch_presumed`) acts only at a step where a presumed Q1
failure meets a solved Q2 while overtaking. With the default abandonment rule (``first_failure``) such a step
turns back at once, so an episode of the old run that never turned back on a presumed verdict never met one,
and this code re-simulates it unchanged: only the listed episodes can move. ``--check-unchanged K`` replays K
of the others bit for bit as a check of that argument. A run whose cells wait before abandoning
(``consecutive``, ``certified``) can change elsewhere too; rerun it instead (refused here).
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from benchmarks import section
from mcverify import store
from mcverify.analysis.intervals import proportion_interval, zero_event_upper_bound
from mcverify.campaign.audit import recorded
from mcverify.campaign.replay import ReplayMismatch, replay, resimulate
from mcverify.campaign.runner import campaign_from_manifest
from mcverify.errors import UserError

NAME = "confirmation"
#: What a re-simulated episode keeps for the table.
KEPT = ("outcome", "safe", "collision_front", "collision_opp", "min_h_front", "went_back_q1_failure",
        "q1_confirm_solves", "q1_confirm_solved", "solves")


def _collided(row: Mapping[str, Any]) -> bool:
    return bool(row["collision_front"]) or bool(row["collision_opp"])


def _resimulated(job: tuple[str, int]) -> dict[str, Any]:
    """One stored episode re-simulated by this code (a worker process's task)."""
    run_dir, episode_id = job
    cpu0 = time.process_time()
    _, _, result = resimulate(Path(run_dir), episode_id, record=False)
    row = result.rows[0]
    return {"episode_id": episode_id, **{k: row[k] for k in KEPT}, "cpu_s": time.process_time() - cpu0}


def _unchanged(job: tuple[str, int]) -> str:
    """'' when the episode replays bit for bit under this code, else the mismatch."""
    run_dir, episode_id = job
    try:
        replay(Path(run_dir), episode_id, out_dir=Path(run_dir) / "replay-confirmation")
    except ReplayMismatch as exc:
        return f"episode {episode_id}: {exc}"
    return ""


def targets(rows: Sequence[Mapping[str, Any]]) -> list[int]:
    """The episodes that turned back on a presumed Q1 failure."""
    return [int(r["episode_id"]) for r in rows if r.get("went_back_q1_failure") == "presumed_infeasible"]


def spread(ids: Sequence[int], k: int) -> list[int]:
    """``k`` of ``ids`` spread evenly over them (the first, then every len/k-th)."""
    if k <= 0 or not ids:
        return []
    return list(ids[:: max(1, len(ids) // k)][:k])


def _rate(k: int, n: int) -> str:
    if k == 0:
        return f"0/{n} (≤ {zero_event_upper_bound(n):.2g})"
    ci = proportion_interval(k, n)
    return f"{k}/{n} = {k / n:.2g} [{ci.low:.2g}, {ci.high:.2g}]"


def cell_rows(stored: Sequence[Mapping[str, Any]], after: Mapping[int, Mapping[str, Any]],
              cell_names: Sequence[str]) -> list[list[str]]:
    """Per cell: episodes, presumed turn-backs, what they do now, collisions before and after, and unsafe
    episodes (a collision or h_ef < 0) after."""
    out = []
    for index, name in enumerate(cell_names):
        mine = [r for r in stored if int(r["cell_index"]) == index]
        moved = [after[int(r["episode_id"])] for r in mine if int(r["episode_id"]) in after]
        before_k = sum(_collided(r) for r in mine)
        now_k = sum(_collided(after.get(int(r["episode_id"]), r)) for r in mine)
        unsafe_k = sum(not after.get(int(r["episode_id"]), r)["safe"] for r in mine)
        back_now = sum(m["outcome"] == "went_back" for m in moved)
        out.append([name, str(len(mine)), str(len(moved)), str(len(moved) - back_now), str(back_now),
                    str(sum(m["q1_confirm_solves"] for m in moved)), _rate(before_k, len(mine)),
                    _rate(now_k, len(mine)), _rate(unsafe_k, len(mine))])
    return out


def audit_lines(audits: Mapping[str, Mapping[str, Any]], after: Mapping[int, Mapping[str, Any]]) -> list[str]:
    """The run's reference-solver audits set beside the re-simulated episodes."""
    lines = []
    for key, a in audits.items():
        now = after.get(int(key))
        if now is None:
            continue
        agree = now["outcome"] == a["reference_outcome"] and bool(now["safe"]) == bool(a["reference_safe"])
        lines.append(f"episode {key}: the run {a['outcome']} (safe {a['safe']}), IPOPT at every step "
                     f"{a['reference_outcome']} (safe {a['reference_safe']}), this code {now['outcome']} "
                     f"(safe {bool(now['safe'])}, min h_ef {now['min_h_front']:.3f}): "
                     f"{'agrees with' if agree else 'differs from'} the reference")
    return lines


def build(run_dir: Path, cmd: str, workers: int, check_unchanged: int) -> str:
    manifest = store.read_manifest(run_dir)
    if not manifest.get("finished_utc"):
        raise UserError(f"{run_dir} is not finished: `mcverify run --resume {run_dir}` first")
    campaign = campaign_from_manifest(manifest)
    waiting = [c.name for c in campaign.cells if c.params.mpc.abandon_rule != "first_failure"]
    if waiting:
        raise UserError(f"{run_dir}: cell {waiting[0]} waits before abandoning (mpc.abandon_rule "
                        f"{campaign.cells[0].params.mpc.abandon_rule!r}): the rule can change episodes that never "
                        "turned back there; rerun the campaign instead")
    stored = store.read_episodes(run_dir).to_pylist()
    ids = targets(stored)
    others = spread([int(r["episode_id"]) for r in stored if int(r["episode_id"]) not in set(ids)], check_unchanged)
    ctx = multiprocessing.get_context("spawn")  # JAX and forked processes do not mix
    t0 = time.perf_counter()
    with ctx.Pool(workers) as pool:
        moved = pool.map(_resimulated, [(str(run_dir), e) for e in ids], chunksize=1)
        mismatches = [m for m in pool.map(_unchanged, [(str(run_dir), e) for e in others], chunksize=1) if m]
    wall_s = time.perf_counter() - t0
    after = {m["episode_id"]: m for m in moved}
    head = ["cell", "episodes", "turned back on a presumed verdict (run)", "now overtake", "now turn back",
            "confirmation solves", "P(collision), the run", "P(collision), this code", "P(unsafe), this code"]
    body = cell_rows(stored, after, [c.name for c in campaign.cells])
    table = "\n".join(["| " + " | ".join(head) + " |", "|" + "---|" * len(head),
                       *("| " + " | ".join(r) + " |" for r in body)])
    confirm = sum(m["q1_confirm_solves"] for m in moved)
    solves = sum(m["solves"] for m in moved)
    env = manifest["environment"]
    checked = (f"{len(others)} of the other episodes replayed bit for bit under this code: "
               + ("all identical." if not mismatches else "MISMATCH: " + "; ".join(mismatches)))
    return "\n".join([
        "## The confirmation rule on a stored run (`python -m benchmarks.confirmation`)", "",
        section.provenance_line(cmd), "",
        f"Run `{run_dir.name}` (campaign {campaign.name}, made at commit `{str(env.get('git_commit', '?'))[:7]}`, "
        "before the rule). Intervals: exact 95 % (Clopper-Pearson), one-sided where no event occurred. "
        f"{len(ids)} turn-backs decided on a presumed Q1 failure re-simulated in {wall_s / 60:.1f} min wall on "
        f"{workers} processes ({sum(m['cpu_s'] for m in moved) / 60:.1f} CPU-min). The rule's cost there: "
        f"{confirm} confirmation solves among {solves} solves of those episodes. {checked}", "",
        table, "", *(f"- {line}" for line in audit_lines(recorded(run_dir), after)),
    ])


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        p = section.parser(NAME, __doc__.splitlines()[0])
        p.add_argument("run_dir", type=Path, help="a finished run folder made before the confirmation rule")
        p.add_argument("--workers", type=int, default=2, help="processes re-simulating episodes (default 2)")
        p.add_argument("--check-unchanged", type=int, default=2, metavar="K",
                       help="other episodes replayed bit for bit as a check (default 2)")
        section.add_output_options(p)
        args = p.parse_args(argv)
        if not (args.run_dir / store.MANIFEST).is_file():
            raise UserError(f"run folder not found: {args.run_dir}")
        if args.workers < 1 or args.check_unchanged < 0:
            raise UserError("--workers must be >= 1 and --check-unchanged >= 0")
        text = build(args.run_dir, section.command(NAME, argv), args.workers, args.check_unchanged)
        section.publish(NAME, section.wrap(NAME, text), args)
        return 0

    return section.run_main(NAME, body)


if __name__ == "__main__":
    raise SystemExit(main())
