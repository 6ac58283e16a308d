"""counterexamples.parquet says when each counterexample first violated its requirement
(``first_violation_s``, from the stored trajectory), and its figure gets a panel at that moment."""

from __future__ import annotations

import copy

import numpy as np
import pyarrow.parquet as pq

from mcverify import store
from mcverify.campaign import executors
from mcverify.falsify import search
from mcverify.reporting import episode_figures
from tests.falsify import fake_episodes

RAW = {
    "campaign": {"name": "walk", "seed": 5, "episodes": 1},
    "falsify": {"requirement": "ellipse", "population": 8, "stop_at_first": True,
                "bounds": {"scenario.front_speed_mps": [5.0, 9.0]}},
}


def test_each_counterexample_carries_its_first_violation_time(tmp_path):
    config = search.SearchConfig(raw=copy.deepcopy(RAW), source="<test>", method="splitting", budget=60, seed=3,
                                 requirement="ellipse")
    result = search.start(config, tmp_path / "s", make_executor=executors.SerialExecutor,
                          episode_fn=fake_episodes.noisy_walk)
    records = pq.read_table(result.out_dir / search.COUNTEREXAMPLES).to_pylist()
    assert records, "the splitting search should find the noise-driven violation"
    for r in records:
        traj = store.read_trajectory(result.out_dir / search.GENERATIONS / f"g{r['generation']:03d}", r["episode_id"])
        first = traj["t_s"][np.argmax(traj["h_front"] < 0)]
        assert r["first_violation_s"] == first
        assert r["first_violation_s"] == r["first_unsafe_s"]  # the fake's rows say the same


def test_the_moment_gets_its_own_panel_unless_one_shows_it():
    assert episode_figures._with_moment([0.0, 1.5, 3.0], 4.7, None) == [0.0, 1.5, 3.0, 4.7]
    assert episode_figures._with_moment([0.0, 1.5, 3.0], 1.5, None) == [0.0, 1.5, 3.0]
    assert episode_figures._with_moment([0.0, 3.0], float("nan"), None) == [0.0, 3.0]
    assert episode_figures._with_moment([0.0, 3.0], None, None) == [0.0, 3.0]
