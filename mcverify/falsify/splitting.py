"""``--method splitting``: a falsifier that acts on the per-step perception noise.

Where a violation is driven by the per-step noise (VL-CBF at epsilon = 0 under twice the paper's
noise: the search over the scenario cannot steer it, README "What the falsifier found"), the
scenario-space methods see a noisy robustness and do no better than random search. This method
searches the noise itself, as adaptive multilevel splitting does for estimation
(:mod:`mcverify.estimate.splitting`, [CG07]), but greedily, for a counterexample rather than an
unbiased estimate ("go with the winners"):

1. generation 0: ``population`` fresh candidates, points drawn uniformly in the unit cube (so the
   searched scenario values and structured disturbances follow their nominal distribution, as
   ``random`` does), each with its own noise root (``noise.key_seed``);
2. the particles are the survivors and the candidates just evaluated; the level L is the robustness
   of the ``population // 2 + 1``-th best particle; the particles strictly below L survive, the
   others are dropped (all of them when no particle is below L: a fresh generation 0 follows);
3. each dropped slot is refilled by a *child* of a survivor drawn uniformly; the slots alternate
   between two moves:

   - a *noise branch*: the same point and noise root, and fresh per-step noise (a new branch id)
     after the first control step at which the survivor's running robustness went below L
     (``noise.branch_after_steps`` / ``noise.branch_ids``); its prefix is the survivor's exactly,
     so it starts its fresh noise already at level L;
   - a *scenario step*: the survivor's noise exactly (root and branches) at a point a Gaussian step
     of :data:`SCENARIO_STEP` away on the unit cube (common random numbers: the change in robustness
     is the scenario's, not the noise's);
4. repeat: the level falls generation by generation towards the violation.

Where the searched scenario misleads (the overtakes' robustness points away from the turn-backs
that violate: results/BENCHMARKS.md, "The rare target, three methods") the method does no better
than random search; it is made for failures the per-step noise drives.

A child is an ordinary episode re-simulated from step 0 (its cell's overrides carry its noise
lineage), so it costs a whole episode in the search's budget, lands in its generation's run folder
like any other candidate, and replays bit for bit with ``mcverify replay`` (the scheduled branches
equal snapshot branches: tests/episode/test_snapshot.py). The running robustness comes from each
candidate's stored trajectory (:func:`mcverify.analysis.robustness.running_robustness`), so only the
requirements of :data:`~mcverify.requirements.STEPWISE` can be searched this way; with
``[falsify] guide = "<r>@run"`` the levels and branch steps are those of the guide's running value
(r brought forward by the current run of steps with neither problem solved), while counterexamples
are still judged by the requirement.

[CG07] F. Cérou, A. Guyader, Adaptive multilevel splitting for rare event analysis, Stoch. Anal.
Appl. 25 (2007).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: fold-in stream of the splitting searcher's generator (apart from the other methods').
_STREAM = 0x53504C54
#: Standard deviation of a scenario step on the unit cube.
SCENARIO_STEP = 0.1


@dataclass(frozen=True)
class Candidate:
    """One candidate of a search: its unit-cube point and, for splitting, its noise lineage.

    ``key_seed`` -1 leaves the noise to the generation's seed (the other methods without
    ``common_noise``); ``parent`` is the 1-based evaluation number of the particle it came from (0:
    none), ``move`` how: a fresh draw, a noise branch or a scenario step."""

    point: tuple[float, ...]
    key_seed: int = -1
    branch_after_steps: tuple[int, ...] = ()
    branch_ids: tuple[int, ...] = ()
    parent: int = 0
    move: str = "fresh"  # splitting: "fresh", "noise" (a noise branch) or "scenario" (a scenario step)

    def noise_overrides(self) -> dict[str, Any]:
        """The cell overrides that give the candidate its noise (none without a lineage)."""
        if self.key_seed < 0:
            return {}
        return {"noise.key_seed": self.key_seed, "noise.branch_after_steps": list(self.branch_after_steps),
                "noise.branch_ids": list(self.branch_ids)}

    @property
    def branch_after_step(self) -> int:
        """The control step after which its own fresh noise starts (-1: a fresh episode)."""
        return self.branch_after_steps[-1] if self.branch_after_steps else -1


@dataclass
class _Particle:
    candidate: Candidate
    evaluation: int  # 1-based evaluation number
    running: np.ndarray  # (steps,) running robustness at the end of each control step

    @property
    def score(self) -> float:
        return float(self.running[-1]) if self.running.size else math.inf


def first_step_below(running: np.ndarray, level: float) -> int:
    """The first control step by whose end the running robustness is below ``level``."""
    below = np.flatnonzero(np.asarray(running) < level)
    if not below.size:
        raise ValueError(f"the running robustness never went below {level}")
    return int(below[0])


@dataclass
class NoiseSplitting:
    """The splitting searcher (module docstring): ``ask()`` the next candidates, ``tell()`` their
    running robustness. Deterministic for a seed and the told values."""

    dimension: int
    population: int
    seed: int
    noise_key: int | None = None  # the campaign seed: searches of two campaigns draw distinct noise roots
    particles: list[_Particle] = field(default_factory=list)
    levels: list[float] = field(default_factory=list)
    _told: int = 0
    _next_branch: int = 0
    _pending: list[Candidate] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.dimension < 1 or self.population < 2:
            raise ValueError(f"dimension >= 1 and population >= 2 required, got {self.dimension}, {self.population}")
        # the noise roots (noise.key_seed) replace the campaign seed in the episodes' keys, so the
        # stream that draws them is keyed by the campaign seed as well as the search seed
        key = () if self.noise_key is None else (self.noise_key,)
        self._rng = np.random.default_rng([self.seed, _STREAM, *key])

    def ask(self) -> list[Candidate]:
        if not self._pending:
            self._pending = [self._fresh() for _ in range(self.population)]
        return list(self._pending)

    def tell(self, candidates: list[Candidate], running: list[np.ndarray]) -> None:
        """The evaluated ``candidates`` (as asked, in order) and each one's running robustness."""
        if list(candidates) != self._pending:
            raise ValueError("tell() needs the candidates ask() gave, in order")
        for cand, run in zip(candidates, running, strict=True):
            self._told += 1
            self.particles.append(_Particle(cand, self._told, np.asarray(run, dtype=np.float64)))
        self._pending = self._next_generation()

    def _fresh(self) -> Candidate:
        point = tuple(float(x) for x in self._rng.random(self.dimension))
        return Candidate(point, int(self._rng.integers(0, 2**31)))

    def _next_generation(self) -> list[Candidate]:
        scores = np.array([p.score for p in self.particles])
        keep = self.population // 2
        level = float(np.sort(scores)[keep]) if scores.size > keep else math.inf
        survivors = [p for p in self.particles if p.score < level and math.isfinite(p.score)]
        if not survivors:  # nothing below the level (e.g. all tied): start afresh
            self.particles = []
            return []
        self.levels.append(level)
        self.particles = survivors
        children = []
        for slot in range(self.population - len(survivors)):
            parent = survivors[int(self._rng.integers(len(survivors)))]
            children.append(self._noise_branch(parent, level) if slot % 2 == 0 else self._scenario_step(parent))
        return children

    def _scenario_step(self, parent: _Particle) -> Candidate:
        """A scenario step: the parent's noise (root and branches) at a point a Gaussian step away."""
        c = parent.candidate
        point = np.clip(np.asarray(c.point) + SCENARIO_STEP * self._rng.standard_normal(self.dimension), 0.0, 1.0)
        return Candidate(tuple(float(x) for x in point), c.key_seed, c.branch_after_steps, c.branch_ids,
                         parent.evaluation, "scenario")

    def _noise_branch(self, parent: _Particle, level: float) -> Candidate:
        step = first_step_below(parent.running, level)
        c = parent.candidate
        kept = [(s, b) for s, b in zip(c.branch_after_steps, c.branch_ids, strict=True) if s < step]
        self._next_branch += 1
        branch_id = (self.seed * 1_000_003 + self._next_branch) % 2**31
        steps, ids = tuple(s for s, _ in kept) + (step,), tuple(b for _, b in kept) + (branch_id,)
        return Candidate(c.point, c.key_seed, steps, ids, parent.evaluation, "noise")
