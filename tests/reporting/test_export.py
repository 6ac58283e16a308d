"""mcverify.reporting.export: a run folder's tables as CSV, the same rows and columns as the parquet files."""

import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
import synthetic

from mcverify.errors import RunError
from mcverify.reporting import export


def test_csv_holds_the_parquet_rows_and_columns(tmp_path):
    run = synthetic.make_run(tmp_path / "run", synthetic.TABLE3, trajectories=False)
    written = export.export_csv(run, tmp_path / "csv")
    assert [p.name for p in written] == ["episodes.csv"]  # a synthetic folder has no cells.parquet yet
    stored = pq.read_table(run / "episodes.parquet")
    back = pacsv.read_csv(written[0])
    assert back.column_names == stored.column_names and back.num_rows == stored.num_rows
    for name in ("episode_id", "safe", "min_dist_front_m", "outcome"):
        assert back.column(name).to_pylist() == stored.column(name).to_pylist()


def test_nested_columns_become_json_text(tmp_path):
    table = pa.table({"episode_id": [0, 1], "steps": [[1, 2], None]})
    pq.write_table(table, tmp_path / "episodes.parquet")
    (path,) = export.export_csv(tmp_path)
    assert path == tmp_path / "episodes.csv"
    assert pacsv.read_csv(path).column("steps").to_pylist() == ["[1, 2]", ""]  # CSV writes a null as empty


def test_a_folder_without_tables_is_one_clear_error(tmp_path):
    with pytest.raises(RunError, match="no episodes.parquet, cells.parquet or counterexamples.parquet"):
        export.export_csv(tmp_path)


def test_the_command_writes_the_files_and_refuses_a_wrong_folder_in_one_line(tmp_path, capsys):
    from mcverify import cli

    run = synthetic.make_run(tmp_path / "run", synthetic.TABLE3, trajectories=False)
    assert cli.main(["export", str(run), "--csv", "--out", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "episodes.csv").is_file() and "written:" in capsys.readouterr().out
    assert cli.main(["export", str(tmp_path / "nothing"), "--csv"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mcverify: error:")
