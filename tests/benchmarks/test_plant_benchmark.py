"""`python -m benchmarks.plant`: the scanned, vmapped rollout is the engine's plant, and the command's contracts."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks import plant as plant_scaling
from mcverify.campaign.spec import load_campaign
from mcverify.sim import plant as plant_mod


@pytest.fixture(scope="module")
def cell(tiny_campaign_path_module):
    return load_campaign(tiny_campaign_path_module).cells[0]


@pytest.fixture(scope="module")
def tiny_campaign_path_module() -> Path:
    return Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"


def test_scanned_rollout_equals_stepping_the_engine_plant(cell):
    """One lax.scan over the control steps gives the same safety trace as the engine's per-period
    calls (observe, stand-in control, advance on groups of LANES), for every episode of the batch."""
    steps, batch = 6, plant_mod.LANES
    plants, keys = plant_scaling.initial_batch(cell, seed=3, batch=batch)
    pp, cp = plant_mod.plant_params(cell.params), plant_scaling.control_params(cell)
    scanned = plant_scaling.batched_rollout(cell.params.sim.substeps, steps)(plants, keys, pp, cp)

    obs, adv, ini = plant_mod.compiled(cell.params.sim.substeps)
    control = jax.vmap(plant_scaling.stand_in_control, in_axes=(0, 0, None))
    trace = ini(plants, pp)
    for step in range(steps):
        front_meas, _ = obs(plants, keys, jnp.asarray(step), pp)
        plants, trace, _ = adv(plants, trace, control(plants.ego, front_meas, cp), jnp.ones(batch, dtype=bool), pp)

    for name in plant_mod.SafetyTrace._fields:
        np.testing.assert_allclose(np.asarray(getattr(scanned, name)), np.asarray(getattr(trace, name)),
                                   rtol=1e-9, atol=1e-12, err_msg=name)
    # the episodes differ from one another (the noise and alpha_f reach the trace)
    assert len(set(np.round(np.asarray(scanned.min_h_front), 9))) > 1


def test_stand_in_control_keeps_the_lane_and_matches_the_measured_speed(cell):
    cp = plant_scaling.control_params(cell)
    lane_y = float(cp[0])
    left_of_lane = jnp.array([0.0, lane_y + 1.0, 0.0, 10.0])
    u = plant_scaling.stand_in_control(left_of_lane, jnp.array([30.0, lane_y, 12.0]), cp)
    assert float(u[0]) > 0, "slower than the measured veh_f: accelerate"
    assert float(u[1]) < 0, "left of the lane centre: steer right"
    on_lane = jnp.array([0.0, lane_y, 0.0, 12.0])
    u = plant_scaling.stand_in_control(on_lane, jnp.array([30.0, lane_y, 12.0]), cp)
    assert float(u[0]) == 0.0 and float(u[1]) == 0.0


def test_bench_plant_writes_a_row_per_batch_and_merges_included_runs(tmp_path, tiny_campaign_path_module, capsys,
                                                                      monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "BENCHMARKS.md").write_text("# Benchmarks\n\nkept text\n")
    out = tmp_path / "cpu.json"
    argv = ["--campaign", str(tiny_campaign_path_module), "--batches", "8,16", "--steps", "3",
            "--repeats", "1", "--platforms", "cpu", "--json", str(out)]
    assert plant_scaling.main(argv) == 0
    runs = json.loads(out.read_text())
    assert [r["batch"] for r in runs[0]["rows"]] == [8, 16]
    assert all(r["finite"] and r["wall_s"] > 0 for r in runs[0]["rows"])
    # a run from "another machine" is shown beside this one's
    other = [dict(runs[0], device="GPU (stand-in for a test)")]
    (tmp_path / "gpu.json").write_text(json.dumps(other))
    assert plant_scaling.main(argv[:-2] + ["--include", str(tmp_path / "gpu.json")]) == 0
    text = (tmp_path / "results" / "BENCHMARKS.md").read_text()
    assert text.startswith("# Benchmarks\n\nkept text")
    assert text.count(plant_scaling.BEGIN) == 1, "the section is replaced, not appended twice"
    assert "### GPU (stand-in for a test)" in text and "### CPU (" in text


@pytest.mark.parametrize("argv, message", [
    (["--batches", "0,8"], "positive integers"),
    (["--batches", "x"], "positive integers"),
])
def test_bench_plant_bad_arguments_exit_2(argv, message, capsys):
    assert plant_scaling.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err


def test_bench_plant_unreadable_include_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("not json")
    assert plant_scaling.main(["--include", str(bad), "--no-write"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.json" in err


def test_bench_plant_only_include_without_include_is_one_line(capsys):
    assert plant_scaling.main(["--only-include", "--no-write"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--include" in err
