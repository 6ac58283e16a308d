"""The ego's own limits on the true trajectory: speed at every sub-step, the held input per period."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcverify.model import ModelParams
from mcverify.sim import plant as pl

P = ModelParams()


def _start(speed_mps: float):
    pp = pl.plant_params(P)
    state = jax.tree.map(lambda a: a[0], pl.initial_plant(P, [0.0]))
    state = state._replace(ego=state.ego.at[3].set(speed_mps))
    return state, pl.initial_trace(state, pp), pp


def _period(state, trace, pp, alpha_mps2: float, beta_rad: float):
    u = jnp.array([alpha_mps2, beta_rad])
    state, trace, _ = pl.advance(state, trace, u, jnp.array(True), pp, substeps=10)
    return state, trace


def test_the_speed_is_checked_between_the_nodes():
    """Full throttle from just below the limit: the true speed passes it within the period."""
    vmax = P.ego.speed_max_mps
    state, trace, pp = _start(vmax - 0.01)
    assert float(trace.speed_excess_mps) == pytest.approx(-0.01) and math.isnan(float(trace.speed_excess_t_s))
    state, trace = _period(state, trace, pp, P.ego.accel_max_mps2, 0.0)
    dt = P.sim.control_period_s
    assert float(trace.speed_excess_mps) == pytest.approx(P.ego.accel_max_mps2 * dt - 0.01, abs=1e-9)
    assert float(trace.speed_excess_t_s) == pytest.approx(dt)  # reached at the period's last sub-step
    # braking afterwards keeps the largest excess and its time
    _, later = _period(state, trace, pp, P.ego.accel_min_mps2, 0.0)
    assert float(later.speed_excess_mps) == float(trace.speed_excess_mps)
    assert float(later.speed_excess_t_s) == float(trace.speed_excess_t_s)


def test_inputs_within_their_bounds_leave_no_excess():
    state, trace, pp = _start(10.0)
    _, trace = _period(state, trace, pp, P.ego.accel_max_mps2, -P.ego.slip_max_rad)
    assert float(trace.accel_excess_mps2) == pytest.approx(0.0) and float(trace.slip_excess_rad) == pytest.approx(0.0)
    assert math.isnan(float(trace.accel_excess_t_s)) and math.isnan(float(trace.slip_excess_t_s))
    assert float(trace.speed_excess_mps) < 0


@pytest.mark.parametrize("alpha, beta, accel, slip", [(4.0, 0.2, 1.0, 0.05), (-7.5, -0.1, 1.5, -0.05)])
def test_an_input_beyond_its_bounds_is_counted_with_its_period(alpha, beta, accel, slip):
    state, trace, pp = _start(10.0)
    state, trace = _period(state, trace, pp, 0.0, 0.0)  # one period within the bounds first
    _, trace = _period(state, trace, pp, alpha, beta)
    assert float(trace.accel_excess_mps2) == pytest.approx(accel)
    assert float(trace.slip_excess_rad) == pytest.approx(slip)
    assert float(trace.accel_excess_t_s) == pytest.approx(P.sim.control_period_s)  # the second period's start
    assert math.isnan(float(trace.slip_excess_t_s)) == (slip <= 0)


def test_the_row_and_the_report_carry_the_limits(tmp_path):
    """Through the batched plant and the row: a real (tiny) episode has the six columns, finite."""
    from mcverify import cli, store

    out = tmp_path / "run"
    tiny = __import__("pathlib").Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"
    assert cli.main(["run", str(tiny), "--episodes", "1", "--run-dir", str(out), "--workers", "1", "--no-progress",
                     "-q"]) == 0
    t = store.read_episodes(out)
    for name in ("speed_excess_mps", "accel_excess_mps2", "slip_excess_rad"):
        assert np.isfinite(t.column(name).to_numpy()).all(), name
    assert "Limits of the ego per cell" in (out / "report.md").read_text()
