"""veh_o that arrives mid-overtake (opposing.spawn = "lane_entry"): drawn per episode, placed the
moment the ego's footprint crosses the lane line, recorded in the row; nothing changes without it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mcverify.campaign.spec import CampaignError, campaign_from_dict
from mcverify.control.planner import Planner
from mcverify.episode.draws import episode_key, sample_scenario
from mcverify.episode.rollout import run_episodes
from mcverify.model import ModelParams
from mcverify.sim.plant import footprint_top_y_m
from mcverify.solver.mpc import MpcSolution
from mcverify.solver.status import SolveOutcome, SolveStatus

SEED = 5
SLIP_LEFT_RAD = 0.15


class SteerLeftSolver:
    """Every problem "solves" to the same plan: no acceleration, full slip to the left, so the ego
    drifts into the opposing lane without any optimisation (a cheap, deterministic driver)."""

    kernel_hash = "steer-left"

    def __init__(self, params: ModelParams, structure=None) -> None:
        n = params.mpc.horizon
        self.structure = structure
        u = np.tile([0.0, SLIP_LEFT_RAD], (n, 1))
        self._sol = MpcSolution(success=True, status=SolveStatus("stub", SolveOutcome.SOLVED), iterations=0,
                                solve_time_s=0.0, total_time_s=10.0, x_plan=np.zeros((n + 1, 4)), u_plan=u,
                                dt_plan=np.full(n, 10.0 / n), warm=None,
                                opp_plan=np.tile([1e6, 0.0], (n + 1, 1)))  # Table I: veh_o far ahead

    def solve(self, *args, **kwargs) -> MpcSolution:
        return self._sol

    def guess_from_plan(self, plan, opp_xv):
        return None


def _cell(**opposing):
    raw = {
        "campaign": {"name": "spawn", "seed": SEED, "episodes": 3},
        "model": {"sim": {"control_period_s": 0.1, "substeps": 10, "max_time_s": 2.0},
                  "opposing": {"kind": "human", "x_m": 300.0, **opposing}},
    }
    return campaign_from_dict(raw).cells[0]


def test_footprint_top_edge() -> None:
    p = ModelParams()
    ego = np.array([[0.0, 0.0, 0.0, 10.0], [0.0, 1.0, 0.2, 10.0]])
    top = footprint_top_y_m(ego, p)
    assert top[0] == pytest.approx(p.geometry.width_m / 2)
    g = p.geometry
    assert top[1] == pytest.approx(1.0 + g.length_m / 2 * math.sin(0.2) + g.width_m / 2 * math.cos(0.2))


def test_draws_are_keyed_in_their_ranges_and_nan_where_they_do_not_apply() -> None:
    cell = _cell(spawn="lane_entry", spawn_gap_range_m=[100.0, 160.0], speed_range_mps=[8.0, 18.0],
                 spawn_delay_range_s=[1.0, 4.0])
    draws = [sample_scenario(episode_key(SEED, 0, e), cell.params) for e in range(200)]
    gaps, speeds, delays = (np.array([d[k] for d in draws]) for k in ("opp_spawn_gap_m", "opp_speed_mps",
                                                                       "opp_spawn_delay_s"))
    assert np.all((gaps > 100.0) & (gaps <= 160.0)) and np.all((speeds > 8.0) & (speeds <= 18.0))
    assert np.all((delays > 1.0) & (delays <= 4.0))
    assert np.all(np.abs(np.corrcoef([gaps, speeds, delays])[np.triu_indices(3, 1)]) < 0.2)  # separate streams
    assert draws[3] == sample_scenario(episode_key(SEED, 0, 3), cell.params)
    fixed = sample_scenario(episode_key(SEED, 0, 0), _cell().params)
    assert fixed["opp_speed_mps"] == 15.0 and math.isnan(fixed["opp_spawn_gap_m"])
    assert math.isnan(fixed["opp_spawn_delay_s"])  # spawn = "start": no delay applies
    at_entry = sample_scenario(episode_key(SEED, 0, 0), _cell(spawn="lane_entry", spawn_delay_s=2.5).params)
    assert at_entry["opp_spawn_delay_s"] == 2.5
    none = sample_scenario(episode_key(SEED, 0, 0), _cell(kind="none").params)
    assert math.isnan(none["opp_speed_mps"]) and math.isnan(none["opp_spawn_gap_m"])


def test_veh_o_appears_at_the_gap_when_the_ego_crosses_the_lane_line() -> None:
    cell = _cell(spawn="lane_entry", spawn_gap_m=120.0, speed_mps=12.0)
    planner = Planner(cell.params, solver_factory=lambda p, st: SteerLeftSolver(p, st))
    res = run_episodes(cell, [0, 1], SEED, planner, record=True)
    for row in res.rows:
        traj = res.recordings[row["cell_episode"]].trajectory
        t, ego_x, opp_x = traj["t_s"], traj["ego_x_m"], traj["opp_x_m"]
        spawn_s = row["opp_spawn_s"]
        assert 0.0 < spawn_s < 2.0 and row["sample_opp_spawn_gap_m"] == 120.0
        # the sample at t = spawn_s is the end of the period before (the spawn happens at the boundary)
        before, at = t <= spawn_s + 1e-9, np.argmax(t > spawn_s + 1e-9)
        assert np.all(opp_x[before] > 1e5)  # parked out of reach until then
        assert opp_x[at] == pytest.approx(ego_x[at] + 120.0, abs=12.0 * 0.1 + 1e-6)
        top = footprint_top_y_m(np.column_stack([ego_x, traj["ego_y_m"], traj["ego_psi_rad"], traj["ego_speed_mps"]]),
                                cell.params)
        steps_before = (t < spawn_s - 1e-9) & np.isclose(np.round(t / 0.1) * 0.1, t)  # control-step instants
        assert np.all(top[steps_before] <= cell.params.road.lane_width_m / 2 + 1e-9)
        assert row["min_gap_opp_m"] < 120.0  # never measured against the parked vehicle
        assert math.isfinite(row["min_gap_opp_any_m"]) and row["min_gap_opp_any_m"] < 120.0


def test_a_spawn_delay_moves_the_spawn_later_by_that_much() -> None:
    def spawn_s(delay: float) -> float:
        cell = _cell(spawn="lane_entry", spawn_gap_m=120.0, spawn_delay_s=delay)
        planner = Planner(cell.params, solver_factory=lambda p, st: SteerLeftSolver(p, st))
        return run_episodes(cell, [0], SEED, planner).rows[0]["opp_spawn_s"]

    assert spawn_s(0.5) == pytest.approx(spawn_s(0.0) + 0.5)


def test_a_drawn_spawn_delay_is_the_one_the_episode_waits_and_records() -> None:
    cell = _cell(spawn="lane_entry", spawn_gap_m=120.0, spawn_delay_range_s=[0.0, 1.0])
    planner = Planner(cell.params, solver_factory=lambda p, st: SteerLeftSolver(p, st))
    rows = run_episodes(cell, [0, 1, 2], SEED, planner).rows
    undelayed = run_episodes(_cell(spawn="lane_entry", spawn_gap_m=120.0), [0], SEED, planner).rows[0]["opp_spawn_s"]
    for row in rows:
        delay = row["sample_opp_spawn_delay_s"]
        assert 0.0 < delay <= 1.0
        # veh_o appears at the first control step at or after lane entry + delay (0.1 s steps)
        assert undelayed + delay - 1e-9 <= row["opp_spawn_s"] < undelayed + delay + 0.1


def test_spawn_at_start_is_recorded_as_zero() -> None:
    cell = _cell(speed_mps=12.0)
    planner = Planner(cell.params, solver_factory=lambda p, st: SteerLeftSolver(p, st))
    row = run_episodes(cell, [0], SEED, planner).rows[0]
    assert row["opp_spawn_s"] == 0.0 and row["sample_opp_speed_mps"] == 12.0


@pytest.mark.parametrize("opposing, field", [
    ({"spawn": "later"}, "opposing.spawn"),
    ({"spawn": "lane_entry", "spawn_gap_m": 3.0}, "opposing.spawn_gap_m"),
    ({"spawn": "lane_entry", "spawn_delay_s": -1.0}, "opposing.spawn_delay_s"),
    ({"spawn": "lane_entry", "spawn_gap_range_m": [200.0, 100.0]}, "opposing.spawn_gap_range_m"),
    ({"spawn": "lane_entry", "spawn_delay_range_s": [-1.0, 2.0]}, "opposing.spawn_delay_range_s"),
    ({"speed_range_mps": [10.0, 25.0]}, "opposing.speed_range_mps"),
    ({"spawn": "lane_entry", "spawn_delay_sd_s": -0.1}, "opposing.spawn_delay_sd_s"),
    ({"spawn": "lane_entry", "spawn_delay_sd_s": 0.1}, "opposing.spawn_delay_sd_s: a normal spawn delay needs"),
    ({"spawn": "lane_entry", "spawn_delay_s": 1.0, "spawn_delay_sd_s": 0.1, "spawn_delay_range_s": [3.0, 8.0]},
     r"opposing.spawn_delay_sd_s: the range \[3.0, 8.0\] s holds 0 of the normal\(1, 0.1\) spawn delay"),
])
def test_bad_spawn_settings_are_one_line(opposing, field) -> None:
    with pytest.raises(CampaignError, match=field.replace(".", r"\.")) as err:
        _cell(**opposing)
    assert "\n" not in str(err.value)
