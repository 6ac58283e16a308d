"""An anytime-valid lower confidence bound for the mean of i.i.d. values in [0, 1] (betting).

For a candidate mean m, the capital K_t(m) = prod_{i <= t} (1 + lambda_i(m) (y_i - m)) with a
predictable bet 0 <= lambda_i(m) <= 1/m (it uses y_1..y_{i-1} only) is a non-negative
supermartingale whenever the true mean is <= m, so by Ville's inequality it ever reaches 1/delta with
probability <= delta [WSR23]. Every m whose capital reached 1/delta is rejected; since K_t is
non-increasing in m, the rejected set is an interval [0, L_t], and L_t is a lower bound that holds
at every t simultaneously (anytime valid), so it may be read after any number of samples, including
a number chosen by looking at the data. The bet is the aGRAPA rule clipped to [0, c/m]:
lambda = (mu_hat - m) / (sigma_hat^2 + (mu_hat - m)^2) from the previous samples.

Used for importance sampling with a defensive mixture, whose weights are bounded by 1/alpha, so
alpha w 1{event} lies in [0, 1].

[WSR23] I. Waudby-Smith, A. Ramdas, Estimating means of bounded random variables by betting,
J. R. Stat. Soc. B 86 (2024).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from mcverify.analysis.intervals import _check_level

#: Largest share of the capital bet at once (c of the module docstring), for numerical safety.
MAX_BET = 0.75


def lower_bound(y: npt.ArrayLike, level: float = 0.95, grid: int = 400) -> float:
    """The anytime-valid lower bound on the mean of ``y`` (values in [0, 1], in sampling order)
    after all of ``y``; candidates m on a log grid of ``grid`` points in [1e-12, 1] (the bound is
    rounded down to the grid, which keeps it valid). 0 when nothing is rejected."""
    level = _check_level(level)
    y = np.asarray(y, dtype=float)
    if y.size and (np.any(y < 0) or np.any(y > 1) or not np.all(np.isfinite(y))):
        raise ValueError("values must lie in [0, 1]")
    if y.size == 0:
        return 0.0
    m = np.concatenate([[0.0], np.logspace(-12, 0, grid)])[:, None]  # (grid + 1, 1) candidates
    # predictable mean and variance of y_1..y_{i-1}; no bet on the first sample
    counts = np.arange(y.size, dtype=float)
    csum = np.concatenate([[0.0], np.cumsum(y)[:-1]])
    csq = np.concatenate([[0.0], np.cumsum(y * y)[:-1]])
    seen = np.maximum(counts, 1.0)
    mu = csum / seen
    var = np.maximum(csq / seen - mu * mu, 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (mu - m) / (var + (mu - m) ** 2)
        lam = np.clip(lam, 0.0, np.where(m > 0, MAX_BET / m, np.inf))
        lam[:, 0] = 0.0
    log_capital = np.cumsum(np.log1p(lam * (y - m)), axis=1)
    rejected = np.max(log_capital, axis=1) >= -math.log1p(-level)  # ever reached 1/delta
    rejected[0] = False  # m = 0 is never rejected
    hits = np.flatnonzero(rejected)
    return float(m[hits[-1], 0]) if hits.size else 0.0
