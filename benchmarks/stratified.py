"""An exact lower bound on a rare event's probability from strata of its decisive draws.

Issue 50's reference (ii), beside the rare-event estimates of one cell: crude Monte Carlo inside boxes of the
inputs that decide the event (:mod:`mcverify.estimate.strata`: each box's probability exact, P(event | box)
bounded by Clopper-Pearson, Bonferroni over the boxes). Episodes are run in chunks, each deterministic from
(``--seed``, stratum, chunk) whatever ``--workers``; a chunk's result is kept in OUT as soon as it is back, so
a killed run resumes with the same command. With ``--replay`` every event found is re-simulated alone and its
robustness compared bit for bit.

    python -m benchmarks.stratified campaigns/rare_validation_10hz.toml \
        --strata benchmarks/strata/validation_10hz.toml --set noise.scale=1.1 --target ellipse --workers 2 \
        --out-dir runs/strata110 --replay
"""

from __future__ import annotations

import dataclasses
import json
import math
import multiprocessing
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks import section
from mcverify import files
from mcverify.errors import RunError, UserError
from mcverify.estimate import strata
from mcverify.requirements import TARGETS

NAME = "stratified"
CHUNK = 10  # episodes per work unit (one rollout call)
BOUND = "bound.json"  # OUT's finished bound: what benchmarks.continuation draws beside the estimates

_PROBLEM: dict[tuple, object] = {}  # one closed loop per process (its solver loads once)


def problem_of(campaign_path: str, settings: tuple[str, ...], target: str):
    """The campaign's only cell as a :class:`~mcverify.estimate.input_vector.ClosedLoopProblem` (cached per process)."""
    key = (campaign_path, settings, target)
    if key not in _PROBLEM:
        from mcverify.campaign.spec import load_campaign
        from mcverify.estimate import subset_run

        campaign = load_campaign(Path(campaign_path), settings=list(settings))
        if len(campaign.cells) != 1:
            raise RunError(f"{campaign_path}: the strata are boxes of one cell's inputs; this campaign has "
                           f"{len(campaign.cells)} cells (fix the others with --set)")
        _PROBLEM[key] = subset_run.problem_for(campaign.cells[0], campaign.seed, target)
    return _PROBLEM[key]


def chunk_inputs(problem, stratum: strata.Stratum, seed: int, index: int, chunk: int) -> np.ndarray:
    """The input vectors of chunk ``chunk`` of stratum ``index``: a pure function of (seed, index, chunk)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(index, chunk)))
    n = min(CHUNK, stratum.episodes - chunk * CHUNK)
    return stratum.inputs(problem, rng, n)


def run_chunk(job: tuple) -> tuple[int, int, dict[str, np.ndarray]]:
    """One work unit: simulate a chunk; its robustness, control steps and the inputs of its events."""
    campaign_path, settings, target, strata_path, seed, index, chunk = job
    problem = problem_of(campaign_path, settings, target)
    stratum = strata.load_strata(Path(strata_path))[index]
    x = chunk_inputs(problem, stratum, seed, index, chunk)
    start = time.process_time()
    g, steps = problem.evaluate(x)
    return index, chunk, {"g": g, "steps": steps, "x_events": x[g <= 0.0], "g_events": g[g <= 0.0],
                          "cpu_s": np.array(time.process_time() - start)}


def chunk_path(out: Path, index: int, chunk: int) -> Path:
    return out / f"stratum-{index:02d}" / f"chunk-{chunk:04d}.npz"


def _save(tmp: str, arrays: dict[str, np.ndarray]) -> None:
    with open(tmp, "wb") as f:
        np.savez(f, **arrays)


def run_strata(args, jobs_for: list[tuple[int, int]], base: tuple) -> None:
    """Run the chunks not kept in OUT yet, each saved as it comes back."""
    todo = [(i, c) for i, c in jobs_for if not chunk_path(args.out_dir, i, c).is_file()]
    print(f"{len(jobs_for) - len(todo)} of {len(jobs_for)} chunks kept in {args.out_dir}; running {len(todo)}",
          flush=True)

    def keep(result) -> None:
        i, c, arrays = result
        path = chunk_path(args.out_dir, i, c)
        path.parent.mkdir(parents=True, exist_ok=True)
        files.atomic_write(path, lambda tmp: _save(tmp, arrays))
        print(f"  stratum {i} chunk {c}: {int((arrays['g'] <= 0).sum())} events in {arrays['g'].size}", flush=True)

    jobs = [(*base, i, c) for i, c in todo]
    if args.workers <= 1:
        for job in jobs:
            keep(run_chunk(job))
        return
    with ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        for result in pool.map(run_chunk, jobs):  # in order: the same files whatever the workers
            keep(result)


def _read(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


def counts(args, problem, all_strata: Sequence[strata.Stratum]) -> list[dict]:
    """Per stratum: its box's probability, events, episodes, control steps, CPU and the events' inputs."""
    out = []
    for i, s in enumerate(all_strata):
        parts = [_read(chunk_path(args.out_dir, i, c)) for c in range(math.ceil(s.episodes / CHUNK))]
        g = np.concatenate([p["g"] for p in parts])
        out.append({"stratum": s, "probability": s.probability(problem), "events": int((g <= 0).sum()),
                    "episodes": int(g.size), "steps": int(sum(p["steps"].sum() for p in parts)),
                    "cpu_s": float(sum(float(p["cpu_s"]) for p in parts)),
                    "x_events": np.concatenate([p["x_events"] for p in parts]),
                    "g_events": np.concatenate([p["g_events"] for p in parts]), "g_min": float(g.min())})
    return out


def replay(problem, rows: list[dict]) -> tuple[int, int]:
    """Re-simulate every event alone; (identical, all)."""
    same = total = 0
    for r in rows:
        for x, g in zip(r["x_events"], r["g_events"], strict=True):
            got, _ = problem.evaluate(x[None, :])
            same += int(np.float64(got[0]).tobytes() == np.float64(g).tobytes())
            total += 1
    return same, total


def write_bound(args, problem, rows: list[dict], bound: strata.Bound) -> None:
    """OUT/bound.json: the bound with the cell's parameters (as a run's manifest records them) and its counts."""
    record = {"target": args.target, "level": bound.level, "lower": bound.lower, "point": bound.point,
              "episodes": sum(r["episodes"] for r in rows), "events": sum(r["events"] for r in rows),
              "seed": args.seed, "strata": str(args.strata), "settings": list(args.settings),
              "params": json.loads(json.dumps(dataclasses.asdict(problem.cell.params), default=files.json_default))}
    files.write_json_atomic(args.out_dir / BOUND, record)


def _box_text(s: strata.Stratum) -> str:
    draws = [f"{name} in [{lo:g}, {hi:g}]" for name, lo, hi in s.draws]
    units = [f"{u.channel}[{u.step}] in [{u.low:g}, {u.high:g}]" for u in s.units]
    return ", ".join(draws + units)


def render(cmd: str, rows: list[dict], bound: strata.Bound, replayed: tuple[int, int] | None, target: str,
           settings: Sequence[str]) -> str:
    m = len(rows)
    lines = [f"## An exact lower bound from strata of the decisive draws (`python -m benchmarks.{NAME}`)", "",
             section.provenance_line(cmd), "",
             f"Target: {target} (robustness <= 0), cell settings {', '.join(settings) or 'as in the file'}. Each "
             "stratum is a box of the episode's inputs (scenario values; perception-error units per control step "
             "and channel, uniform in [-1, 1]) whose probability P(R) is exact; crude Monte Carlo inside it gives k "
             "events in n episodes. The bound is the sum over strata of P(R) times the one-sided Clopper-Pearson "
             f"lower bound of k/n at level 1 - {1 - bound.level:g}/{m} (Bonferroni), so it holds at "
             f"{bound.level:.0%} whatever the strata; the point is the sum of P(R) k/n, the strata's share of "
             "P(event) (the event outside the boxes is not counted).", "",
             "| stratum | box | P(R) | events / episodes | P(event and R), point | lower bound | control steps "
             "| CPU (s) |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r, (lo, pt) in zip(rows, bound.per_stratum, strict=True):
        lines.append(f"| {r['stratum'].name} | {_box_text(r['stratum'])} | {r['probability']:.4g} | "
                     f"{r['events']} / {r['episodes']} | {pt:.3g} | {lo:.3g} | {r['steps']} | {r['cpu_s']:.0f} |")
    lines += ["", f"**P({target}) >= {bound.lower:.3g}** ({bound.level:.0%}, exact); the strata's point "
              f"{bound.point:.3g}; {sum(r['episodes'] for r in rows)} episodes, "
              f"{sum(r['steps'] for r in rows)} control steps, {sum(r['cpu_s'] for r in rows) / 60:.0f} CPU-min."]
    if replayed is not None:
        lines.append(f"Replay: {replayed[0]} of {replayed[1]} events re-simulated alone reproduce their robustness "
                     "bit for bit.")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        p = section.parser(NAME, __doc__.splitlines()[0])
        p.add_argument("campaign", type=Path, help="campaign file with one cell (after --set)")
        p.add_argument("--strata", type=Path, required=True, help="TOML file of [[stratum]] boxes")
        p.add_argument("--set", dest="settings", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                       help="override a model parameter (repeatable)")
        p.add_argument("--target", default="ellipse", choices=tuple(TARGETS), help="the event (default ellipse)")
        p.add_argument("--seed", type=int, default=0, help="keys every chunk's draws (default 0)")
        p.add_argument("--workers", type=int, default=1, help="processes (default 1)")
        p.add_argument("--level", type=float, default=0.95, help="confidence level (default 0.95)")
        p.add_argument("--out-dir", type=Path, required=True, help="where the chunks are kept (resumable)")
        p.add_argument("--replay", action="store_true", help="re-simulate every event alone, bit for bit")
        section.add_output_options(p)
        args = p.parse_args(argv)
        if not 0.0 < args.level < 1.0 or args.workers < 1:
            raise UserError("--level must lie in (0, 1) and --workers be at least 1")
        if not args.campaign.is_file():
            raise UserError(f"{args.campaign}: no such campaign file")
        all_strata = strata.load_strata(args.strata)
        base = (str(args.campaign), tuple(args.settings), args.target, str(args.strata), args.seed)
        problem = problem_of(*base[:3])
        strata.check_disjoint(all_strata, problem)  # every box checked against the cell before anything runs
        run_strata(args, [(i, c) for i, s in enumerate(all_strata) for c in range(math.ceil(s.episodes / CHUNK))],
                   base)
        rows = counts(args, problem, all_strata)
        bound = strata.lower_bound([strata.StratumCount(r["stratum"].name, r["probability"], r["events"],
                                                        r["episodes"]) for r in rows], args.level)
        replayed = replay(problem, rows) if args.replay else None
        write_bound(args, problem, rows, bound)
        text = render(section.command(NAME, argv), rows, bound, replayed, args.target, args.settings)
        section.publish(NAME, section.wrap(NAME, text), args)
        return 0

    return section.run_main(NAME, body)


if __name__ == "__main__":
    raise SystemExit(main())
