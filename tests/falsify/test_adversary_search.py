"""mcverify falsify over the perception error ([falsify.adversary]): validation, determinism, resume, baselines,
and a found counterexample that replays bit for bit with its stored schedule."""

from __future__ import annotations

import copy
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest

from mcverify.campaign import executors
from mcverify.campaign.replay import replay
from mcverify.campaign.spec import campaign_from_dict
from mcverify.episode.schedule_file import SCHEDULES, read_schedule, schedule_path
from mcverify.errors import CampaignError, RunError
from mcverify.falsify import ask_tell, search
from mcverify.falsify.parametrisations import BangBang, FullSequence, parametrisation
from tests.falsify import fake_episodes

RAW = {
    "campaign": {"name": "fza", "seed": 11, "episodes": 1},
    "model": {"sim": {"control_period_s": 0.1, "max_time_s": 2.0}},
    "falsify": {
        "requirement": "ellipse", "population": 4, "stop_at_first": False,
        "bounds": {"scenario.front_speed_mps": [5.0, 9.0]},
        "adversary": {"kind": "bang_bang", "segments": 4, "channels": ["front_x", "front_y"]},
    },
}


def _config(method="cma", budget=12, raw=RAW, seed=3):
    return search.SearchConfig(raw=copy.deepcopy(raw), source="<test>", method=method, budget=budget, seed=seed,
                               requirement=raw["falsify"]["requirement"])


def _kw():
    return {"make_executor": executors.SerialExecutor, "episode_fn": fake_episodes.scheduled}


def _with(**adversary):
    raw = copy.deepcopy(RAW)
    raw["falsify"]["adversary"] = adversary
    return raw


@pytest.mark.parametrize(("adversary", "message"), [
    ({"kind": "wiggle"}, "kind: expected one of gap_bands"),
    ({"kind": "bang_bang", "segments": 0}, "segments: expected a positive integer"),
    ({"kind": "bang_bang", "edges_m": [1, 2, 3]}, "unknown key 'edges_m' for kind 'bang_bang'"),
    ({"kind": "gap_bands", "edges_m": [3, 2, 1]}, "must not decrease"),
    ({"kind": "gap_bands", "channels": ["front_z"]}, "channels: expected distinct names"),
    ({"kind": "full", "front_share": 1.5}, "front_share: expected a number in [0, 1]"),
    ({"kind": "windows"}, "needs centres_s"),
])
def test_bad_adversary_tables_are_one_line(adversary, message):
    with pytest.raises(CampaignError, match=None) as err:
        campaign_from_dict(_with(**adversary))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_adversary_replaces_the_drawn_noise():
    raw = copy.deepcopy(RAW)
    raw["falsify"]["bounds"] = {"noise.front_x_bias": [-1.0, 1.0]}
    with pytest.raises(CampaignError, match="which \\[falsify.adversary\\] replaces"):
        campaign_from_dict(raw)
    raw["falsify"].update(bounds={}, common_noise=True)
    with pytest.raises(CampaignError, match="common_noise"):
        campaign_from_dict(raw)
    with pytest.raises(RunError, match="splitting"):
        search.check(_config("splitting"))
    raw = copy.deepcopy(RAW)
    raw["model"]["noise"] = {"kind": "none"}
    with pytest.raises(RunError, match="no bounds to search in"):
        search.check(_config(raw=raw))


# random in the default suite; cma and cross-entropy (10-20 s each on the closed loop) with -m slow
@pytest.mark.parametrize("method", [pytest.param("cma", marks=pytest.mark.slow),
                                    pytest.param("cross-entropy", marks=pytest.mark.slow), "random"])
def test_a_schedule_search_is_deterministic_and_resumes_to_the_uninterrupted_result(tmp_path, method):
    whole = search.start(_config(method), tmp_path / "whole", **_kw())
    with pytest.raises(RunError, match="test hook"):
        search.start(_config(method), tmp_path / "cut", stop_after_generations=1, **_kw())
    resumed = search.resume(tmp_path / "cut", **_kw())
    a, b = pq.read_table(tmp_path / "whole" / search.SEARCH), pq.read_table(tmp_path / "cut" / search.SEARCH)
    assert a.equals(b) and whole.episodes == resumed.episodes == 12
    assert len({tuple(t) for t in a.column("adversary_theta").to_pylist()}) == 12  # the error was searched
    # each candidate's stored schedule is its theta's, and its cost is counted in control steps
    ev = whole.evaluations[7]
    gen = tmp_path / "whole" / search.GENERATIONS / f"g{ev.generation:03d}"
    stored = read_schedule(schedule_path(gen / SCHEDULES, int(ev.row["episode_id"])))
    spec = campaign_from_dict(RAW).falsify.adversary
    expected = BangBang(20, 4, ("front_x", "front_y")).schedule(2 * np.array(ev.point[1:]) - 1)
    assert parametrisation(spec, campaign_from_dict(RAW).cells[0].params.sim) == BangBang(20, 4, ("front_x", "front_y"))
    assert np.array_equal(stored.units, expected.units)
    assert whole.full_episode_steps == 20 and whole.control_steps == sum(e.control_steps for e in whole.evaluations) > 0
    assert a.column("episode_equivalents").to_pylist()[-1] == pytest.approx(whole.control_steps / 20)
    if method == "cma":  # a search that descends: its best is below random's at the same budget and seed
        rand = search.start(_config("random"), tmp_path / "rand", **_kw())
        assert whole.min_robustness <= rand.min_robustness


def test_random_over_bang_bang_and_full_are_the_random_baselines(tmp_path):
    res = search.start(_config("random", budget=8), tmp_path / "bb", **_kw())
    for ev in res.evaluations:
        units = read_schedule(schedule_path(tmp_path / "bb" / search.GENERATIONS / f"g{ev.generation:03d}" / SCHEDULES,
                                            int(ev.row["episode_id"]))).units
        assert set(np.unique(units[:, :2])) <= {-1.0, 1.0} and not units[:, 2:].any()
    raw = _with(kind="full", channels=["front_y"])
    raw["falsify"]["bounds"] = {}
    res = search.start(_config("random", budget=8, raw=raw), tmp_path / "full", **_kw())
    assert ask_tell.search_dimension(*search.target(_config(raw=raw))) == FullSequence(20, ("front_y",)).dimension
    ev = res.evaluations[3]
    units = read_schedule(schedule_path(tmp_path / "full" / search.GENERATIONS / "g000" / SCHEDULES,
                                        int(ev.row["episode_id"]))).units
    assert np.array_equal(units[:, 1], 2 * np.array(ev.point) - 1) and np.ptp(units[:, 1]) > 1.0


@pytest.mark.slow  # about 15 s; the one-line errors of the table itself are tested above in the default suite
def test_cli_bad_adversary_exits_2_with_one_line(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text('[campaign]\nname = "b"\nseed = 1\nepisodes = 1\n[falsify.adversary]\nkind = "wiggle"\n')
    proc = subprocess.run([sys.executable, "-m", "mcverify.cli", "falsify", str(f), "--budget", "4"],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "kind: expected one of" in proc.stderr
    f.write_text('[campaign]\nname = "b"\nseed = 1\nepisodes = 1\n[falsify.adversary]\nkind = "gap_bands"\n')
    proc = subprocess.run([sys.executable, "-m", "mcverify.cli", "falsify", str(f), "--budget", "4",
                           "--method", "splitting", "--dry-run"], capture_output=True, text=True, check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "splitting" in proc.stderr


REAL = {"campaign": {"name": "adv-real", "seed": 3, "episodes": 1},
        "model": {"sim": {"control_period_s": 0.1, "substeps": 20, "max_time_s": 3.0},
                  "scenario": {"front_x_m": 30.0}},
        "falsify": {"requirement": "stl:always (h_ef >= 1.2)", "population": 2, "stop_at_first": False,
                    "adversary": {"kind": "bang_bang", "segments": 2, "channels": ["front_x", "front_y"]}}}


@pytest.mark.slow  # about 30 s; tests/falsify/test_adversary.py replays a run with schedules in the default suite
def test_a_counterexample_found_with_a_schedule_replays_bit_for_bit(tmp_path):
    """The real closed loop (30 steps): a violating candidate of a schedule search re-simulates exactly from
    its generation folder (replay raises unless every metric agrees)."""
    config = search.SearchConfig(copy.deepcopy(REAL), "<test>", "random", budget=2, seed=5,
                                 requirement=REAL["falsify"]["requirement"])
    res = search.start(config, tmp_path / "s", make_executor=executors.SerialExecutor)
    hits = [e for e in res.evaluations if e.robustness < 0]
    assert hits, [e.robustness for e in res.evaluations]
    gen_dir = tmp_path / "s" / search.GENERATIONS / f"g{hits[0].generation:03d}"
    out = replay(gen_dir, int(hits[0].row["episode_id"]))
    assert out.row["min_h_front"] == hits[0].row["min_h_front"]
    assert pq.read_table(tmp_path / "s" / search.COUNTEREXAMPLES).num_rows == len(hits)
