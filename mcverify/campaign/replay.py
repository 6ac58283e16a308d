"""Replay one stored episode: re-simulate it alone, check its metrics, write its trajectory and a plot."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mcverify import store
from mcverify.campaign import executors
from mcverify.campaign.runner import campaign_from_manifest
from mcverify.episode import schedule_file
from mcverify.episode.recording import PLANS_SUFFIX
from mcverify.episode.rollout import run_episodes
from mcverify.errors import RunError
from mcverify.schema import ERROR_COLUMN, ERROR_OUTCOME, TIMING_COLUMNS
from mcverify.sim.schedule import ErrorInput


class ReplayMismatch(RuntimeError):
    """The re-simulated episode's metrics differ from the stored row."""


@dataclass(frozen=True)
class ReplayResult:
    episode_id: int
    trajectory_path: Path
    plot_path: Path
    row: dict
    #: Columns the replay produced that the stored run has not (it was made by an older version).
    not_stored: tuple[str, ...] = ()


def replay(run_dir: Path, episode_id: int, out_dir: Path | None = None) -> ReplayResult:
    """Re-simulate one stored episode with this code and check it against the stored row
    (:class:`ReplayMismatch` when a metric differs); its trajectory and plot go to ``out_dir``
    (default ``RUN_DIR/replay``)."""
    run_dir = Path(run_dir)
    stored, cell, result = resimulate(run_dir, episode_id)
    row = result.rows[0]
    out_dir = Path(out_dir) if out_dir else run_dir / "replay"
    recording = result.recordings[stored["cell_episode"]]
    traj_path, plot_path = write_recording(recording, cell, row, out_dir, f"episode-{episode_id:06d}")
    return checked(episode_id, stored, row, traj_path, plot_path)


def resimulate(run_dir: Path, episode_id: int, record: bool = True):
    """(stored row, cell, :class:`~mcverify.episode.rollout.ChunkResult`) of one stored episode
    re-simulated with this code, nothing compared (the replay's and a re-measurement's common part)."""
    run_dir = Path(run_dir)
    manifest = store.read_json(run_dir / store.MANIFEST)
    campaign = campaign_from_manifest(manifest)  # first: a folder this code cannot rebuild says so at once
    table = store.read_episodes(run_dir)
    ids = table.column("episode_id").to_pylist()
    if episode_id not in ids:
        raise RunError(
            f"{run_dir}: no episode {episode_id}; episode ids run from {min(ids)} to {max(ids)}"
        )
    stored = table.slice(ids.index(episode_id), 1).to_pylist()[0]
    cell = campaign.cells[stored["cell_index"]]
    local = stored["cell_episode"]
    schedules = stored_schedules(run_dir, manifest, episode_id)
    try:
        result = run_episodes(
            cell,
            [local],
            campaign.seed,
            executors.solver_for(cell.params),
            common_random_numbers=campaign.common_random_numbers,
            record=record,
            schedules=schedules,
        )
    except Exception as exc:  # noqa: BLE001 - the stored error row says what to expect
        if stored.get("outcome") != ERROR_OUTCOME:
            raise
        raise RunError(
            f"{run_dir}: episode {episode_id} ended in an error in the run "
            f"({stored.get(ERROR_COLUMN)}); the replay fails again: {type(exc).__name__}: {exc}"
        ) from exc
    return stored, cell, result


def stored_schedules(run_dir: Path, manifest: dict, episode_id: int) -> list[ErrorInput] | None:
    """[the episode's error schedule] when its run kept error schedules (manifest ``error_schedules``), else
    None (the episode drew its noise)."""
    folder = manifest.get(schedule_file.MANIFEST_KEY)
    if not folder:
        return None
    return [schedule_file.read_schedule(schedule_file.schedule_path(Path(run_dir) / folder, episode_id))]


def write_recording(recording, cell, row: dict, out_dir: Path, stem: str) -> tuple[Path, Path]:
    """Write a replayed episode's trajectory (``STEM.parquet``, plans in ``STEM_plans.parquet`` when it
    has any) and its plot (``STEM.png``) into ``out_dir``; (trajectory path, plot path)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    traj = recording.trajectory
    traj_path = out_dir / f"{stem}.parquet"
    pq.write_table(pa.table(dict(traj)), traj_path)
    if recording.plans:  # unlike a run folder, no empty plans file
        pq.write_table(pa.table(dict(recording.plans)), out_dir / f"{stem}{PLANS_SUFFIX}.parquet")
    plot_path = out_dir / f"{stem}.png"
    from mcverify.reporting import episode_plot

    episode_plot.episode_figure(traj, cell, row, plot_path, plans=recording.plans or None)
    return traj_path, plot_path


def checked(episode_id: int, stored: dict, row: dict, traj_path: Path, plot_path: Path) -> ReplayResult:
    """The replay's result, or :class:`ReplayMismatch` when a stored value differs from the replayed."""
    diffs = compare_rows(stored, row)
    if diffs:
        detail = "; ".join(f"{k}: stored {a!r} vs replayed {b!r}" for k, (a, b) in diffs.items())
        raise ReplayMismatch(f"episode {episode_id} does not reproduce: {detail}")
    not_stored = tuple(k for k in row if k not in stored and k not in TIMING_COLUMNS)
    return ReplayResult(episode_id, traj_path, plot_path, row, not_stored)


def compare_rows(stored: dict, replayed: dict) -> dict[str, tuple]:
    """Columns whose values differ (bit for bit; NaN equals NaN); timing columns are skipped, and so
    are columns the stored run does not have (added to the schema after it was made)."""
    diffs = {}
    for key, value in replayed.items():
        if key in TIMING_COLUMNS or key not in stored:
            continue
        old = stored.get(key)
        if not _same(old, value):
            diffs[key] = (old, value)
    return diffs


def _same(a, b) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        if a is None or b is None:
            return False
        fa, fb = float(a), float(b)
        return (math.isnan(fa) and math.isnan(fb)) or np.float64(fa).tobytes() == np.float64(fb).tobytes()
    return a == b
