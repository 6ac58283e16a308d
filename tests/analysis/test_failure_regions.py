"""Counterexamples grouped by failure mode and parameter region (mcverify.analysis.failure_regions)."""

from __future__ import annotations

import random

import pytest

from mcverify.analysis import failure_regions as fr

BOUNDS = {"param:v": (0.0, 10.0), "param:g": (100.0, 200.0)}


def _records():
    # mode A: a chain 1.0 - 2.5 - 4.0 in v (steps of 0.15 of the range) and one far away at 9.0;
    # mode B: one at the same place as A's chain (another mode: another region)
    pts = [("A", 1.0, 150.0, -0.3), ("A", 2.5, 155.0, -0.1), ("A", 4.0, 160.0, -0.2), ("A", 9.0, 150.0, -0.05),
           ("B", 2.5, 155.0, -0.4)]
    return [{"episode_id": i, "failure_mode": m, "param:v": v, "param:g": g, "robustness": rob,
             "replay": f"mcverify replay R {i}"} for i, (m, v, g, rob) in enumerate(pts)]


def test_single_linkage_within_a_mode_and_boxes():
    records = _records()
    regions = fr.assign(records, BOUNDS)
    assert [(g.region, g.failure_mode, g.count) for g in regions] == [(1, "A", 3), (2, "B", 1), (3, "A", 1)]
    assert [r["region"] for r in records] == [1, 1, 1, 3, 2]
    assert regions[0].box == {"param:v": (1.0, 4.0), "param:g": (150.0, 160.0)}
    assert regions[0].worst_robustness == -0.3 and regions[0].worst_replay == "mcverify replay R 0"
    assert fr.from_records(records) == regions  # the report rebuilds them from the stored column


def test_the_link_is_in_every_coordinate_and_order_does_not_matter():
    records = _records()
    records[1]["param:g"] = 190.0  # now 0.35 of g's range from its neighbours: the chain breaks twice
    assert [g.count for g in fr.assign(records, BOUNDS)] == [1, 1, 1, 1, 1]
    records = _records()
    shuffled = [dict(r) for r in records]
    random.Random(3).shuffle(shuffled)
    fr.assign(records, BOUNDS)
    fr.assign(shuffled, BOUNDS)
    assert {r["episode_id"]: r["region"] for r in records} == {r["episode_id"]: r["region"] for r in shuffled}


@pytest.mark.parametrize("bounds", [{}, {"param:v": (3.0, 3.0)}, {"param:missing": (0.0, 1.0)}])
def test_without_usable_coordinates_each_mode_is_one_region(bounds):
    regions = fr.assign(_records(), bounds)
    assert sorted((g.failure_mode, g.count) for g in regions) == [("A", 4), ("B", 1)]


def test_numeric_columns_and_span():
    records = _records()
    records[0]["param:text"] = "x"
    records[0]["sample_a"] = float("nan")
    assert fr.numeric_columns(records) == ["param:v", "param:g"]
    assert fr.span([None, 3.0, float("nan"), 1, "x"]) == (1.0, 3.0) and fr.span([None]) is None
