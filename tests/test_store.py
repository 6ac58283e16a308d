"""Run folders: chunk plans, atomic chunk files, the ledger, corruption detection, streaming merge."""

import json
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mcverify import files, schema, store
from mcverify.errors import RunError


def rows(cell_index, ids, **extra):
    return [
        {"episode_id": 100 * cell_index + i, "cell_episode": i, "cell_index": cell_index, "min_h_front": float(i),
         **extra}
        for i in ids
    ]


def test_plan_covers_every_episode_once():
    chunks = store.plan_chunks([5, 3], chunk_size=2)
    seen = [(c.cell_index, e) for c in chunks for e in c.episode_ids]
    assert seen == [(0, i) for i in range(5)] + [(1, i) for i in range(3)]
    assert len({c.name for c in chunks}) == len(chunks)
    with pytest.raises(ValueError):
        store.plan_chunks([1], 0)


def test_chunk_roundtrip_record_and_corruption_is_detected(tmp_path: Path):
    chunk = store.plan_chunks([3], 3)[0]
    assert store.read_chunk(tmp_path, chunk) is None
    record = store.write_chunk(tmp_path, chunk, rows(0, chunk.episode_ids))
    assert (record.rows, record.errors, record.first_episode, record.last_episode) == (3, 0, 0, 2)
    assert store.read_chunk(tmp_path, chunk).num_rows == 3
    assert store.verify_chunk(tmp_path, chunk, record)
    assert not store.verify_chunk(tmp_path, chunk, None), "a file without a ledger record is redone"
    assert not list((tmp_path / store.CHUNK_DIR).glob(".*.tmp")), "no temporary file is left behind"
    path = store.chunk_path(tmp_path, chunk)
    path.write_bytes(path.read_bytes()[:-40])  # truncated
    assert store.read_chunk(tmp_path, chunk) is None
    assert not store.verify_chunk(tmp_path, chunk, record)
    path.write_bytes(b"")
    assert store.read_chunk(tmp_path, chunk) is None


def test_chunk_file_with_other_episodes_is_not_done(tmp_path: Path):
    a, b = store.plan_chunks([4], 2)
    rec_a = store.write_chunk(tmp_path, a, rows(0, a.episode_ids))
    store.write_chunk(tmp_path, b, rows(0, b.episode_ids))
    store.chunk_path(tmp_path, a).write_bytes(store.chunk_path(tmp_path, b).read_bytes())
    assert store.read_chunk(tmp_path, a) is None
    assert not store.verify_chunk(tmp_path, a, rec_a)
    # Even a ledger record that matches the file's bytes does not make wrong episodes right.
    forged = store.ChunkRecord(**{**rec_a.__dict__, "sha256": files.sha256_file(store.chunk_path(tmp_path, a))})
    assert not store.verify_chunk(tmp_path, a, forged)


def test_write_chunk_refuses_rows_that_are_not_the_chunk(tmp_path: Path):
    chunk = store.plan_chunks([3], 3)[0]
    with pytest.raises(ValueError, match="expected"):
        store.write_chunk(tmp_path, chunk, rows(0, [0, 1]))
    with pytest.raises(ValueError, match="expected"):
        store.write_chunk(tmp_path, chunk, rows(0, [0, 1, 1]))


def test_ledger_latest_record_wins_and_torn_lines_are_ignored(tmp_path: Path):
    a, b, c = store.plan_chunks([3], 1)
    ra = store.write_chunk(tmp_path, a, rows(0, a.episode_ids))
    store.append_record(tmp_path, ra)
    # A writer killed mid-line leaves a torn last line ...
    with open(tmp_path / store.LEDGER, "ab") as fh:
        fh.write(b'{"chunk": "cell000_ep0000')
    rb = store.write_chunk(tmp_path, b, rows(0, b.episode_ids))
    store.append_record(tmp_path, rb)  # ... which must not swallow the next record
    ra2 = store.write_chunk(tmp_path, a, rows(0, a.episode_ids), attempts=2)
    store.append_record(tmp_path, ra2)
    ledger = store.read_ledger(tmp_path)
    assert set(ledger) == {a.name, b.name}
    assert ledger[a.name].attempts == 2
    assert store.done_chunks(tmp_path, [a, b, c]) == {a.name, b.name}


def test_merge_streams_sorted_rows_and_unifies_error_chunks(tmp_path: Path):
    chunks = store.plan_chunks([3, 2], 2)
    # The first chunk holds only an error row: fewer columns, nulls where others have numbers.
    error_row = {"episode_id": 0, "cell_episode": 0, "cell_index": 0, "outcome": "error",
                 schema.ERROR_COLUMN: "RuntimeError: boom"}
    store.write_chunk(tmp_path, chunks[0], [rows(0, [1], outcome="ok")[0], error_row])
    for c in chunks[1:]:
        store.write_chunk(tmp_path, c, rows(c.cell_index, reversed(c.episode_ids), outcome="ok"))
    assert store.merge_chunks(tmp_path, chunks) == 5
    merged = store.read_episodes(tmp_path)
    assert merged.column("episode_id").to_pylist() == [0, 1, 2, 100, 101]
    # the declared order and types, whichever chunk comes first
    assert merged.column_names == ["episode_id", "cell_episode", "cell_index", "outcome", "min_h_front",
                                   schema.ERROR_COLUMN]
    assert merged.schema.equals(schema.arrow_schema(merged.column_names))
    assert merged.column("min_h_front").to_pylist()[:2] == [None, 1.0]
    assert merged.column(schema.ERROR_COLUMN).to_pylist() == ["RuntimeError: boom", None, None, None, None]
    assert merged.schema.field(schema.ERROR_COLUMN).type == pa.string()


def test_chunks_have_the_declared_types_and_refuse_undeclared_columns(tmp_path: Path):
    chunk = store.plan_chunks([2], 2)[0]
    # an int where the schema declares a double is stored as a double
    store.write_chunk(tmp_path, chunk, [{**r, "min_h_front": 1} for r in rows(0, [0, 1])])
    assert store.read_chunk(tmp_path, chunk).schema.field("min_h_front").type == pa.float64()
    with pytest.raises(ValueError, match="does not declare: x_m"):
        store.write_chunk(tmp_path, chunk, rows(0, [0, 1], x_m=1.0))


def test_merge_of_a_clean_run_has_a_typed_error_column(tmp_path: Path):
    chunks = store.plan_chunks([2], 2)
    store.write_chunk(tmp_path, chunks[0], rows(0, [0, 1]))
    store.merge_chunks(tmp_path, chunks)
    table = pq.read_table(tmp_path / store.EPISODES)
    assert table.schema.field(schema.ERROR_COLUMN).type == pa.string()
    assert table.column(schema.ERROR_COLUMN).null_count == 2


def test_merge_names_a_missing_chunk(tmp_path: Path):
    chunks = store.plan_chunks([4], 2)
    store.write_chunk(tmp_path, chunks[0], rows(0, [0, 1]))
    with pytest.raises(RunError, match=r"cell000_ep000002-000003 is missing.*--resume"):
        store.merge_chunks(tmp_path, chunks)
    assert not (tmp_path / store.EPISODES).exists()


def test_run_folder_messages(tmp_path: Path):
    with pytest.raises(RunError, match="no episodes.parquet"):
        store.read_episodes(tmp_path)
    with pytest.raises(RunError, match="run folder not found"):
        store.read_manifest(tmp_path / "nope")
    with pytest.raises(RunError, match=r"not an mcverify run folder \(no manifest.json\)"):
        store.read_manifest(tmp_path)
    (tmp_path / "file").write_text("x")
    with pytest.raises(RunError, match="not a run folder"):
        store.read_manifest(tmp_path / "file")
    (tmp_path / store.MANIFEST).write_text("{not json")
    with pytest.raises(RunError, match="not valid JSON"):
        store.read_manifest(tmp_path)
    (tmp_path / store.MANIFEST).write_text("[1, 2]")
    with pytest.raises(RunError, match="not an mcverify manifest"):
        store.read_manifest(tmp_path)


def test_run_lock_refuses_a_second_holder(tmp_path: Path):
    with store.run_lock(tmp_path):
        with pytest.raises(RunError, match=rf"being run by another mcverify process \(pid {os.getpid()}\)"):
            with store.run_lock(tmp_path):
                pass
    with store.run_lock(tmp_path):  # released on exit
        pass


def test_trajectory_and_json_are_written_atomically(tmp_path: Path):
    path = store.write_trajectory(tmp_path, 12, {"t_s": [0.0, 0.1], "x_m": [1.0, 2.0]})
    assert path.name == "episode-000012.parquet"
    assert pq.read_table(path).num_rows == 2
    files.write_json_atomic(tmp_path / "a.json", {"k": (1, 2)})
    assert json.loads((tmp_path / "a.json").read_text()) == {"k": [1, 2]}
    assert not [p for p in tmp_path.rglob("*.tmp")]


def test_replace_section_appends_then_replaces_keeping_the_rest(tmp_path):
    md = tmp_path / "BENCHMARKS.md"
    md.write_text("# Benchmarks\n\nhand-written row\n", encoding="utf-8")
    begin, end = "<!-- x:begin -->", "<!-- x:end -->"
    files.replace_section(md, f"{begin}\nfirst\n{end}\n", begin, end)
    files.replace_section(md, f"{begin}\nsecond\n{end}\n", begin, end)
    text = md.read_text(encoding="utf-8")
    assert text.count(begin) == 1 and "second" in text and "first" not in text
    assert text.startswith("# Benchmarks\n\nhand-written row\n")
