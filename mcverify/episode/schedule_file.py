"""An episode's error schedule on disk: ``SCHEDULES/episode-NNNNNN.npz`` in a run folder, read by replay.

A run whose episodes ran with error schedules (:mod:`mcverify.sim.schedule`) says so in its manifest
(``error_schedules``: the folder, relative to the run) and keeps one file per episode, named by its
global episode id (column ``episode_id``). A file holds plain arrays (no pickle): ``format``, ``kind``
("time" or "gap_bands"), ``units``, ``front_share``, ``opp_share`` and, for the gap-band form,
``edges_m``. float64 round-trips exactly, so the stored input re-simulates the episode bit for bit.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from mcverify.errors import RunError
from mcverify.sim.schedule import ErrorInput, ErrorSchedule, GapBandSchedule

#: The manifest key naming a run's schedule folder, and its default name.
MANIFEST_KEY = "error_schedules"
SCHEDULES = "schedules"
FORMAT = 1


def schedule_path(folder: Path, episode_id: int) -> Path:
    """The file of global episode ``episode_id`` in a schedule folder."""
    return Path(folder) / f"episode-{int(episode_id):06d}.npz"


def write_schedule(path: Path, schedule: ErrorInput) -> Path:
    """Write ``schedule`` to ``path`` atomically (a temporary file renamed into place)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fields: dict[str, np.ndarray] = {
        "format": np.array(FORMAT), "units": np.asarray(schedule.units, dtype=np.float64),
        "front_share": np.array(float(schedule.front_share)), "opp_share": np.array(float(schedule.opp_share)),
    }
    if isinstance(schedule, GapBandSchedule):
        fields.update(kind=np.array("gap_bands"), edges_m=np.asarray(schedule.edges_m, dtype=np.float64))
    elif isinstance(schedule, ErrorSchedule):
        fields["kind"] = np.array("time")
    else:
        raise TypeError(f"not an error schedule: {type(schedule).__name__}")
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **fields)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def read_schedule(path: Path) -> ErrorInput:
    """The schedule stored at ``path``, validated; :class:`~mcverify.errors.RunError` (one line) for a
    missing, unreadable or invalid file."""
    path = Path(path)
    if not path.is_file():
        raise RunError(f"{path}: the episode's error schedule is missing; it cannot be re-simulated without it")
    try:
        with np.load(path, allow_pickle=False) as data:
            if int(data["format"]) != FORMAT:
                raise ValueError(f"format {int(data['format'])}, this mcverify reads {FORMAT}")
            kind, shares = str(data["kind"]), (float(data["front_share"]), float(data["opp_share"]))
            if kind == "time":
                return ErrorSchedule.of(data["units"], *shares)
            if kind == "gap_bands":
                return GapBandSchedule.of(data["units"], data["edges_m"], *shares)
            raise ValueError(f"unknown kind {kind!r}")
    except (KeyError, ValueError, TypeError, OSError, zipfile.BadZipFile) as err:
        raise RunError(f"{path}: not a readable error schedule ({type(err).__name__}: {err})") from None
