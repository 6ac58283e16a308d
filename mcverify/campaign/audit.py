"""Audit a stored episode with the reference solver: the same episode (same noise, same scenario draws)
re-simulated with ``mpc.backend = "ipopt"``, IPOPT solving every problem in full at every step.

A verdict of the fast path (``ipm``) can sit on a knife edge of the solver path: an unsafe episode the
reference solver reproduces is the controller's ("confirmed by the reference solver"); one whose verdict
changes is the solver's as much as the controller's ("solver-dependent"). Nothing is compared bit for
bit here (the solvers differ); :func:`mcverify.campaign.replay.replay` does that.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from mcverify import files, store
from mcverify.analysis.cells import json_ready
from mcverify.analysis.robustness import robustness
from mcverify.campaign import executors
from mcverify.campaign.replay import stored_schedules, write_recording
from mcverify.campaign.runner import campaign_from_manifest
from mcverify.cell import Cell
from mcverify.episode.rollout import run_episodes
from mcverify.errors import RunError

#: The reference solver's backend name (:data:`mcverify.model.BACKEND_NAMES`).
REFERENCE_BACKEND = "ipopt"


class AuditVerdict(str, Enum):
    """What the reference solver says of a stored episode's safety verdict."""

    CONFIRMED = "confirmed by the reference solver"  # the same safe/unsafe verdict
    SOLVER_DEPENDENT = "solver-dependent"  # the reference solver gives the other verdict
    REFERENCE_RUN = "the run used the reference solver"  # nothing to audit


@dataclass(frozen=True)
class AuditResult:
    episode_id: int
    verdict: AuditVerdict
    stored: dict  # the run's row
    reference: dict | None  # the reference solver's row (None for a run made with it)
    trajectory_path: Path | None
    plot_path: Path | None
    requirement: str = "safe"  # what the verdict compares: whether this requirement is violated

    def describe(self) -> str:
        """One line: both outcomes and the verdict."""
        ran = f"{self.stored['outcome']}, safe={self.stored['safe']}"
        if self.reference is None:
            return f"episode {self.episode_id} ({ran}): {self.verdict.value}; nothing to audit"
        if self.requirement != "safe":
            ran += f", {self.requirement} {'violated' if violated(self.stored, self.requirement) else 'holds'}"
            ref = (f"{self.reference['outcome']}, safe={self.reference['safe']}, {self.requirement} "
                   f"{'violated' if violated(self.reference, self.requirement) else 'holds'}")
            return (f"episode {self.episode_id}: {self.verdict.value} (the run: {ran}; "
                    f"the reference solver {REFERENCE_BACKEND}: {ref})")
        ref = f"{self.reference['outcome']}, safe={self.reference['safe']}"
        return (f"episode {self.episode_id}: {self.verdict.value} (the run: {ran}; "
                f"the reference solver {REFERENCE_BACKEND}: {ref})")


def record(run_dir: Path, result: AuditResult) -> dict | None:
    """Keep ``result`` in ``RUN_DIR/audits.json`` (the report reads it; an audit is never repeated) and return
    the entry kept; None for a run made with the reference solver (nothing to keep)."""
    if result.reference is None:
        return None
    path = Path(run_dir) / store.AUDITS
    audits = store.read_json(path) if path.is_file() else {}
    entry = audits[str(result.episode_id)] = {
        "verdict": result.verdict.value, "backend": REFERENCE_BACKEND,
        "outcome": result.stored["outcome"], "safe": bool(result.stored["safe"]),
        "reference_outcome": result.reference["outcome"], "reference_safe": bool(result.reference["safe"]),
        "reference_robustness": json_ready(float(robustness(result.reference, result.requirement))),
        **({} if result.requirement == "safe" else {
            "requirement": result.requirement,
            "reference_violated": violated(result.reference, result.requirement)}),
    }
    files.write_json_atomic(path, dict(sorted(audits.items(), key=lambda kv: int(kv[0]))))
    return entry


def recorded(run_dir: Path) -> dict[str, dict]:
    """The audits kept in ``RUN_DIR/audits.json`` (episode id as text -> audit); {} when none."""
    path = Path(run_dir) / store.AUDITS
    return store.read_json(path) if path.is_file() else {}


def audit_unsafe(run_dir: Path, progress=lambda msg: None) -> list[AuditResult]:
    """Audit every unsafe episode of ``run_dir`` not audited yet, keeping each in ``audits.json``."""
    table = store.read_episodes(Path(run_dir))
    done = recorded(run_dir)
    ids = [e for e, safe in zip(table.column("episode_id").to_pylist(), table.column("safe").to_pylist(), strict=True)
           if safe is False and str(e) not in done]
    results = []
    for k, episode_id in enumerate(ids):
        progress(f"auditing episode {episode_id} with the reference solver ({k + 1} of {len(ids)})")
        res = audit(run_dir, episode_id)
        record(run_dir, res)
        progress(res.describe())
        results.append(res)
    return results


def reference_cell(cell: Cell) -> Cell:
    """``cell`` with the reference solver: every other parameter, the level and the keys as they were."""
    mpc = dataclasses.replace(cell.params.mpc, backend=REFERENCE_BACKEND)
    return dataclasses.replace(cell, params=dataclasses.replace(cell.params, mpc=mpc))


def violated(row: dict, requirement: str) -> bool:
    """Whether ``row`` violates the named ``requirement`` (robustness < 0)."""
    return bool(robustness(row, requirement) < 0)


def audit(run_dir: Path, episode_id: int, out_dir: Path | None = None, requirement: str = "safe") -> AuditResult:
    """Re-simulate ``episode_id`` of ``run_dir`` with the reference solver and compare the verdicts (whether
    ``requirement``, a named one, is violated: ``safe`` for a run's counterexamples, a search's own for its
    own); its trajectory and plot go to ``out_dir`` (default ``RUN_DIR/replay``) as ``episode-NNNNNN-ipopt``."""
    run_dir = Path(run_dir)
    manifest = store.read_json(run_dir / store.MANIFEST)
    campaign = campaign_from_manifest(manifest)
    table = store.read_episodes(run_dir)
    ids = table.column("episode_id").to_pylist()
    if episode_id not in ids:
        raise RunError(f"{run_dir}: no episode {episode_id}; episode ids run from {min(ids)} to {max(ids)}")
    stored = table.slice(ids.index(episode_id), 1).to_pylist()[0]
    cell = campaign.cells[stored["cell_index"]]
    if cell.params.mpc.backend == REFERENCE_BACKEND:
        return AuditResult(episode_id, AuditVerdict.REFERENCE_RUN, stored, None, None, None)
    ref_cell = reference_cell(cell)
    local = stored["cell_episode"]
    result = run_episodes(ref_cell, [local], campaign.seed, executors.solver_for(ref_cell.params),
                          common_random_numbers=campaign.common_random_numbers, record=True,
                          schedules=stored_schedules(run_dir, manifest, episode_id))  # the same error
    row = result.rows[0]
    out = Path(out_dir) if out_dir else run_dir / "replay"
    traj, plot = write_recording(result.recordings[local], ref_cell, row, out,
                                 f"episode-{episode_id:06d}-{REFERENCE_BACKEND}")
    same = violated(row, requirement) == violated(stored, requirement)
    verdict = AuditVerdict.CONFIRMED if same else AuditVerdict.SOLVER_DEPENDENT
    return AuditResult(episode_id, verdict, stored, row, traj, plot, requirement)
