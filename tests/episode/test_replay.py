"""`mcverify replay` through the command line: exact reproduction, trajectories, loud mismatches."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from mcverify import cli

CAMPAIGN = """
[campaign]
name = "replay-test"
seed = 3
episodes = 3

[model.sim]
control_period_s = 0.1
substeps = 20
max_time_s = 4.0

[model.opposing]
kind = "human"
x_m = 330.0
speed_mps = 10.0

[grid]
"noise.scale" = [1.0, 2.0]
"""


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("replay")
    spec = root / "c.toml"
    spec.write_text(CAMPAIGN)
    out = root / "run"
    # chunk size 2: episode 2 of each cell ran in a chunk of its own, the others two together
    assert cli.main(["run", str(spec), "--run-dir", str(out), "--chunk-size", "2", "--workers", "1",
                     "--no-progress"]) == 0
    return out


@pytest.mark.parametrize("episode_id", [0, 4, 5])
def test_replay_reproduces_stored_metrics_exactly(run_dir, episode_id, capsys):
    assert cli.main(["replay", str(run_dir), str(episode_id)]) == 0
    assert "reproduced exactly" in capsys.readouterr().out
    traj = pq.read_table(run_dir / "replay" / f"episode-{episode_id:06d}.parquet")
    for col in ("t_s", "ego_x_m", "ego_y_m", "ego_psi_rad", "ego_speed_mps", "front_x_m", "front_speed_mps",
                "opp_x_m", "opp_speed_mps", "alpha_mps2", "beta_rad", "h_front", "h_opp", "active_problem"):
        assert col in traj.column_names, col
    t = traj.column("t_s").to_numpy()
    assert t.size > 20 and (t[1:] > t[:-1]).all()  # full resolution, ordered
    plans = pq.read_table(run_dir / "replay" / f"episode-{episode_id:06d}-plans.parquet")
    assert set(plans.column("problem").to_pylist()) <= {"Q1", "Q2"} and plans.num_rows >= 51
    assert (run_dir / "replay" / f"episode-{episode_id:06d}.png").stat().st_size > 10_000


def test_replay_fails_loudly_on_a_changed_row(run_dir, capsys):
    path = run_dir / "episodes.parquet"
    table = pq.read_table(path)
    original = table
    column = table.column("min_h_front")
    changed = pc.if_else(pc.equal(table.column("episode_id"), 1), pc.add(column, 1e-12), column)
    pq.write_table(table.set_column(table.column_names.index("min_h_front"), "min_h_front", changed), path)
    try:
        assert cli.main(["replay", str(run_dir), "1"]) == 1
        err = capsys.readouterr().err
        assert "does not reproduce" in err and "min_h_front" in err
    finally:
        pq.write_table(original, path)


def test_replay_of_an_unknown_episode_is_one_clear_line(run_dir, capsys):
    assert cli.main(["replay", str(run_dir), "99"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no episode 99" in err


def test_every_episode_row_is_there(run_dir):
    table = pq.read_table(run_dir / "episodes.parquet")
    assert table.num_rows == 6
    assert table.column("episode_id").to_pylist() == list(range(6))
    assert isinstance(table, pa.Table) and "collision_opp" in table.column_names
