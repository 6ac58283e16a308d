"""Record the engine's backend solves of closed loops and replay them on the C interior point.

Replaying recorded problems is far cheaper than running episodes: one Table IV episode costs
about 12 CPU-s, its ~400 backend solves replay on the IPM in a second or two. Used to measure the
restoration phase and the phase-1 certificates of :mod:`mcverify.solver.ipm` on the problems the
engine met (which IPOPT certified infeasible, which it rescued) and to check that the default
IPM attempts reproduce the recorded ones bit for bit (``tests/bench/test_recorded_ipm.py``).

A :class:`RecordedSolve` holds what :meth:`mcverify.solver.backends.IpmBackend.solve` got (the
parameter vector, the warm start, the cold guess) and what the engine answered (status string,
success); the kernel and bounds are held once per problem structure (:class:`ProblemKey`).
Recordings are pickled (:func:`save`, :func:`load`); nothing of them is committed.
"""

from __future__ import annotations

import dataclasses
import pickle
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mcverify.solver.backends import IpmBackend, Start
from mcverify.solver.ipm import Ipm, IpmOptions, IpmResult


@dataclass(frozen=True)
class ProblemKey:
    """One problem structure: the kernel's shared object and the NLP's bounds."""

    kernel_so: str
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray


@dataclass(frozen=True)
class RecordedSolve:
    """One backend solve: problem index (into :attr:`Recording.problems`), p (n_p,), the warm start
    (or None), the cold guess (n_w,), fast_only, and the engine's answer (``str`` of its status,
    success, IPM attempts' statuses in order)."""

    problem: int
    p: np.ndarray
    warm: Start | None
    guess: np.ndarray
    fast_only: bool
    status: str
    success: bool
    attempts: tuple[str, ...]

    @property
    def certified_by_ipopt(self) -> bool:
        """The IPM failed and IPOPT, as the fallback, reported local infeasibility."""
        return self.status == "fallback:Infeasible_Problem_Detected"

    @property
    def rescued_by_ipopt(self) -> bool:
        """The IPM failed and IPOPT, as the fallback, solved it."""
        return self.success and self.status.startswith("fallback:")


@dataclass
class Recording:
    problems: list[ProblemKey] = dataclasses.field(default_factory=list)
    solves: list[RecordedSolve] = dataclasses.field(default_factory=list)


class RecordingBackend:
    """Wraps an :class:`IpmBackend`: every solve's inputs and answer go into ``recording``."""

    def __init__(self, backend: IpmBackend, recording: Recording) -> None:
        self.backend = backend
        self.recording = recording
        pr = backend.problem
        recording.problems.append(ProblemKey(str(pr.kernel.so_path), pr.lbx, pr.ubx, pr.lbg, pr.ubg))
        self.index = len(recording.problems) - 1

    def solve(self, p, warm, guess, fast_only: bool = False):
        g = np.array(guess(), dtype=float)
        before = dict(self.backend.ipm_outcomes)
        res = self.backend.solve(p, warm, lambda: g.copy(), fast_only=fast_only)
        # this solve's attempt tags ("warm1:<status>", ..., "cold3:<status>"), in the order they ran
        new = [t for t, n in self.backend.ipm_outcomes.items() if n > before.get(t, 0)]
        order = [number for number, _, _ in self.backend.attempts(warm, fast_only)]
        attempts = tuple(sorted(new, key=lambda t: order.index(int(t.split(":")[0].lstrip("warmcold")))))
        w = (None if warm is None
             else Start(np.array(warm.x), np.array(warm.lam_x), np.array(warm.lam_g), warm.hard_run))
        self.recording.solves.append(RecordedSolve(
            self.index, np.array(p, dtype=float), w, g, bool(fast_only), str(res.status), bool(res.success), attempts))
        return res

    def __getattr__(self, name):
        return getattr(self.backend, name)


def record_engine(cells: Sequence, seed: int, episode_ids: Sequence[int], common_random_numbers: bool = False
                  ) -> Recording:
    """Run ``episode_ids`` of every cell with the engine (its ``ipm`` backend) and record every
    backend solve (``common_random_numbers``: the campaign's setting, see ``run_episodes``)."""
    from mcverify.control.planner import Planner
    from mcverify.episode.rollout import run_episodes
    from mcverify.solver.mpc import MpcSolver

    rec = Recording()

    def factory(params, structure):
        solver = MpcSolver(params, structure)
        solver.backend = RecordingBackend(solver.backend, rec)
        return solver

    for cell in cells:
        if cell.params.mpc.backend != "ipm":
            raise ValueError(f"cell {cell.name}: record_engine needs the ipm backend")
        run_episodes(cell, list(episode_ids), seed, Planner(cell.params, solver_factory=factory),
                     common_random_numbers=common_random_numbers)
    return rec


def save(rec: Recording, path: str | Path) -> None:
    Path(path).write_bytes(pickle.dumps(rec, protocol=pickle.HIGHEST_PROTOCOL))


class _Unpickler(pickle.Unpickler):
    """Reads recordings whose classes were pickled as ``__main__.Recording`` (files written by
    ``python -m`` before the command line imported this module by its name)."""

    def find_class(self, module: str, name: str):
        return super().find_class(__name__ if module == "__main__" else module, name)


def load(path: str | Path) -> Recording:
    with open(path, "rb") as f:
        rec = _Unpickler(f).load()  # noqa: S301 - our own benchmark files
    for s in rec.solves:  # files written before Start counted hard solves in a row held a flag, after_hard
        if s.warm is not None and "after_hard" in vars(s.warm):
            object.__setattr__(s.warm, "hard_run", int(vars(s.warm).pop("after_hard")))
    return rec


class Replayer:
    """The C IPM on every problem structure of a recording (one :class:`Ipm` per structure)."""

    def __init__(self, rec: Recording, library_so: str | Path) -> None:
        self.rec = rec
        self.ipms = [Ipm(k.kernel_so, k.lbx, k.ubx, k.lbg, k.ubg, library_so) for k in rec.problems]

    def solve(self, s: RecordedSolve, options: IpmOptions, warm: bool) -> IpmResult:
        """One IPM solve of ``s`` from its warm start (``warm``; requires one) or its cold guess."""
        ipm = self.ipms[s.problem]
        if warm:
            return ipm.solve(s.p, s.warm.x, s.warm.lam_x, s.warm.lam_g, options)
        return ipm.solve(s.p, s.guess, None, None, options)

    def engine_attempts(self, s: RecordedSolve, warm_attempts: Iterable[IpmOptions], cold: IpmOptions
                        ) -> list[IpmResult]:
        """The IPM attempts of :meth:`IpmBackend.solve` in order, up to the first converged one."""
        out = []
        starts = ([(o, True) for o in warm_attempts] if s.warm is not None else []) + [(cold, False)]
        for o, w in starts:
            out.append(self.solve(s, o, w))
            if out[-1].success:
                break
        return out


# ------------------------------------------------------------------ infeasibility verdicts


def engine_class(s: RecordedSolve) -> str:
    """What the engine made of ``s``: "converged" (by the IPM), "rescued" / "certified" (by IPOPT
    as the fallback), "presumed" (IPM only, memo), "other" (IPOPT failed otherwise)."""
    if s.status.startswith("presumed_infeasible:"):
        return "presumed"
    if s.certified_by_ipopt:
        return "certified"
    if s.rescued_by_ipopt:
        return "rescued"
    return "converged" if s.success else "other"


@dataclass(frozen=True)
class Verdicts:
    """The C restoration phase on one recorded solve: phase 1 from the warm start (None: no warm
    start) and from the cold guess (status names), the start-independent verdict ("infeasible" if
    every phase 1 certified, "feasible" if one found a feasible point, else "undecided"), and the
    engine's IPM attempts rerun with the restoration phase on (did one converge; its status list), and
    the central warm attempt of ``mpc.ipm_central_attempt`` (did it converge; None without a warm
    start). cpu_s: CPU seconds of the phase-1 runs, of the restoration attempts, of the central one."""

    engine: str
    phase1_warm: str | None
    phase1_cold: str
    verdict: str
    resto_converged: bool
    resto_attempts: tuple[str, ...]
    phase1_cpu_s: float
    resto_cpu_s: float
    central_converged: bool | None = None
    central_cpu_s: float = 0.0


def verdicts(rp: Replayer, s: RecordedSolve, tol: float) -> Verdicts:
    """Replay ``s`` under the phase-1 certificate and the restoration-enabled attempts."""
    import time

    from mcverify.solver.ipm import CENTRAL_WARM, COLD, WARM_ATTEMPTS

    t0 = time.process_time()
    warm = None if s.warm is None else rp.solve(s, dataclasses.replace(WARM_ATTEMPTS[0], tol=tol, phase1=True), True)
    cold = rp.solve(s, dataclasses.replace(COLD, tol=tol, phase1=True), False)
    t1 = time.process_time()
    runs = [r.status for r in (warm, cold) if r is not None]
    if all(st == "Infeasible_Problem_Detected" for st in runs):
        verdict = "infeasible"
    elif "Feasible_Point_Found" in runs:
        verdict = "feasible"
    else:
        verdict = "undecided"
    attempts = rp.engine_attempts(s, [dataclasses.replace(o, tol=tol, restoration=True) for o in WARM_ATTEMPTS],
                                  dataclasses.replace(COLD, tol=tol, restoration=True))
    t2 = time.process_time()
    central = None if s.warm is None else rp.solve(s, dataclasses.replace(CENTRAL_WARM, tol=tol), True).success
    return Verdicts(engine_class(s), None if warm is None else warm.status, cold.status, verdict,
                    attempts[-1].success, tuple(a.status for a in attempts), t1 - t0, t2 - t1,
                    central, time.process_time() - t2)


def verdict_table(rows: Sequence[Verdicts]) -> dict[str, dict[str, int]]:
    """engine class -> {start-independent verdict: count, "resto_converged", "warm_started" (had a warm
    start), "central_converged" (the central warm attempt converged): counts, "solves": count}."""
    out: dict[str, dict[str, int]] = {}
    for v in rows:
        d = out.setdefault(v.engine, {"solves": 0, "infeasible": 0, "feasible": 0, "undecided": 0,
                                      "warm_only_infeasible": 0, "resto_converged": 0, "warm_started": 0,
                                      "central_converged": 0})
        d["solves"] += 1
        d["warm_started"] += int(v.central_converged is not None)
        d["central_converged"] += int(bool(v.central_converged))
        d[v.verdict] += 1
        d["resto_converged"] += int(v.resto_converged)
        warm_cert = v.phase1_warm == "Infeasible_Problem_Detected"
        d["warm_only_infeasible"] += int(warm_cert and v.phase1_cold != "Infeasible_Problem_Detected")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mcverify.bench.recorded_ipm CAMPAIGN --out FILE [--episodes 0,1] [--seed S] [--cell NAME]``:
    record the engine's solves of those episodes of every cell (or one) into a pickle."""
    import argparse
    import sys

    from mcverify.campaign.spec import load_campaign
    from mcverify.errors import CampaignError

    ap = argparse.ArgumentParser(prog="python -m mcverify.bench.recorded_ipm", description=main.__doc__.split("\n")[1])
    ap.add_argument("campaign")
    ap.add_argument("--out", required=True, help="the pickle to write")
    ap.add_argument("--episodes", default="0", help="comma-separated episode ids per cell (default 0)")
    ap.add_argument("--seed", type=int, help="campaign seed instead of the file's")
    ap.add_argument("--cell", help="one cell's name (default: every cell)")
    args = ap.parse_args(argv)
    try:
        camp = load_campaign(args.campaign, seed=args.seed)
        episodes = [int(e) for e in args.episodes.split(",")]
    except (CampaignError, ValueError) as err:
        print(f"mcverify: error: {err}", file=sys.stderr)
        return 2
    cells = [c for c in camp.cells if args.cell in (None, c.name)]
    if not cells:
        print(f"mcverify: error: no cell {args.cell!r} in {args.campaign}", file=sys.stderr)
        return 2
    rec = record_engine(cells, camp.seed, episodes, camp.common_random_numbers)
    save(rec, args.out)
    print(f"{len(rec.solves)} solves of {len(cells)} cell(s) x {len(episodes)} episode(s) -> {args.out}")
    return 0


if __name__ == "__main__":
    # the module by its package name, so that the pickle's classes are not "__main__.Recording"
    from mcverify.bench import recorded_ipm

    raise SystemExit(recorded_ipm.main())
