"""The falsification report names episodes by their replay ids (issue 51): gG/E, episode E (from 0) of
generation G, as ``mcverify replay OUT/generations/gGGG E`` takes them, never a 1-based count."""

from __future__ import annotations

import math

import numpy as np

from mcverify.falsify import report
from mcverify.reporting.figure_common import subplots


def test_the_robustness_axis_ticks_each_generation_at_its_episode_zero():
    episodes = [(g, e) for g in range(3) for e in range(4)]
    values = [1.0] * 12
    values[6] = -0.5  # generation 1, episode 2
    fig, ax = subplots(figsize=(6.0, 3.0))
    ax.plot(np.arange(12), values)
    report._replay_id_axis(ax, values, episodes)
    assert list(ax.get_xticks()) == [0, 4, 8]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["g000/0", "g001/0", "g002/0"]
    labels = [t.get_text() for t in ax.texts]
    assert labels == ["g001/2"]  # the worst episode, by its replay id


def test_one_generation_runs_its_axis_through_the_episode_ids(tmp_path):
    episodes = [(0, e) for e in range(5)]
    fig, ax = subplots(figsize=(6.0, 3.0))
    ax.plot(np.arange(5), [0.3, 0.2, -0.1, 0.4, math.nan])
    report._replay_id_axis(ax, [0.3, 0.2, -0.1, 0.4, math.nan], episodes)
    assert ax.get_xlabel() == "episode id (generation g000)"
    assert [t.get_text() for t in ax.texts] == ["g000/2"]
    path = tmp_path / "r.png"
    report.robustness_curves({"random": [0.3, 0.2, -0.1, 0.4, math.nan]}, path, "safe", episodes)
    assert path.stat().st_size > 1000


class _E:
    def __init__(self, generation, episode_id, parent, move, branch=-1):
        self.generation, self.row, self.parent, self.move = generation, {"episode_id": episode_id}, parent, move
        self.branch_after_step = branch


def test_the_lineage_names_each_ancestor_by_its_replay_id():
    ev = [_E(0, 0, 0, "fresh"), _E(0, 1, 0, "fresh"), _E(1, 0, 2, "noise", 30), _E(2, 3, 3, "scenario")]
    assert report.lineage(ev, 4) == ("episode g002/3 (scenario step) ← g001/0 (noise branch after step 30) ← "
                                     "g000/1 (fresh)")
