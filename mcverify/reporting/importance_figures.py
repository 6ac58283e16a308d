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

from mcverify.reporting.figure_common import plt, save

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
    fig, axes = plt.subplots(1, len(names), figsize=(width_in, 3.4), squeeze=False)
    for j, (ax, name, (low, high)) in enumerate(zip(axes[0], names, bounds, strict=True)):
        x = np.linspace(low, high, CURVE_POINTS)
        ax.hist(theta[:, j], bins=30, range=(low, high), density=True, color="0.85", label="final draws")
        nominal = (np.exp(nominal_logpdf(j, x)) if nominal_logpdf is not None
                   else np.full_like(x, 1.0 / (high - low)))
        ax.plot(x, nominal, "--", color="0.4", label="nominal")
        ax.plot(x, mixture_density(x, low, high, proposal_a[j], proposal_b[j], alpha, nominal), color="tab:blue",
                label="proposal")
        fails = theta[failed, j]
        if fails.size:
            ax.plot(fails, np.zeros_like(fails), "|", color="tab:red", markersize=12, label="failing draws")
        ax.set_xlim(low, high)
        ax.set_xlabel(name)
        ax.set_ylabel("density")
        ax.legend(fontsize=7, loc="upper right")
    fig.suptitle(title, fontsize=9)
    fig.subplots_adjust(left=0.65 / width_in, right=0.97, bottom=0.17, top=0.86, wspace=0.3)
    return save(fig, path)
