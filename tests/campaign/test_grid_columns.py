"""episodes.parquet carries the grid values (schema.GRID_FAMILY) as typed columns, so a notebook
groups episodes by barrier.epsilon or mpc.controller without joining cells.parquet; the columns
are inputs copied from the cells' overrides (the same as cells.parquet's), not metrics."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import synthetic_episodes as synth

from mcverify import schema, store
from mcverify.campaign import executors, runner
from mcverify.campaign.spec import campaign_from_dict

RAW = {"campaign": {"name": "g", "seed": 3, "episodes": 3},
       "grid": {"barrier.epsilon": [0, 0.3], "scenario.front_accel_range_mps2": [[1.0, 3.0], [3.0, 5.0]]},
       "axes": {"method": {"A": {"mpc.controller": "vlcbf", "sim.substeps": 10},
                           "B": {"mpc.controller": "mpcdc", "sim.substeps": 10}}}}


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    run_dir = tmp_path_factory.mktemp("grid") / "run"
    runner.run(campaign_from_dict(RAW), run_dir, executor=executors.SerialExecutor(), chunk_size=2, progress=False,
               episode_fn=synth.episodes)
    return run_dir


def test_episodes_have_the_varied_fields_typed_after_seed(run: Path):
    t = pq.read_table(run / store.EPISODES)
    grid = ["mpc.controller", "barrier.epsilon", "scenario.front_accel_range_mps2"]  # as the overrides list them
    at = t.column_names.index("seed") + 1
    assert t.column_names[at:at + 3] == grid
    assert "sim.substeps" not in t.column_names  # the same in every cell: no column
    assert [t.schema.field(n).type for n in grid] == [pa.string(), pa.float64(), pa.string()]
    assert all(schema.is_grid_column(n) for n in grid) and not schema.is_grid_column("min_h_front")
    cells = {int(c["index"]): c["overrides"] for c in store.read_json(run / store.MANIFEST)["cells"]}
    for r in t.to_pylist():  # every row holds its own cell's values
        o = cells[r["cell_index"]]
        assert r["barrier.epsilon"] == float(o["barrier.epsilon"])
        assert r["mpc.controller"] == o["mpc.controller"]
        assert r["scenario.front_accel_range_mps2"] == str(o["scenario.front_accel_range_mps2"])
    assert t.num_rows == 8 * 3


def test_the_same_columns_and_values_as_cells_parquet(run: Path):
    episodes = pq.read_table(run / store.EPISODES)
    cells = pq.read_table(run / "cells.parquet")
    grid = [n for n in episodes.column_names if schema.is_grid_column(n)]
    assert grid == [n for n in cells.column_names if schema.is_grid_column(n)]
    by_cell = {r["cell_index"]: r for r in cells.to_pylist()}
    for r in episodes.to_pylist():
        assert {n: r[n] for n in grid} == {n: by_cell[r["cell_index"]][n] for n in grid}
        assert episodes.schema.field(grid[0]).type == cells.schema.field(grid[0]).type


def test_pandas_groups_episodes_by_a_grid_value(run: Path):
    pd = pytest.importorskip("pandas")
    df = pd.read_parquet(run / store.EPISODES)
    counts = df.groupby(["barrier.epsilon", "mpc.controller"]).size()
    assert counts.to_dict() == {(0.0, "mpcdc"): 6, (0.0, "vlcbf"): 6, (0.3, "mpcdc"): 6, (0.3, "vlcbf"): 6}


def test_a_run_without_a_grid_has_no_grid_column(tmp_path: Path):
    runner.run(campaign_from_dict({"campaign": {"name": "one", "seed": 1, "episodes": 2}}), tmp_path / "r",
               executor=executors.SerialExecutor(), chunk_size=2, progress=False, episode_fn=synth.episodes)
    names = pq.read_table(tmp_path / "r" / store.EPISODES).column_names
    assert not [n for n in names if schema.is_grid_column(n)]
    assert names == [n for n in schema.COLUMN_NAMES if n in names]  # only declared columns, in file order


def test_grid_columns_typing_and_refusals():
    assert schema.grid_columns([{"noise.scale": 2.0}, {}]) == {"noise.scale": pa.float64()}  # set in some cells
    assert schema.grid_columns([{"a.b": 1}, {"a.b": 1}]) == {}
    assert schema.grid_columns([{"a.b": True}, {"a.b": False}]) == {"a.b": pa.bool_()}
    assert schema.grid_value([1, 2], pa.string()) == "[1, 2]" and schema.grid_value(3, pa.float64()) == 3.0
    with pytest.raises(ValueError, match="not a <section>.<field> name"):
        schema.grid_columns([{"Bad Name": 1}, {"Bad Name": 2}])
