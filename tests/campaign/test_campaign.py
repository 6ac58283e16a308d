"""Campaign files: validation messages, grid expansion, unit aliases."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from mcverify.campaign.spec import CampaignError, campaign_from_dict, load_campaign

ROOT = Path(__file__).resolve().parents[2]


def spec(**over):
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 3}}
    for key, value in over.items():
        raw[key] = value
    return raw


def test_shipped_campaigns_load():
    for path in sorted((ROOT / "campaigns").glob("*.toml")):
        camp = load_campaign(path)
        assert camp.cells, path


def test_table2_grid_expands_to_four_cells_with_kmh_converted():
    camp = load_campaign(ROOT / "campaigns" / "table2.toml")
    assert [c.name for c in camp.cells] == [f"front_speed_kmh={v}" for v in (25, 28, 32, 36)]
    assert camp.cells[0].params.scenario.front_speed_mps == pytest.approx(25 / 3.6)
    assert camp.total_episodes == 120
    assert [c.episode_offset for c in camp.cells] == [0, 30, 60, 90]
    assert all(c.epsilon == pytest.approx(0.3) for c in camp.cells)
    # lambda0 = -kappa~(eps) with the default lambdas (1.0, 0.5): -(0.3 + 0.5 * 0.3**3)
    assert camp.cells[0].lambda0 == pytest.approx(-(0.3 + 0.5 * 0.3**3))


def test_cartesian_product_of_two_fields():
    camp = campaign_from_dict(spec(grid={"barrier.epsilon": [0.1, 0.3], "noise.scale": [1.0, 2.0, 3.0]}))
    assert len(camp.cells) == 6
    assert len({c.name for c in camp.cells}) == 6


def test_overrides_from_cli_take_precedence():
    camp = campaign_from_dict(spec(), episodes=11, seed=5)
    assert camp.episodes_per_cell == 11 and camp.seed == 5


def test_lambda0_replaces_the_default_epsilon_and_round_trips():
    camp = campaign_from_dict(spec(model={"barrier": {"lambda0": -0.5, "lambdas_m": [1.0]}}))
    cell = camp.cells[0]
    assert cell.params.barrier.epsilon is None
    assert cell.lambda0 == pytest.approx(-0.5)
    assert cell.epsilon == pytest.approx(0.5)  # kappa~(h) = h, so eps = -lambda0


def test_grid_over_lambda0():
    camp = campaign_from_dict(spec(grid={"barrier.lambda0": [-0.1, -0.3]}))
    assert [c.params.barrier.epsilon for c in camp.cells] == [None, None]
    assert camp.cells[1].epsilon > camp.cells[0].epsilon


@pytest.mark.parametrize(
    "raw, fragment",
    [
        (spec(campaign={"name": "t", "seed": 1, "episode": 3}), "did you mean 'episodes'"),
        (spec(campaign={"name": "t", "seed": 1, "episodes": -2}), "episodes: must be >= 1"),
        (spec(campaign={"name": "t", "seed": 1, "episodes": "many"}), "expected int"),
        (spec(model={"barrier": {"epsilon": -0.1}}), "barrier.epsilon: must be >= 0"),
        (spec(model={"barier": {"epsilon": 0.1}}), "did you mean 'barrier'"),
        (spec(model={"barrier": {"epsilonn": 0.1}}), "did you mean 'barrier.epsilon'"),
        (spec(grid={"noise.scale": []}), "non-empty list"),
        (spec(model={"scenario": {"ego_speed_mps": 30.0}}), "outside the ego speed range"),
        (spec(model={"scenario": {"front_x_m": 12.0}}), "infeasible scenario"),
        (spec(model={"noise": {"kind": "gaussian"}}), "unknown noise model"),
        (spec(model={"mpc": {"dt_min_s": 0.5}}), "mpc.dt_min_s: must be below"),
        (spec(model={"mpc": {"infeasible_recheck_steps": 60}}), "mpc.infeasible_recheck_max_steps: must be >="),
        (spec(model={"mpc": {"infeasible_recheck_steps": 0}}), "mpc.infeasible_recheck_steps: must be >= 1"),
        (spec(model={"barrier": {"lambdas_m": [1.0, -1.0]}}), "all > 0"),
        (spec(model={"mpc": {"controller": "lqr"}}), "unknown controller"),
        ({"campaign": {"seed": 1, "episodes": 1}}, "missing required field 'name'"),
        ({"campaing": {}}, "did you mean 'campaign'"),
    ],
)
def test_bad_input_gives_one_line_naming_the_problem(raw, fragment):
    with pytest.raises(CampaignError) as err:
        campaign_from_dict(raw)
    message = str(err.value)
    assert fragment in message
    assert "\n" not in message


def test_both_epsilon_and_lambda0_is_rejected():
    with pytest.raises(CampaignError, match="not both"):
        campaign_from_dict(spec(model={"barrier": {"lambda0": -0.3, "epsilon": 0.2}}))


def test_order_one_barrier_from_file(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[campaign]\nname="x"\nepisodes=1\n[model.barrier]\nlambdas_m=[2.0]\n')
    camp = load_campaign(path)
    assert math.isclose(camp.cells[0].lambda0, -0.6)


def test_malformed_toml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[campaign\nname = 1")
    with pytest.raises(CampaignError, match="malformed TOML"):
        load_campaign(bad)
    with pytest.raises(CampaignError, match="not found"):
        load_campaign(tmp_path / "nope.toml")


def test_bundle_axes_times_grid_with_own_episode_counts():
    axes = {
        "scenario": {"A": {"opposing.speed_mps": 18.0}, "B": {"opposing.speed_mps": 10.0}},
        "method": {
            "MPC-DC": {"mpc.controller": "mpcdc", "episodes": 5},
            "VL-CBF eps=0.3": {"barrier.epsilon": 0.3},
        },
    }
    camp = campaign_from_dict(spec(axes=axes, model={"opposing": {"kind": "human"}}))
    names = [c.name for c in camp.cells]
    assert names == [
        "scenario=A,method=MPC-DC", "scenario=A,method=VL-CBF eps=0.3",
        "scenario=B,method=MPC-DC", "scenario=B,method=VL-CBF eps=0.3",
    ]
    assert [c.episodes for c in camp.cells] == [5, 3, 5, 3]
    assert [c.episode_offset for c in camp.cells] == [0, 5, 8, 13]  # ids unique across the run
    assert [c.controller for c in camp.cells] == ["mpcdc", "vlcbf", "mpcdc", "vlcbf"]
    assert camp.cells[2].params.opposing.speed_mps == 10.0
    assert camp.cells[0].labels == {"scenario": "A", "method": "MPC-DC"}
    # --episodes from the command line wins over a bundle's count
    forced = campaign_from_dict(spec(axes=axes, model={"opposing": {"kind": "human"}}), episodes=2)
    assert [c.episodes for c in forced.cells] == [2, 2, 2, 2]


def test_mpcdc_eps_is_a_controller_treated_as_mpcdc():
    camp = campaign_from_dict(spec(axes={"method": {"MPC-DC eps=0.5": {"mpc.controller": "mpcdc_eps",
                                                                        "barrier.epsilon": 0.5}}},
                                   model={"opposing": {"kind": "human"}}))
    (cell,) = camp.cells
    assert cell.controller == "mpcdc_eps" and cell.params.mpc.is_mpcdc and cell.epsilon == 0.5
    from mcverify.ocp import OcpStructure, distance_margin, opposing_mode
    assert OcpStructure.from_params(cell.params).constraint == "distance"
    assert opposing_mode(cell.params) == "constant" and distance_margin(cell.params) == 0.5


def test_front_accel_range_grid_and_validation():
    camp = campaign_from_dict(spec(grid={"scenario.front_accel_range_mps2": [[1, 3], [3, 5]]}))
    assert [c.params.scenario.front_accel_range_mps2 for c in camp.cells] == [(1.0, 3.0), (3.0, 5.0)]
    assert camp.cells[0].name == "front_accel_range_mps2=[1,3]"
    with pytest.raises(CampaignError, match="0 <= lo < hi"):
        campaign_from_dict(spec(model={"scenario": {"front_accel_range_mps2": [5, 3]}}))


@pytest.mark.parametrize(
    "raw, fragment",
    [
        (spec(axes={"m": {"x": {"mpc.controler": "mpcdc"}}}), "did you mean 'mpc.controller'"),
        (spec(axes={"m": {"x": {"episodes": 0}}}), "episodes: must be an integer >= 1"),
        (spec(axes={"m": {}}), "one or more tables"),
        (spec(axes={"m": {"x": {"noise.scale": 2.0}}}, grid={"noise.scale": [1.0]}), "sets 'noise.scale' twice"),
        (spec(model={"opposing": {"kind": "robot"}}), "unknown opposing vehicle"),
        (spec(model={"opposing": {"kind": "human", "speed_mps": 30.0}}), "above opposing.speed_limit_mps"),
        (spec(model={"opposing": {"kind": "human", "x_m": 50.0}}), "must start ahead of the front vehicle"),
        (spec(model={"mpc": {"backend": "magic"}}), "unknown solver backend"),
        (spec(model={"mpc": {"controller": "mpcdc_epsilon"}}),
         "mpc.controller: unknown controller 'mpcdc_epsilon'; valid: vlcbf, mpcdc, mpcdc_eps$"),
    ],
)
def test_axes_and_opposing_errors_name_the_problem(raw, fragment):
    with pytest.raises(CampaignError, match=fragment):
        campaign_from_dict(raw)


def test_settings_override_the_files_model_and_are_recorded_in_the_raw_content(tmp_path):
    from mcverify.campaign.spec import apply_settings, load_campaign

    path = tmp_path / "c.toml"
    path.write_text('[campaign]\nname = "t"\nepisodes = 1\n[model.mpc]\nbackend = "ipm"\n'
                    '[axes.eps.a]\n"barrier.epsilon" = 0.3\n[axes.eps.b]\n"barrier.epsilon" = 0.5\n')
    camp = load_campaign(path, settings=["mpc.backend=ipopt", "mpc.max_iter = 40", "noise.scale=0.5"])
    for cell in camp.cells:
        assert cell.params.mpc.backend == "ipopt" and cell.params.mpc.max_iter == 40
        assert cell.params.noise.scale == 0.5
    assert [c.params.barrier.epsilon for c in camp.cells] == [0.3, 0.5]  # axes still apply
    assert camp.raw["model"]["mpc"] == {"backend": "ipopt", "max_iter": 40}  # what a run records (--resume)
    raw = {"campaign": {"name": "t"}, "model": {"mpc": {"backend": "ipm"}}}
    assert apply_settings(raw, ["mpc.backend=ipopt"])["model"]["mpc"]["backend"] == "ipopt"
    assert raw["model"]["mpc"]["backend"] == "ipm", "the caller's content is not changed"
    for bad in ("backend=ipopt", "mpc.=1", ".x=1", "mpc.a.b=1"):
        with pytest.raises(CampaignError, match="expected SECTION.FIELD=VALUE"):
            apply_settings(raw, [bad])


def test_the_level_is_resolved_once_per_cell_either_way():
    from mcverify.levels import Level, epsilon_from_lambda0, lambda0_from_epsilon

    by_eps = campaign_from_dict(spec(model={"barrier": {"epsilon": 0.2}})).cells[0]
    by_l0 = campaign_from_dict(spec(model={"barrier": {"lambda0": -0.5, "lambdas_m": [1.0, 0.5]}})).cells[0]
    assert by_eps.level == Level(0.2, lambda0_from_epsilon((1.0, 0.5), 0.2))
    assert by_l0.level == Level(epsilon_from_lambda0((1.0, 0.5), -0.5), -0.5)
    assert (by_eps.epsilon, by_eps.lambda0) == (by_eps.level.epsilon, by_eps.level.lambda0)  # what rows store
    with pytest.raises(ValueError, match="exactly one of epsilon and lambda0"):
        Level.of((1.0,), epsilon=0.3, lambda0=-0.3)
