"""mcverify.reporting.figures: every figure is written, decodes, has its size in pixels, is not blank, and
drew its data (artist counts); missing columns are left out rather than failing."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pyarrow as pa
import pytest
import synthetic

from mcverify.analysis import summary
from mcverify.campaign import runner
from mcverify.campaign.spec import campaign_from_dict
from mcverify.reporting import cell_figures, episode_figures, figure_common


def check_png(path: Path, size_in: tuple[float, float]) -> np.ndarray:
    """The image decodes, has figsize x DPI pixels and is not blank."""
    assert path.is_file() and path.stat().st_size > 5_000
    img = mpimg.imread(path)
    w, h = (round(x * figure_common.DPI) for x in size_in)  # figure_common.inches makes this exact
    assert img.shape[:2] == (h, w)
    rgb = img[..., :3]
    assert rgb.std() > 0.05, "blank image"
    assert len(np.unique(rgb.reshape(-1, 3).round(2), axis=0)) > 20, "too few colours for a plot"
    return img


def _cells(raw, probs=synthetic.default_probs, opposing=False):
    camp = campaign_from_dict(raw)
    rows = []
    for cell in camp.cells:
        rows += synthetic.episode_rows(cell, camp.seed, probs(cell), opposing=opposing, crn=False)
    table = pa.Table.from_pylist(rows)
    return summary.summarise(table, runner.manifest_for(camp, 8, {}), bootstrap_resamples=50), table


def test_rates_per_cell(tmp_path):
    summ, _ = _cells(synthetic.TABLE3)
    drawn = cell_figures.rates_per_cell(summ["cells"], tmp_path / "r.png")
    check_png(tmp_path / "r.png", (12, 0.32 * 3 + 1.8))
    outcomes_present = sum(any(c["outcomes"][o] for c in summ["cells"]) for o in ("overtook", "went_back", "timeout"))
    assert drawn["patches"] == 3 * outcomes_present  # one bar per cell and outcome
    assert drawn["lines"] >= 3 * 3  # three rates with error bars (points + caps)


def test_rate_vs_axis_draws_points_with_bars_and_bounds_on_a_log_scale(tmp_path):
    summ, _ = _cells(synthetic.EPS_SWEEP, probs=synthetic.eps_probs)
    cells = summ["cells"]
    xs = [summary.axis_value(c, "epsilon") for c in cells]
    groups = [c["labels"]["noise"] for c in cells]
    metrics = [("collision", "collision"), ("ellipse_violation", "ellipse violated")]
    drawn = cell_figures.rate_vs_axis(cells, "epsilon", xs, groups, metrics, tmp_path / "e.png", level=0.95)
    check_png(tmp_path / "e.png", (12, 4.2))
    # per panel and group: an interval bar collection where some cell saw events, a dotted bound line
    # collection where some cell saw none
    expected = 0
    for metric, _ in metrics:
        for group in dict.fromkeys(groups):
            ks = [c["rates"][metric]["k"] for c, g in zip(cells, groups, strict=True) if g == group]
            expected += any(k > 0 for k in ks) + any(k == 0 for k in ks)
    assert drawn["collections"] == expected


def test_log_floor_sits_below_every_drawn_number():
    cells = [{"rates": {"collision": {"k": 1, "n": 200, "rate": 0.005, "low": 1.3e-4, "high": 0.027,
                                      "upper_one_sided": 0.023}}},
             {"rates": {"collision": {"k": 0, "n": 100, "rate": 0.0, "low": 0.0, "high": 0.036,
                                      "upper_one_sided": 0.0295}}}]
    assert cell_figures._log_floor(cells, ["collision"]) == pytest.approx(1.3e-4 / 3)
    assert cell_figures._log_floor(cells[1:], ["collision"]) == pytest.approx(0.0295 / 3)


def test_heatmap_writes_every_count(tmp_path):
    summ, _ = _cells(synthetic.LAMBDA0_GRID)
    axes = summ["axes"]
    drawn = cell_figures.rate_heatmap(summ["cells"], "lambda0", axes["lambda0"], "front_accel_range_mps2",
                                 axes["front_accel_range_mps2"], "safe", tmp_path / "h.png", title="safe rate")
    check_png(tmp_path / "h.png", (max(5.0, 1.9 * 3 + 2.5), max(3.0, 0.75 * 3 + 1.6)))
    assert drawn["texts"] == 9 and drawn["images"] == 1 and drawn["patches"] == 0  # every cell safe: no outline


def test_heatmap_outlines_the_cells_with_an_unsafe_episode(tmp_path):
    summ, _ = _cells(synthetic.EPS_SWEEP, probs=synthetic.eps_probs)
    cells, axes = summ["cells"], summ["axes"]
    unsafe = [c["cell"] for c in cells if cell_figures.unsafe_cell(c)]
    assert 0 < len(unsafe) < len(cells)  # the fixture has both kinds
    assert all(c["rates"]["safe"]["k"] < c["rates"]["safe"]["n"] for c in cells if c["cell"] in unsafe)
    drawn = cell_figures.rate_heatmap(cells, "epsilon", axes["epsilon"], "noise", axes["noise"], "safe",
                                      tmp_path / "h.png", title="safe rate")
    assert drawn["patches"] == len(unsafe)  # one outline per unsafe cell
    assert drawn["texts"] == len(cells) + len(unsafe)  # the counts, and a ⚠ per unsafe cell


def test_distance_histograms(tmp_path):
    rng = np.random.default_rng(0)
    samples = [rng.normal(0.8, 0.2, 30), rng.normal(0.5, 0.3, 30), np.array([np.nan, np.nan])]
    drawn = cell_figures.distance_histograms(["a", "b", "c"], samples, tmp_path / "d.png", x_label="m")
    check_png(tmp_path / "d.png", (3 * 3, 2.3 + 0.6))
    assert drawn["axes"] == 3 and drawn["patches"] == 2  # a filled histogram per cell with data
    with pytest.raises(ValueError, match="no finite value"):
        cell_figures.distance_histograms(["c"], [np.array([np.nan])], tmp_path / "x.png", x_label="m")


def test_snapshots_with_plans_opposing_and_without(tmp_path):
    traj = synthetic.trajectory(opposing=True)
    plans = synthetic.plans(traj, opposing=True)
    full = episode_figures.snapshots(traj, plans, None, tmp_path / "s.png", title="full")
    assert mpimg.imread(tmp_path / "s.png").shape[:2] == (full["height_px"], full["width_px"])
    check_png(tmp_path / "s.png", (12, full["height_px"] / figure_common.DPI))
    assert 5 * 0.6 * figure_common.DPI < full["height_px"] < 5 * 2.0 * figure_common.DPI  # five thin road panels
    assert full["axes"] == 5
    assert full["patches"] >= 5 * 3  # ego, front and ellipse in every panel
    assert full["lines"] >= 5 * 3  # ego path, Q1 and Q2 plans in every panel
    bare_traj = {k: v for k, v in synthetic.trajectory(opposing=False).items()
                 if not k.startswith("opp_") and k not in ("ego_psi_rad", "front_y_m")}
    bare = episode_figures.snapshots(bare_traj, None, None, tmp_path / "b.png", title="bare")
    assert mpimg.imread(tmp_path / "b.png").shape[:2] == (bare["height_px"], bare["width_px"])
    check_png(tmp_path / "b.png", (12, bare["height_px"] / figure_common.DPI))
    assert bare["lines"] < full["lines"] and bare["patches"] < full["patches"]


def test_barrier_and_speed_series(tmp_path):
    with_opp = synthetic.trajectory(opposing=True)
    no_opp = synthetic.trajectory(opposing=False)
    drawn = episode_figures.barrier_series([("a", with_opp, 0.3), ("b", no_opp, 0.5), ("c", with_opp, 0.1)],
                                   tmp_path / "h.png")
    check_png(tmp_path / "h.png", (12, 2 * 2.6 + 0.6))
    assert drawn["axes"] == 3 and drawn["lines"] >= 3 * 3  # h, its level and 0 per panel
    assert drawn["patches"] >= 3  # Q1/Q2 shading
    opp = episode_figures.barrier_series([("a", with_opp, 1.0)], tmp_path / "o.png", opp=True)
    check_png(tmp_path / "o.png", (6, 2.6 + 0.6))
    assert opp["lines"] == 3
    speeds = episode_figures.speed_profiles([("a", with_opp, 19.4), ("b", no_opp, 19.4)], tmp_path / "v.png")
    check_png(tmp_path / "v.png", (12, 2.6 + 0.6))
    assert speeds["lines"] == (3 + 1) + (2 + 1)  # the opposing speed only where there is one


def test_missing_h_column_is_said_not_drawn(tmp_path):
    traj = {k: v for k, v in synthetic.trajectory().items() if k != "h_front"}
    drawn = episode_figures.barrier_series([("a", traj, 0.3)], tmp_path / "h.png")
    assert drawn["texts"] == 1 and drawn["lines"] == 0


def test_same_data_same_bytes(tmp_path):
    traj = synthetic.trajectory()
    plans = synthetic.plans(traj)
    episode_figures.snapshots(traj, plans, None, tmp_path / "a.png", title="x")
    episode_figures.snapshots(traj, plans, None, tmp_path / "b.png", title="x")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    assert b"Matplotlib" not in (tmp_path / "a.png").read_bytes()  # no version stamp in the metadata
