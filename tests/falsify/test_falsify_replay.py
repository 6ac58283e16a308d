"""End to end with the real closed loop: a falsification episode replays bit for bit (slow)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import tomllib

from mcverify.campaign import executors
from mcverify.campaign.replay import replay
from mcverify.falsify import search

CAMPAIGN = Path(__file__).resolve().parents[2] / "campaigns" / "falsify_mpcdc_table4b.toml"


@pytest.mark.slow  # two closed-loop episodes and a replay: about a minute of CPU
def test_a_searched_episode_with_disturbances_replays_bit_for_bit(tmp_path):
    raw = tomllib.loads(CAMPAIGN.read_text(encoding="utf-8"))
    raw = copy.deepcopy(raw)
    raw["model"]["sim"] = {"control_period_s": 0.1, "substeps": 20}
    config = search.SearchConfig(raw, str(CAMPAIGN), "cma", budget=2, seed=1, requirement="safe")
    res = search.start(config, tmp_path / "s", make_executor=executors.SerialExecutor)
    ev = min(res.evaluations, key=lambda e: e.robustness)
    assert ev.values["noise.structured_share"] > 0.0  # the disturbance is part of the episode's inputs
    gen_dir = tmp_path / "s" / search.GENERATIONS / f"g{ev.generation:03d}"
    out = replay(gen_dir, int(ev.row["episode_id"]))  # raises ReplayMismatch unless every metric agrees
    assert out.row["min_h_front"] == ev.row["min_h_front"]
