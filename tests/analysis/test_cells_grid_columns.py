"""cells.parquet carries every varied model field as a typed column named as in the campaign file,
so a notebook filters and plots by the numbers, not by parsing cell names."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.parquet as pq
import synthetic

from mcverify.analysis.cells import varied_fields
from mcverify.reporting import run_report


def test_grid_and_axis_fields_are_typed_columns(tmp_path):
    raw = {"campaign": {"name": "g", "seed": 3, "episodes": 4},
           "grid": {"barrier.epsilon": [0, 0.3], "scenario.front_speed_kmh": [25, 36],
                    "scenario.front_accel_range_mps2": [[1.0, 3.0], [3.0, 5.0]]},
           "axes": {"method": {"A": {"mpc.controller": "vlcbf", "sim.substeps": 10},
                               "B": {"mpc.controller": "mpcdc", "sim.substeps": 10}}}}
    run = synthetic.make_run(tmp_path / "run", raw, trajectories=False)
    run_report.write(run)
    t = pq.read_table(run / "cells.parquet")
    assert t.schema.field("barrier.epsilon").type == pa.float64()       # [0, 0.3]: ints and floats -> float
    assert t.schema.field("scenario.front_speed_kmh").type == pa.int64()
    assert t.schema.field("mpc.controller").type == pa.string()
    assert t.schema.field("scenario.front_accel_range_mps2").type == pa.string()
    assert "sim.substeps" not in t.column_names, "the same in every cell: not varied"
    rows = t.to_pylist()
    assert len(rows) == 16
    first = rows[0]
    assert (first["mpc.controller"], first["barrier.epsilon"], first["scenario.front_speed_kmh"],
            first["scenario.front_accel_range_mps2"]) == ("vlcbf", 0.0, 25, "[1.0, 3.0]")
    for r in rows:  # the typed values agree with the cell's name
        assert f"epsilon={r['barrier.epsilon']:g}" in r["cell"]
        assert f"front_speed_kmh={r['scenario.front_speed_kmh']}" in r["cell"]


def test_a_field_set_in_some_cells_only_is_varied_with_nulls():
    cells = [{"overrides": {"noise.scale": 2.0}}, {"overrides": {}}]
    assert varied_fields(cells) == {"noise.scale": pa.float64()}
