"""The importance-sampling figure: one panel per parameter with the nominal and proposal densities,
the final draws and a tick per failing draw; the mixture density integrates to one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mcverify.reporting.importance_figures import draw_importance_cell, mixture_density


@pytest.mark.parametrize("a, b, alpha", [(1.0, 1.0, 0.1), (8.0, 2.0, 0.1), (3.0, 30.0, 0.3)])
def test_the_mixture_is_a_density_on_the_box(a, b, alpha):
    x = np.linspace(2.0, 10.0, 200_001)
    assert np.trapezoid(mixture_density(x, 2.0, 10.0, a, b, alpha), x) == pytest.approx(1.0, rel=1e-3)


def test_one_panel_per_parameter_and_a_tick_per_failing_draw(tmp_path: Path):
    rng = np.random.default_rng(0)
    theta = np.column_stack([rng.uniform(0, 8, 50), rng.uniform(100, 200, 50)])
    failed = (theta[:, 0] > 2.0) & (theta[:, 0] < 2.6)
    counts = draw_importance_cell(tmp_path / "f.png", "cell", ["delay_s", "gap_m"], [(0.0, 8.0), (100.0, 200.0)],
                                  [3.0, 1.0], [9.0, 1.0], 0.1, theta, failed)
    assert counts["axes"] == 2 and (tmp_path / "f.png").stat().st_size > 0
    # per panel: nominal and proposal curves, and the failing draws' ticks where there are any
    assert counts["lines"] == 2 * 2 + 2 * int(failed.any())


def test_a_narrow_nominal_and_proposal_are_shown_where_their_mass_is(tmp_path: Path):
    """A normal nominal at 1.5 s and a proposal on a window near 2 s in an 8 s box: the panel shows about
    1-2.3 s, not a spike at one side of [0, 8]."""
    import matplotlib.pyplot as plt
    from scipy import stats as sps

    rng = np.random.default_rng(1)
    theta = np.concatenate([rng.normal(1.5, 0.125, 12), rng.normal(2.0, 0.06, 108)])[:, None]
    seen = {}
    real_savefig = plt.Figure.savefig

    def keep(fig, *args, **kw):
        seen["xlim"] = fig.axes[0].get_xlim()
        return real_savefig(fig, *args, **kw)

    plt.Figure.savefig = keep
    try:
        draw_importance_cell(tmp_path / "f.png", "cell", ["delay_s"], [(0.0, 8.0)], [250.0], [750.0], 0.1, theta,
                             theta[:, 0] > 1.96, nominal_logpdf=lambda j, x: sps.norm.logpdf(x, 1.5, 0.125))
    finally:
        plt.Figure.savefig = real_savefig
    lo, hi = seen["xlim"]
    assert 0.8 < lo < 1.2 and 2.1 < hi < 2.6
