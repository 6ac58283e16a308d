"""Audit an estimate's counterexample with the reference solver: ``mcverify replay ESTIMATE_DIR K
--backend ipopt``.

K is what ``mcverify replay ESTIMATE_DIR K`` re-simulates (an importance sampling final draw, a splitting
failing particle, a subset simulation failing sample). The counterexample is first replayed exactly (its
kept values checked bit for bit, as a replay does), then re-simulated on the same inputs with IPOPT
solving every problem at every step (:func:`mcverify.campaign.audit.reference_cell`). The verdict is on
the estimate's target event: "confirmed by the reference solver" when both solvers give the same event,
"solver-dependent" otherwise. Nothing is kept in the folder: an estimate's report lists its cells, not
its episodes one by one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcverify import store
from mcverify.campaign.audit import REFERENCE_BACKEND, AuditVerdict
from mcverify.campaign.replay import ReplayResult
from mcverify.estimate.replay import estimate_method, replay_draw, replay_particle, replay_sample
from mcverify.requirements import SCORES, TARGETS

#: What K names in each estimate folder kind, and the replay that re-simulates it.
_KINDS = {"importance": ("final draw", replay_draw), "splitting": ("failing particle", replay_particle),
          "subset": ("failing sample", replay_sample)}


@dataclass(frozen=True)
class EstimateAudit:
    """Both re-simulations of one counterexample of an estimate folder, and the verdict on its target."""

    kind: str
    index: int
    target: str
    stored: ReplayResult  # the estimate's own solver path, replayed exactly
    reference: ReplayResult  # the reference solver on the same inputs
    verdict: AuditVerdict

    def describe(self) -> str:
        def said(res: ReplayResult) -> str:
            event = "event" if target_event(res.row, self.target) else "no event"
            return f"{res.row['outcome']}, safe={res.row['safe']}, {self.target}: {event}"

        return (f"{self.kind} {self.index}: {self.verdict.value} (the estimate's solver path: {said(self.stored)}; "
                f"the reference solver {REFERENCE_BACKEND}: {said(self.reference)})")


def target_event(row: dict[str, Any], target: str) -> bool:
    """Whether ``row`` shows the target event (:data:`mcverify.requirements.TARGETS`: the OR of its flags,
    or the negation of its one flag)."""
    t = TARGETS[target]
    if t.negated:
        return row.get(t.flags[0]) is False
    return any(bool(row.get(flag)) for flag in t.flags)


def estimate_target(est_dir: Path) -> str:
    """The target event of an estimate folder (a splitting folder names its score, whose target it is)."""
    spec = store.read_manifest(Path(est_dir))["estimate"]
    return spec["target"] if "target" in spec else SCORES[spec["score"]]


def audit(est_dir: Path, k: int, out_dir: Path | None = None, cell_name: str | None = None) -> EstimateAudit:
    """Replay counterexample ``k`` of ``est_dir`` exactly, then with the reference solver, and compare their
    target events; both trajectories and plots go to ``out_dir`` (default ESTIMATE_DIR/replay)."""
    kind, replay = _KINDS[estimate_method(est_dir)]
    target = estimate_target(est_dir)
    stored = replay(est_dir, k, out_dir, cell_name)
    reference = replay(est_dir, k, out_dir, cell_name, reference=True)
    same = target_event(stored.row, target) == target_event(reference.row, target)
    return EstimateAudit(kind, k, target, stored, reference,
                         AuditVerdict.CONFIRMED if same else AuditVerdict.SOLVER_DEPENDENT)
