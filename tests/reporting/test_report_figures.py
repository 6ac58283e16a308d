"""mcverify.reporting.run_figures: which figures a run gets; every one of them is written and non-trivial."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import synthetic

from mcverify import store
from mcverify.reporting import run_figures, run_report


def _small(raw: dict, episodes: int) -> dict:
    return {**raw, "campaign": {**raw["campaign"], "episodes": episodes}}


def _figures(run: Path) -> list[run_figures.FigureResult]:
    manifest = store.read_json(run / store.MANIFEST)
    table = store.read_episodes(run)
    summ = run_report.build_summary(manifest, table, run_report.Options(bootstrap_resamples=50))
    return run_figures.write_figures(run, summ, table, manifest)


def _check_all(run: Path, results) -> dict[str, run_figures.FigureResult]:
    """Every drawn figure: the file exists, decodes to its reported size, is not blank, drew data."""
    drawn = {r.key: r for r in results if r.file}
    assert sorted(p.name for p in (run / "figures").glob("*.png")) == sorted(f"{k}.png" for k in drawn)
    for r in drawn.values():
        img = mpimg.imread(run / r.file)
        assert img.shape[:2] == (r.drawn["height_px"], r.drawn["width_px"]), r.key
        assert img[..., :3].std() > 0.05, f"{r.key} is blank"
        assert r.drawn["lines"] + r.drawn["patches"] + r.drawn["collections"] + r.drawn["images"] > 0, r.key
        assert r.title and r.caption, r.key
    return drawn


def test_eps_sweep_gets_rates_against_eps_and_heat_maps(tmp_path):
    run = synthetic.make_run(tmp_path / "eps", _small(synthetic.EPS_SWEEP, 20), probs=synthetic.eps_probs,
                             trajectories=False)
    drawn = _check_all(run, _figures(run))
    assert {"rates", "rate-vs-epsilon", "heatmap-safe", "heatmap-overtook", "min-dist-front"} <= set(drawn)
    assert drawn["rate-vs-epsilon"].drawn["collections"] >= 3 * 2  # 3 rates x 2 noise levels: bars or bounds
    unsafe = drawn["heatmap-safe"].drawn["patches"]  # an outline and a ⚠ per cell with an unsafe episode
    assert drawn["heatmap-safe"].drawn["texts"] == 10 + unsafe  # 5 levels x 2 noise levels, counts written in


def test_lambda0_grid_gets_rates_against_lambda0_and_a_heat_map(tmp_path):
    run = synthetic.make_run(tmp_path / "l0", _small(synthetic.LAMBDA0_GRID, 10), trajectories=False)
    drawn = _check_all(run, _figures(run))
    assert {"rate-vs-lambda0", "heatmap-safe"} <= set(drawn)
    assert drawn["heatmap-safe"].drawn["texts"] == 9


def test_opposing_run_gets_every_episode_figure(tmp_path):
    run = synthetic.make_run(tmp_path / "t3", _small(synthetic.TABLE3, 8), opposing=True)
    results = _figures(run)
    drawn = _check_all(run, results)
    expected = {"rates", "min-dist-front", "min-gap-opp", "barrier-h-ef", "barrier-h-eo", "speeds",
                "snapshots-cell-000", "snapshots-cell-001", "snapshots-cell-002"}
    assert expected == set(drawn)
    assert not [r for r in results if not r.file]
    assert drawn["snapshots-cell-000"].drawn["axes"] == 5


def test_trajectory_lookup_prefers_trajectories_then_lowest_episode(tmp_path):
    for sub, eid in (("replay", 3), ("replay", 1), ("trajectories", 2), ("trajectories", 9)):
        (tmp_path / sub).mkdir(exist_ok=True)
        (tmp_path / sub / f"episode-{eid:06d}.parquet").write_bytes(b"")
    (tmp_path / "trajectories" / "episode-000002-plans.parquet").write_bytes(b"")
    found = run_figures.find_trajectories(tmp_path, {1: 0, 2: 0, 3: 1, 9: 2})
    assert found[0].trajectory == "trajectories/episode-000002.parquet"
    assert found[0].plans == "trajectories/episode-000002-plans.parquet"
    assert found[1].trajectory == "replay/episode-000003.parquet" and found[1].plans is None
    assert found[2].episode_id == 9


def test_sweep_axis_choice():
    cells = [{"labels": {"scale": s, "epsilon": e}, "overrides": {"noise.scale": float(s), "barrier.epsilon": float(e)}}
             for s in ("1", "2", "3") for e in ("0.1", "0.2", "0.3")]
    axes = {"scale": ["1", "2", "3"], "epsilon": ["0.1", "0.2", "0.3"]}
    assert run_figures.sweep_axis(cells, axes) == "epsilon"  # preferred over an equally long axis
    assert run_figures.sweep_axis(cells, {"scale": ["1", "2", "3"]}) == "scale"
    assert run_figures.sweep_axis(cells, {"scale": ["1", "2"]}) == "scale"  # two values: a figure too
    assert run_figures.sweep_axis(cells, {"scale": ["1"]}) is None


def test_nothing_to_draw_is_said(tmp_path):
    run = synthetic.make_run(tmp_path / "nan", _small(synthetic.TABLE3, 3), trajectories=False)
    t = store.read_episodes(run)
    t = t.set_column(t.column_names.index("min_dist_front_m"), "min_dist_front_m",
                     pa.array(np.full(t.num_rows, np.nan)))
    pq.write_table(t, run / store.EPISODES)
    results = {r.key: r for r in _figures(run)}
    assert results["min-dist-front"].file is None
    assert results["min-dist-front"].skipped == "not drawn: no finite value to draw"


def test_run_without_cells(tmp_path):
    run = synthetic.make_run(tmp_path / "x", _small(synthetic.TABLE3, 3), trajectories=False)
    summ = {"cells": [], "axes": {}, "confidence_level": 0.95, "interval_method": "clopper-pearson"}
    results = run_figures.write_figures(run, summ, store.read_episodes(run), {"cells": []})
    assert [r.skipped for r in results] == ["not drawn: the run has no cell"]
