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
