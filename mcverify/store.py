"""Run folders: manifest, atomically written chunk files, the merged episode table.

A run folder holds::

    manifest.json      the resolved campaign, every model parameter, versions, git commit, seed,
                       kernel hashes, and the chunk plan
    chunks/*.parquet   one file per finished chunk, written to a temporary name then renamed, so
                       a file that exists is complete
    episodes.parquet   all episode rows, sorted by (cell_index, episode_id)
    summary.json, report.md

Nothing here depends on how many workers produced the chunks.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

MANIFEST = "manifest.json"
EPISODES = "episodes.parquet"
CHUNK_DIR = "chunks"


class RunError(ValueError):
    """A run folder is missing or unusable; the message is one line for the user."""


@dataclass(frozen=True)
class Chunk:
    """A slice of one cell's episodes, run as one vmapped batch."""

    cell_index: int
    episode_ids: tuple[int, ...]

    @property
    def name(self) -> str:
        return f"cell{self.cell_index:03d}_ep{self.episode_ids[0]:06d}-{self.episode_ids[-1]:06d}"


def plan_chunks(episodes_per_cell: list[int], chunk_size: int) -> list[Chunk]:
    if chunk_size < 1:
        raise ValueError(f"chunk size must be >= 1, got {chunk_size}")
    chunks = []
    for cell_index, n in enumerate(episodes_per_cell):
        for start in range(0, n, chunk_size):
            chunks.append(Chunk(cell_index, tuple(range(start, min(n, start + chunk_size)))))
    return chunks


def write_json_atomic(path: Path, data: Any) -> None:
    _atomic_write(path, (json.dumps(data, indent=2, sort_keys=False, default=_json_default) + "\n").encode())


def read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise RunError(f"missing file: {path}") from None
    except json.JSONDecodeError as err:
        raise RunError(f"{path}: not valid JSON ({err})") from None


def write_chunk(run_dir: Path, chunk: Chunk, rows: list[dict]) -> Path:
    """Write one finished chunk atomically (temporary file, then rename)."""
    path = run_dir / CHUNK_DIR / f"{chunk.name}.parquet"
    path.parent.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pylist(rows)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{chunk.name}.", suffix=".tmp")
    os.close(fd)
    try:
        pq.write_table(table, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def read_chunk(run_dir: Path, chunk: Chunk) -> pa.Table | None:
    """The chunk's rows, or None if the file is missing or unreadable (then it is redone)."""
    path = run_dir / CHUNK_DIR / f"{chunk.name}.parquet"
    if not path.exists():
        return None
    try:
        table = pq.read_table(path)
    except Exception:  # noqa: BLE001 - any corruption means: redo the chunk
        return None
    ids = table.column("cell_episode").to_pylist() if "cell_episode" in table.column_names else []
    if sorted(ids) != list(chunk.episode_ids):
        return None
    return table


def merge_chunks(run_dir: Path, chunks: list[Chunk]) -> pa.Table:
    tables = []
    for chunk in chunks:
        table = read_chunk(run_dir, chunk)
        if table is None:
            raise RunError(f"{run_dir}: chunk {chunk.name} is missing or corrupt; run `mcverify run --resume`")
        tables.append(table)
    merged = pa.concat_tables(tables, promote_options="default")
    merged = merged.sort_by([("cell_index", "ascending"), ("episode_id", "ascending")])
    _atomic_parquet(merged, run_dir / EPISODES)
    return merged


def read_episodes(run_dir: Path) -> pa.Table:
    path = Path(run_dir) / EPISODES
    if not path.exists():
        raise RunError(f"{run_dir}: no {EPISODES}; is this a finished mcverify run folder?")
    return pq.read_table(path)


def environment_info() -> dict[str, Any]:
    versions = {}
    for pkg in ("mcverify", "jax", "jaxlib", "numpy", "scipy", "casadi", "pyarrow", "matplotlib"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    return {
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "packages": versions,
        "git_commit": git_commit(),
    }


def git_commit() -> str | None:
    root = Path(__file__).resolve().parent.parent
    try:
        out = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5
        )
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=5,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    if out.returncode != 0:
        return None
    return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def _atomic_parquet(table: pa.Table, path: Path) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        pq.write_table(table, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "item"):
        return obj.item()
    if isinstance(obj, tuple | set):
        return list(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
