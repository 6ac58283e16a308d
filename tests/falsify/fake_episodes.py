"""A cheap episode function for falsification tests: rows whose margins depend on the cell's
parameters (the searched fields) and on per-episode noise from (seed, episode id) only."""

from __future__ import annotations

import math

import numpy as np

from tests import synthetic_episodes


def episodes(cell, episode_ids, seed, common_random_numbers, record):
    out = synthetic_episodes.episodes(cell, episode_ids, seed, common_random_numbers, record)
    v = cell.params.scenario.front_speed_mps
    o = cell.params.opposing.speed_mps
    for r in out.rows:
        noise = np.random.default_rng([seed, int(r["episode_id"])]).random()
        min_h = 0.6 * abs(v - 8.6) + 0.05 * abs(o - 17.0) - 0.15 + 0.01 * noise
        r.update({"min_h_front": min_h, "collision_front": False, "ellipse_violation": min_h < 0,
                  "min_gap_front_m": 1.0, "safe": min_h >= 0, "opposing_kind": "none",
                  "first_unsafe_s": 3.0 if min_h < 0 else math.nan,
                  "first_unsafe_cause": "planned" if min_h < 0 else ""})
    return out
