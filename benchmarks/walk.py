"""A calibration process for the rare-event estimators (their tests and ``python -m benchmarks.rare``): a cheap
episode driven by per-step noise, a Gaussian random
walk x_{t+1} = x_t + drift + sigma * e_t over ``horizon`` control steps, whose score is the running
maximum of x and whose "collision" is max x >= barrier. The noise of branch b at step t is the t-th
draw of a generator seeded by (seed, b): a pure function of (branch id, step), as in the real loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WalkPath:
    """One walk (or branch): states and running maxima from step 0, and the steps this run simulated."""

    x: np.ndarray  # state after each step, from step 0
    scores: np.ndarray  # running max of x after each step
    steps: int  # steps this simulation ran

    def snapshot(self, step: int) -> tuple[int, np.ndarray, np.ndarray]:
        return step, self.x[: step + 1], self.scores[: step + 1]


@dataclass(frozen=True)
class Walk:
    """x_{t+1} = x_t + drift + sigma e_t over ``horizon`` steps (a splitting BranchingProcess)."""

    drift: float = -0.05
    sigma: float = 0.3
    horizon: int = 60
    seed: int = 0

    def noise(self, branch_id: int) -> np.ndarray:
        return np.random.default_rng([self.seed, branch_id]).standard_normal(self.horizon)

    def run(self, start, branch_id: int, stop_level: float) -> WalkPath:
        e = self.noise(branch_id)
        if start is None:
            step, x0, prefix_x, prefix_s = -1, 0.0, np.zeros(0), np.zeros(0)
            best = -np.inf
        else:
            step, prefix_x, prefix_s = start
            x0, best = float(prefix_x[-1]), float(prefix_s[-1])
        inc = self.drift + self.sigma * e[step + 1:]
        x = np.cumsum(np.concatenate([[x0], inc]))[1:]  # the same additions, in order, as one whole run
        s = np.maximum(best, np.maximum.accumulate(x)) if x.size else x
        hit = np.flatnonzero(s >= stop_level)
        end = int(hit[0]) + 1 if hit.size else x.size  # the failure set is absorbing: stop there
        return WalkPath(np.concatenate([prefix_x, x[:end]]), np.concatenate([prefix_s, s[:end]]), end)

    def crude(self, episodes: int, barrier: float, seed: int, batch: int = 200_000) -> tuple[int, int]:
        """(hits, episodes) of crude Monte Carlo with its own generator (a reference, not branch-keyed)."""
        rng = np.random.default_rng([self.seed, seed, 99])
        hits = 0
        for start in range(0, episodes, batch):
            m = min(batch, episodes - start)
            x = np.cumsum(self.drift + self.sigma * rng.standard_normal((m, self.horizon)), axis=1)
            hits += int(np.sum(x.max(axis=1) >= barrier))
        return hits, episodes
