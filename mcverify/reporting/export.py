"""``mcverify export RUN_DIR --csv``: a run folder's tables as CSV, for spreadsheets and other tools.

Writes ``episodes.csv``, ``cells.csv`` and ``counterexamples.csv`` (each where the folder has the
parquet file) with the same columns and rows as the parquet files; nested values (lists, structs)
become JSON text. The parquet files stay the record: the CSV files are a copy, rewritten on every
export.
"""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from mcverify.errors import RunError
from mcverify.files import atomic_write

#: The tables a run folder keeps, in the order they are exported.
TABLES: tuple[str, ...] = ("episodes", "cells", "counterexamples")


def _flat(table: pa.Table) -> pa.Table:
    """``table`` with every nested column as JSON text (CSV has no lists or structs)."""
    for i, field in enumerate(table.schema):
        if pa.types.is_nested(field.type):
            text = pa.array([None if v is None else json.dumps(v) for v in table.column(i).to_pylist()], pa.string())
            table = table.set_column(i, field.name, text)
    return table


def export_csv(run_dir: Path, out_dir: Path | None = None) -> list[Path]:
    """Write each table of ``run_dir`` as CSV into ``out_dir`` (default: the run folder itself).

    Returns the files written. Raises :class:`~mcverify.errors.RunError` (one line) when the folder
    holds none of the tables."""
    run_dir = Path(run_dir)
    sources = [(name, run_dir / f"{name}.parquet") for name in TABLES]
    present = [(name, path) for name, path in sources if path.is_file()]
    if not present:
        raise RunError(f"{run_dir}: no episodes.parquet, cells.parquet or counterexamples.parquet to export "
                       "(is this a finished mcverify run folder?)")
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, path in present:
        table = _flat(pq.read_table(path))
        target = out_dir / f"{name}.csv"
        atomic_write(target, lambda tmp, t=table: pacsv.write_csv(t, tmp))
        written.append(target)
    return written
