"""Where an importance-sampling estimate looked: per scenario parameter, the nominal density, the
fitted proposal (the defensive mixture the final draws came from) and the final draws, the failing
ones marked, so that a reader sees at a glance which values the event needs and whether the
proposal covers them (``mcverify estimate --method importance``; one figure per cell).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from scipy import stats as sps

from mcverify.reporting.figure_common import save, subplots

#: Points on each density curve.
CURVE_POINTS = 400


def mixture_density(x: np.ndarray, low: float, high: float, a: float, b: float, alpha: float,
                    nominal: np.ndarray | None = None) -> np.ndarray:
    """Density of the defensive mixture alpha p + (1 - alpha) scaled Beta(a, b) at x (1/unit), where p is
    the nominal density at x (``nominal``; default uniform on (low, high)); the nominal itself where the
    Beta is NaN."""
    width = high - low
    p = np.full_like(np.asarray(x, dtype=float), 1.0 / width) if nominal is None else nominal
    if np.isnan(a) or np.isnan(b):  # no Beta was fitted to a normal nominal: the proposal is the nominal
        return p
    return alpha * p + (1.0 - alpha) * sps.beta.pdf((x - low) / width, a, b) / width


def _shown_range(low: float, high: float, draws: np.ndarray, densities) -> tuple[float, float]:
    """The part of [low, high] worth showing: where the draws fall and either density exceeds a thousandth
    of its peak, padded by a tenth; the whole range unless that part is under half of it (a nominal normal
    in a wide box, or a proposal narrowed onto a window, would otherwise be a spike at one side)."""
    x = np.linspace(low, high, 20 * CURVE_POINTS)
    nominal, proposal = densities(x)
    mass = (nominal > 1e-3 * nominal.max()) | (proposal > 1e-3 * proposal.max())
    lo = min(float(x[mass].min()), float(np.min(draws))) if mass.any() else float(np.min(draws))
    hi = max(float(x[mass].max()), float(np.max(draws))) if mass.any() else float(np.max(draws))
    if hi - lo >= 0.5 * (high - low):
        return low, high
    pad = 0.1 * max(hi - lo, 1e-9 * (high - low))
    return max(low, lo - pad), min(high, hi + pad)


def draw_importance_cell(path: Path, title: str, names: Sequence[str], bounds: Sequence[tuple[float, float]],
                         proposal_a: Sequence[float], proposal_b: Sequence[float], alpha: float,
                         theta: np.ndarray, failed: np.ndarray,
                         nominal_logpdf: Callable[[int, np.ndarray], np.ndarray] | None = None) -> dict[str, int]:
    """One panel per parameter: nominal and proposal densities, a histogram of the final draws
    ``theta`` ((M, d), in the order of ``names``) and a red tick under the axis per failing draw.
    ``nominal_logpdf(j, x)``: parameter j's nominal log density (default: uniform on its bounds); the
    proposal's defensive part is that density too."""
    theta = np.asarray(theta, dtype=float).reshape(-1, len(names))
    failed = np.asarray(failed, dtype=bool)
    width_in = max(6.0, 4.2 * len(names))
    fig, axes = subplots(1, len(names), figsize=(width_in, 3.4), squeeze=False)
    for j, (ax, name, (low, high)) in enumerate(zip(axes[0], names, bounds, strict=True)):

        def densities(x: np.ndarray, j: int = j, low: float = low, high: float = high) -> tuple[np.ndarray, np.ndarray]:
            nominal = (np.exp(nominal_logpdf(j, x)) if nominal_logpdf is not None
                       else np.full_like(x, 1.0 / (high - low)))
            return nominal, mixture_density(x, low, high, proposal_a[j], proposal_b[j], alpha, nominal)

        shown = _shown_range(low, high, theta[:, j], densities)
        x = np.linspace(*shown, CURVE_POINTS)
        nominal, proposal = densities(x)
        ax.hist(theta[:, j], bins=30, range=shown, density=True, color="0.85", label="final draws")
        ax.plot(x, nominal, "--", color="0.4", label="nominal")
        ax.plot(x, proposal, color="tab:blue", label="proposal")
        fails = theta[failed, j]
        if fails.size:
            ax.plot(fails, np.zeros_like(fails), "|", color="tab:red", markersize=12, label="failing draws")
        ax.set_xlim(*shown)
        ax.set_xlabel(name if shown == (low, high) else f"{name} (range {low:g} to {high:g}; shown where the mass is)")
        ax.set_ylabel("density")
        ax.legend(fontsize=7, loc="upper right")
    fig.suptitle(title, fontsize=9)
    fig.subplots_adjust(left=0.65 / width_in, right=0.97, bottom=0.17, top=0.86, wspace=0.3)
    return save(fig, path)
