"""Choose Table III's burst ranges from the exploration run (issue 51.5).

Usage: python studies/table3-burst/fit.py [--onset-from S] [--check RUN_DIR] RUN_DIR [RUN_DIR ...]
(--onset-from: fit only the episodes whose burst started at S seconds or later; --check: also print, per
cell of that run, the overtakes the fit expects given the run's own draws, beside those observed)

Fits P(overtook) = logistic(b0 + b1 * log(alpha_f * duration) + b2 * onset) by maximum likelihood
on the runs' episodes (alpha_f * duration is the speed veh_f gains in the burst, the quantity that
decides whether the ego can still pass it), then scores candidate (onset, duration) ranges by the
expected overtakes per Table III range, integrating the fit over the uniform draws, against the
paper's 29/11/0. Prints the fit, the observed overtake rate in bins of the gained speed, and the
best candidates.
"""

from __future__ import annotations

import argparse
import itertools
import math
from pathlib import Path

import numpy as np

from mcverify.api import Run

PAPER_OVERTAKES = (29, 11, 0)
ALPHA_RANGES = ((1.0, 3.0), (3.0, 5.0), (5.0, 7.0))
EPISODES_PER_RANGE = 30


def _features(gain_mps: np.ndarray, onset_s: np.ndarray) -> np.ndarray:
    return np.column_stack([np.ones_like(gain_mps), np.log(gain_mps), onset_s])


def fit_logistic(x: np.ndarray, y: np.ndarray, ridge: float = 1e-3) -> np.ndarray:
    """Newton's method on the (slightly ridged, so separable data stay finite) log-likelihood."""
    beta = np.zeros(x.shape[1])
    for _ in range(100):
        p = 1.0 / (1.0 + np.exp(-x @ beta))
        grad = x.T @ (y - p) - ridge * beta
        hess = (x * (p * (1 - p))[:, None]).T @ x + ridge * np.eye(x.shape[1])
        step = np.linalg.solve(hess, grad)
        beta += step
        if np.max(np.abs(step)) < 1e-10:
            break
    return beta


def expected_overtakes(beta, onset_range_s, duration_range_s, rng, draws=20000) -> list[float]:
    counts = []
    for lo, hi in ALPHA_RANGES:
        alpha = rng.uniform(lo, hi, draws)
        onset = rng.uniform(*onset_range_s, draws)
        duration = rng.uniform(*duration_range_s, draws)
        p = 1.0 / (1.0 + np.exp(-_features(alpha * duration, onset) @ beta))
        counts.append(EPISODES_PER_RANGE * float(p.mean()))
    return counts


def _score(counts) -> float:
    # Poisson-like deviance against the paper's counts (0 handled by the expected count itself).
    return sum((c - k) ** 2 / max(k, 1.0) for c, k in zip(counts, PAPER_OVERTAKES, strict=True))


def _check(beta: np.ndarray, run_dir: str) -> None:
    frame = Run(Path(run_dir)).episodes(as_pandas=True)
    print(f"{run_dir}: overtakes observed, and expected by the fit given each episode's draws (+- binomial sd)")
    for cell, g in frame.groupby("cell", sort=False):
        gain = g["sample_front_accel_mps2"].to_numpy() * g["sample_front_accel_duration_s"].to_numpy()
        p = 1.0 / (1.0 + np.exp(-_features(gain, g["sample_front_accel_onset_s"].to_numpy()) @ beta))
        alpha = g["sample_front_accel_mps2"].mean()
        print(f"  {cell}: {int(g['overtook'].sum())}/{len(g)} observed, {p.sum():.1f} +- "
              f"{np.sqrt((p * (1 - p)).sum()):.1f} expected; mean alpha_f drawn {alpha:.2f}")


def main(run_dirs: list[str], onset_from_s: float = -math.inf, check_dir: str | None = None) -> None:
    frames = [Run(Path(d)).episodes(as_pandas=True) for d in run_dirs]
    frames = [f[f["sample_front_accel_onset_s"] >= onset_from_s] for f in frames]
    alpha = np.concatenate([f["sample_front_accel_mps2"].to_numpy() for f in frames])
    onset = np.concatenate([f["sample_front_accel_onset_s"].to_numpy() for f in frames])
    duration = np.concatenate([f["sample_front_accel_duration_s"].to_numpy() for f in frames])
    overtook = np.concatenate([f["overtook"].to_numpy() for f in frames]).astype(float)
    gain = alpha * duration
    beta = fit_logistic(_features(gain, onset), overtook)
    print(f"{len(gain)} episodes, {int(overtook.sum())} overtook")
    print(f"fit: logit P(overtook) = {beta[0]:.2f} {beta[1]:+.2f} log(gain_mps) {beta[2]:+.2f} onset_s")
    for lo, hi in itertools.pairwise([0, 3, 5, 6, 7, 8, 9, 11, 30]):
        sel = (gain > lo) & (gain <= hi)
        if sel.any():
            print(f"  gain ({lo:>2}, {hi:>2}] m/s: {int(overtook[sel].sum())}/{int(sel.sum())} overtook")
    rng = np.random.default_rng(0)
    candidates = []
    for onset_range in ((3.5, 3.5), (3.0, 4.0), (3.5, 4.5), (2.5, 4.5)):
        for d_lo in np.arange(1.0, 2.51, 0.25):
            for d_hi in np.arange(d_lo + 0.25, 3.51, 0.25):
                counts = expected_overtakes(beta, onset_range, (d_lo, d_hi), rng)
                candidates.append((_score(counts), onset_range, (d_lo, d_hi), counts))
    if check_dir is not None:
        _check(beta, check_dir)
    candidates.sort(key=lambda c: c[0])
    print("best (onset range s, duration range s): expected overtakes per range (paper 29/11/0)")
    for score, onset_range, duration_range, counts in candidates[:10]:
        print(f"  onset {onset_range}, duration ({duration_range[0]:.2f}, {duration_range[1]:.2f}): "
              + "/".join(f"{c:.1f}" for c in counts) + f"  (score {score:.2f})")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--onset-from", type=float, default=-math.inf)
    parser.add_argument("--check")
    parser.add_argument("runs", nargs="+")
    args = parser.parse_args()
    main(args.runs, args.onset_from, args.check)
