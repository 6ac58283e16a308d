"""Run folders: manifest, chunk files written atomically, the chunk ledger, the merged episode table.

A run folder holds::

    manifest.json      the resolved campaign, every model parameter, the code version, package
                       versions, git commit, seed, kernel hashes, the chunk plan and the sessions
                       that worked on the run; ``finished_utc`` once the report is written
    chunks/*.parquet   one file per finished chunk, written to a temporary name then renamed, so
                       a file that exists under its final name is complete
    chunks.jsonl       the chunk ledger (named by the manifest): one JSON line per finished chunk
                       with its episode range, row and error counts, attempts and the SHA-256 of
                       its file, appended after the file is renamed into place
    trajectories/      full-resolution trajectories of recorded episodes (written before the
                       chunk's ledger line)
    episodes.parquet   all episode rows, sorted by (cell_index, episode_id)
    summary.json, report.md

A chunk counts as done only when its ledger line exists *and* its file still hashes to the recorded
SHA-256 *and* reads back with exactly the chunk's episode ids; anything else (a kill between the
rename and the ledger line, a truncated or edited file, a torn last ledger line) is redone. Nothing
is fsync'ed: a process kill cannot lose data that the kernel already holds, and what a power loss
could tear is caught by the same checks.

Nothing here depends on how many workers produced the chunks.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from mcverify import schema
from mcverify.errors import RunError
from mcverify.files import FILE_MODE, atomic_parquet, ends_with_newline, named, sha256_file
from mcverify.provenance import now_utc
from mcverify.schema import ERROR_COLUMN, ERROR_OUTCOME

MANIFEST = "manifest.json"
EPISODES = "episodes.parquet"
CHUNK_DIR = "chunks"
LEDGER = "chunks.jsonl"
TRAJECTORY_DIR = "trajectories"
LOCK = ".lock"
#: Verdicts of the reference solver on stored episodes (``mcverify replay --backend ipopt``,
#: ``mcverify report --audit``): episode id -> the audit (:mod:`mcverify.campaign.audit`).
AUDITS = "audits.json"
#: Version of the run-folder layout; a resume refuses another one.
FORMAT = 2


# ------------------------------------------------------------------------------------ chunks


@dataclass(frozen=True)
class Chunk:
    """A slice of one cell's episodes (cell-local ids, ascending), run as one vmapped batch."""

    cell_index: int
    episode_ids: tuple[int, ...]

    @property
    def name(self) -> str:
        return f"cell{self.cell_index:03d}_ep{self.episode_ids[0]:06d}-{self.episode_ids[-1]:06d}"


def plan_chunks(episodes_per_cell: Sequence[int], chunk_size: int) -> list[Chunk]:
    """Every episode of every cell exactly once, in (cell, episode) order, ``chunk_size`` at most per chunk."""
    if chunk_size < 1:
        raise ValueError(f"chunk size must be >= 1, got {chunk_size}")
    chunks = []
    for cell_index, n in enumerate(episodes_per_cell):
        for start in range(0, n, chunk_size):
            chunks.append(Chunk(cell_index, tuple(range(start, min(n, start + chunk_size)))))
    return chunks


@dataclass(frozen=True)
class ChunkRecord:
    """One ledger line: a chunk whose file is in place.

    rows: episode rows in the file; errors: rows with ``outcome == "error"``; attempts: runs of
    the chunk (or of its episodes one by one, after a failure) this session needed; sha256: of the
    chunk file's bytes.
    """

    chunk: str
    cell_index: int
    first_episode: int
    last_episode: int
    rows: int
    errors: int
    attempts: int
    sha256: str
    finished_utc: str


def chunk_path(run_dir: Path, chunk: Chunk) -> Path:
    return Path(run_dir) / CHUNK_DIR / f"{chunk.name}.parquet"


def write_chunk(run_dir: Path, chunk: Chunk, rows: list[dict], *, attempts: int = 1) -> ChunkRecord:
    """Write one finished chunk atomically (temporary file, then rename); returns its ledger record.

    The rows must be exactly the chunk's episodes (checked: a wrong set would be lost or repeated).
    """
    ids = sorted(int(r["cell_episode"]) for r in rows)
    if ids != list(chunk.episode_ids):
        raise ValueError(f"chunk {chunk.name}: rows hold episodes {ids}, expected {list(chunk.episode_ids)}")
    table = _table_from_rows(rows)
    path = chunk_path(run_dir, chunk)
    path.parent.mkdir(parents=True, exist_ok=True)
    digest = atomic_parquet(table, path)
    return ChunkRecord(
        chunk=chunk.name,
        cell_index=chunk.cell_index,
        first_episode=chunk.episode_ids[0],
        last_episode=chunk.episode_ids[-1],
        rows=table.num_rows,
        errors=sum(r.get("outcome") == ERROR_OUTCOME for r in rows),
        attempts=attempts,
        sha256=digest,
        finished_utc=now_utc(),
    )


def read_chunk(run_dir: Path, chunk: Chunk, columns: list[str] | None = None) -> pa.Table | None:
    """The chunk's rows (all columns, or ``columns``), or None if the file is missing, unreadable
    or holds other episodes than the chunk's."""
    path = chunk_path(run_dir, chunk)
    if not path.exists():
        return None
    try:
        # ParquetFile, single-threaded: a third of read_table's cost on small files (1,250 per 10k episodes)
        table = pq.ParquetFile(path).read(columns=columns, use_threads=False)
        ids = table.column("cell_episode").to_pylist()
        cells = set(table.column("cell_index").to_pylist())
    except Exception:  # noqa: BLE001 - any corruption (or missing id column) means: redo the chunk
        return None
    if sorted(ids) != list(chunk.episode_ids) or cells != {chunk.cell_index}:
        return None
    return table


def verify_chunk(run_dir: Path, chunk: Chunk, record: ChunkRecord | None) -> bool:
    """Whether ``chunk`` is done: recorded, its file hashes to the record, and it reads back right."""
    if record is None or record.chunk != chunk.name:
        return False
    path = chunk_path(run_dir, chunk)
    try:
        digest = sha256_file(path)
    except OSError:
        return False
    return digest == record.sha256 and read_chunk(run_dir, chunk, ["cell_index", "cell_episode"]) is not None


# ------------------------------------------------------------------------------------ ledger


def append_record(run_dir: Path, record: ChunkRecord) -> None:
    """Append one ledger line (one ``write`` of a complete line; a torn one is ignored on reading)."""
    path = Path(run_dir) / LEDGER
    line = (json.dumps(asdict(record), sort_keys=True) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        if os.fstat(fd).st_size and not ends_with_newline(path):
            line = b"\n" + line  # a torn last line from a killed writer stays a line of its own
        os.write(fd, line)
    finally:
        os.close(fd)


def read_ledger(run_dir: Path) -> dict[str, ChunkRecord]:
    """Chunk name -> its latest ledger record; unparsable (torn) lines are skipped."""
    path = Path(run_dir) / LEDGER
    records: dict[str, ChunkRecord] = {}
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except FileNotFoundError:
        return records
    for line in text.splitlines():
        try:
            rec = ChunkRecord(**json.loads(line))
        except (ValueError, TypeError):
            continue
        records[rec.chunk] = rec
    return records


def done_chunks(run_dir: Path, chunks: Iterable[Chunk]) -> set[str]:
    """Names of the planned chunks that are done (see :func:`verify_chunk`)."""
    ledger = read_ledger(run_dir)
    return {c.name for c in chunks if verify_chunk(run_dir, c, ledger.get(c.name))}


# ------------------------------------------------------------------------------------- merge


#: Rows per row group of ``episodes.parquet``: fixed, so the file's layout does not depend on the
#: chunk size, and bounded, so merging holds at most this many rows in memory.
ROW_GROUP_ROWS = 1024


def merge_chunks(run_dir: Path, chunks: Sequence[Chunk], overrides: Mapping[int, Mapping[str, Any]] | None = None,
                 ) -> int:
    """Stream every chunk, in plan order, into ``episodes.parquet`` (atomically); returns the row count.

    Chunks are planned in (cell, episode) order and each file is sorted here, so the merged table
    is sorted by (cell_index, episode_id) while at most :data:`ROW_GROUP_ROWS` rows (plus one
    chunk) are held in memory. The file's schema is the declared one (:mod:`mcverify.schema`),
    narrowed to the columns the chunks have (a run of error rows only has no metrics), with the
    grid values (:data:`mcverify.schema.GRID_FAMILY`) after ``seed``: ``overrides`` maps each cell
    index to its manifest overrides (``"<section>.<field>" -> value``); None adds none.
    """
    run_dir = Path(run_dir)
    names: set[str] = set()
    for chunk in chunks:
        try:
            names.update(pq.ParquetFile(chunk_path(run_dir, chunk)).schema_arrow.names)
        except Exception:  # noqa: BLE001 - missing or corrupt: the user must resume
            raise _missing(run_dir, chunk) from None
    if not names:
        raise RunError(f"{run_dir}: the run has no chunks")
    row_schema = _declared_schema(names, f"{run_dir}: a chunk")
    grid = schema.grid_columns(list(overrides.values())) if overrides else {}
    table_schema = _with_grid_fields(row_schema, grid)
    fd, tmp = tempfile.mkstemp(dir=run_dir, prefix=f".{EPISODES}.", suffix=".tmp")
    os.close(fd)
    rows = 0
    try:
        os.chmod(tmp, FILE_MODE)
        with pq.ParquetWriter(tmp, table_schema) as writer:
            pending: list[pa.Table] = []
            held = 0
            for chunk in chunks:
                table = read_chunk(run_dir, chunk)
                if table is None:
                    raise _missing(run_dir, chunk)
                rows_of_chunk = _conform(table.sort_by([("episode_id", "ascending")]), row_schema)
                pending.append(_add_grid_values(rows_of_chunk, grid, overrides or {}, table_schema))
                held += table.num_rows
                rows += table.num_rows
                if len(pending) >= 64:  # many small tables cost far more than their rows: compact
                    pending = [pa.concat_tables(pending).combine_chunks()]
                while held >= ROW_GROUP_ROWS:
                    combined = pa.concat_tables(pending)
                    writer.write_table(combined.slice(0, ROW_GROUP_ROWS))
                    pending, held = [combined.slice(ROW_GROUP_ROWS)], held - ROW_GROUP_ROWS
            if held:
                writer.write_table(pa.concat_tables(pending))
        os.replace(tmp, run_dir / EPISODES)
    except OSError as err:
        if err.filename is None:  # pyarrow says "No space left on device" without naming the file
            raise named(err, run_dir / EPISODES) from err
        raise
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return rows


def _with_grid_fields(row_schema: pa.Schema, grid: Mapping[str, pa.DataType]) -> pa.Schema:
    """``row_schema`` with the grid-value columns inserted after ``seed`` (at the end without it)."""
    at = row_schema.get_field_index("seed") + 1 if "seed" in row_schema.names else len(row_schema)
    fields = list(row_schema)
    return pa.schema(fields[:at] + [pa.field(name, typ) for name, typ in grid.items()] + fields[at:])


def _add_grid_values(table: pa.Table, grid: Mapping[str, pa.DataType], overrides: Mapping[int, Mapping[str, Any]],
                     target: pa.Schema) -> pa.Table:
    """``table`` with each row's grid values, looked up by its ``cell_index``, in ``target``'s order."""
    if not grid:
        return table
    cells = table.column("cell_index").to_pylist()
    added = {name: pa.array([schema.grid_value(overrides.get(c, {}).get(name), typ) for c in cells], type=typ)
             for name, typ in grid.items()}
    return pa.Table.from_arrays([added[f.name] if f.name in added else table.column(f.name) for f in target],
                                schema=target)


def _missing(run_dir: Path, chunk: Chunk) -> RunError:
    return RunError(f"{run_dir}: chunk {chunk.name} is missing or corrupt; run `mcverify run --resume {run_dir}`")


def read_episodes(run_dir: Path) -> pa.Table:
    path = Path(run_dir) / EPISODES
    if not path.exists():
        raise RunError(f"{run_dir}: no {EPISODES}; {_not_a_run(Path(run_dir))}")
    return pq.read_table(path)


def _not_a_run(folder: Path) -> str:
    """Why a folder without episodes.parquet has none, for the folders mcverify writes that are not runs."""
    if (folder / "estimate.json").is_file():
        try:
            method = read_json(folder / "estimate.json").get("spec", {}).get("method", "?")
        except (OSError, ValueError):
            method = "?"
        if method in ("importance", "splitting"):
            what = ("each cell's final draws (samples_cellNNN.parquet)" if method == "importance"
                    else "each cell's failing particles (estimate.json)")
            return (f"it is an `estimate --method {method}` folder, which stores its estimate (estimate.json, "
                    f"report.md) and {what}, not episodes; `mcverify replay {folder} K [--cell NAME]` replays "
                    f"one, `mcverify report {folder}` rebuilds its report; compare and export work on run folders "
                    "and on `estimate --method mc` folders")
        return (f"it is an `estimate --method {method}` folder, which stores its estimate (estimate.json, "
                "report.md), not episodes; replay, compare and export work on run folders and on "
                "`estimate --method mc` folders")
    if (folder / "falsify.json").is_file() and (folder / "beam").is_dir():
        return (f"it is a beam search, whose best episode is its run folder best/ (`mcverify replay {folder}/best 0`); "
                f"`mcverify report {folder}` rebuilds its report")
    if (folder / "falsify.json").is_file():
        return (f"it is a falsification search, whose episodes are in its generation folders (e.g. "
                f"`mcverify replay {folder}/generations/g000 0`); `mcverify report {folder}` rebuilds its report")
    return "is this a finished mcverify run folder?"


def _declared_schema(names: Iterable[str], where: str) -> pa.Schema:
    """The declared schema of the columns ``names`` (file order, declared types), ``error_message``
    always included; an undeclared column is refused (:class:`ValueError`, naming it)."""
    undeclared = sorted(set(names) - set(schema.COLUMN_NAMES))
    if undeclared:
        raise ValueError(
            f"{where} has columns that mcverify.schema does not declare: {', '.join(undeclared)}"
        )
    return schema.arrow_schema({*names, ERROR_COLUMN})


def _conform(table: pa.Table, target: pa.Schema) -> pa.Table:
    """``table`` with the columns and types of ``target`` (missing ones null)."""
    if table.schema.equals(target):
        return table
    columns = []
    for f in target:
        if f.name in table.column_names:
            columns.append(table.column(f.name).cast(f.type))
        else:
            columns.append(pa.nulls(table.num_rows, f.type))
    return pa.Table.from_arrays(columns, schema=target)


def _table_from_rows(rows: list[dict]) -> pa.Table:
    """Rows -> table of the declared columns the rows have (any row: an error row has fewer), in
    file order and with the declared types; ``error_message`` always (null for simulated episodes)."""
    names: set[str] = set()
    for row in rows:
        names.update(row)
    target = _declared_schema(names, "an episode row")
    return pa.table({f.name: pa.array([row.get(f.name) for row in rows], type=f.type) for f in target},
                    schema=target)


# ------------------------------------------------------------------------------ trajectories


def trajectory_path(run_dir: Path, episode_id: int, suffix: str = "") -> Path:
    """Where a run keeps episode ``episode_id``'s recorded trajectory (``suffix``: its other tables)."""
    return Path(run_dir) / TRAJECTORY_DIR / f"episode-{episode_id:06d}{suffix}.parquet"


def write_trajectory(run_dir: Path, episode_id: int, columns: Mapping[str, Any], *, suffix: str = "") -> Path:
    """Write one episode's trajectory (column name -> 1-D array of equal lengths, e.g. one row per
    sub-step) atomically to ``trajectories/episode-NNNNNN<suffix>.parquet``."""
    path = trajectory_path(run_dir, episode_id, suffix)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_parquet(pa.table(dict(columns)), path)
    return path


def read_trajectory(run_dir: Path, episode_id: int) -> dict[str, Any] | None:
    """Episode ``episode_id``'s stored trajectory (column name -> numpy array), None if not stored."""
    path = trajectory_path(run_dir, episode_id)
    if not path.is_file():
        return None
    table = pq.read_table(path)
    return {name: table.column(name).to_numpy() for name in table.column_names}


# ---------------------------------------------------------------------------------- manifest


def read_json(path: Path) -> Any:
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        if path.name == MANIFEST:
            if not path.parent.exists():
                raise RunError(f"run folder not found: {path.parent}") from None
            why = (f"; {_not_a_run(path.parent)}" if (path.parent / "falsify.json").is_file() else "")
            raise RunError(f"{path.parent}: not an mcverify run folder (no {MANIFEST}){why}") from None
        raise RunError(f"missing file: {path}") from None
    except NotADirectoryError:
        raise RunError(f"not a run folder: {path.parent}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise RunError(f"{path}: not valid JSON ({err})") from None
    except OSError as err:
        raise RunError(f"cannot read {path}: {err.strerror or err}") from None


def read_manifest(run_dir: Path) -> dict[str, Any]:
    """The run folder's manifest, checked to be one this code can resume or report on."""
    run_dir = Path(run_dir)
    if not run_dir.exists():
        raise RunError(f"run folder not found: {run_dir}")
    if not run_dir.is_dir():
        raise RunError(f"not a run folder (a file): {run_dir}")
    manifest = read_json(run_dir / MANIFEST)
    if not isinstance(manifest, dict) or "campaign" not in manifest or "cells" not in manifest:
        raise RunError(f"{run_dir / MANIFEST}: not an mcverify manifest")
    return manifest


@contextlib.contextmanager
def run_lock(run_dir: Path) -> Iterator[None]:
    """Hold the run folder for this process: a second ``run``/``--resume`` on it is refused.

    An ``flock`` dies with its process, so a ``kill -9`` never leaves a stale lock behind.
    """
    path = Path(run_dir) / LOCK
    fh = open(path, "a+")  # noqa: SIM115 - held for the context's lifetime
    try:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "?"
            raise RunError(f"{run_dir} is being run by another mcverify process (pid {holder})") from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"{os.getpid()}\n")
        fh.flush()
        yield
    finally:
        fh.close()

