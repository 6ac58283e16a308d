"""Run folders: chunk plans, atomic chunk files, corruption detection, merging."""

from pathlib import Path

import pytest

from mcverify import store


def rows(cell_index, ids):
    return [
        {"episode_id": 100 * cell_index + i, "cell_episode": i, "cell_index": cell_index, "x": float(i)} for i in ids
    ]


def test_plan_covers_every_episode_once():
    chunks = store.plan_chunks([5, 3], chunk_size=2)
    seen = [(c.cell_index, e) for c in chunks for e in c.episode_ids]
    assert seen == [(0, i) for i in range(5)] + [(1, i) for i in range(3)]
    assert len({c.name for c in chunks}) == len(chunks)
    with pytest.raises(ValueError):
        store.plan_chunks([1], 0)


def test_chunk_roundtrip_and_corruption_is_detected(tmp_path: Path):
    chunk = store.plan_chunks([3], 3)[0]
    assert store.read_chunk(tmp_path, chunk) is None
    store.write_chunk(tmp_path, chunk, rows(0, chunk.episode_ids))
    assert store.read_chunk(tmp_path, chunk).num_rows == 3
    assert not list((tmp_path / store.CHUNK_DIR).glob(".*.tmp")), "no temporary file is left behind"
    path = tmp_path / store.CHUNK_DIR / f"{chunk.name}.parquet"
    path.write_bytes(path.read_bytes()[:40])  # truncated
    assert store.read_chunk(tmp_path, chunk) is None
    path.write_bytes(b"")
    assert store.read_chunk(tmp_path, chunk) is None


def test_chunk_with_wrong_episodes_is_redone(tmp_path: Path):
    chunk = store.plan_chunks([3], 3)[0]
    store.write_chunk(tmp_path, chunk, rows(0, [0, 1]))
    assert store.read_chunk(tmp_path, chunk) is None


def test_merge_sorts_by_cell_then_episode(tmp_path: Path):
    chunks = store.plan_chunks([3, 2], 2)
    for c in reversed(chunks):
        store.write_chunk(tmp_path, c, rows(c.cell_index, reversed(c.episode_ids)))
    merged = store.merge_chunks(tmp_path, chunks)
    assert merged.column("episode_id").to_pylist() == [0, 1, 2, 100, 101]
    assert store.read_episodes(tmp_path).num_rows == 5


def test_missing_run_folder_message(tmp_path: Path):
    with pytest.raises(store.RunError, match="no episodes.parquet"):
        store.read_episodes(tmp_path)
    with pytest.raises(store.RunError, match="missing file"):
        store.read_json(tmp_path / "manifest.json")
