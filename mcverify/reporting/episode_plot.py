"""The one-episode figure ``mcverify replay`` writes (drawing code: :mod:`mcverify.reporting.episode_figures`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from mcverify.cell import Cell
from mcverify.reporting import episode_figures


def episode_figure(
    traj: Mapping[str, np.ndarray],
    cell: Cell,
    row: Mapping[str, Any],
    path: Path,
) -> Path:
    """Road view with snapshots and the safety ellipse, h_ef(t) against ε, and speeds, for one
    episode (``traj``: sub-step columns as in ``trajectories/episode-NNNNNN.parquet``; ``row``:
    its ``episodes.parquet`` row). Columns the trajectory lacks are left out of the drawing; the
    road snapshots with the Q1/Q2 plans are :func:`mcverify.reporting.episode_figures.snapshots`."""
    dist = row.get("min_dist_front_m", math.nan)
    h = row.get("min_h_front", math.nan)
    title = (
        f"{cell.name} · episode {row.get('episode_id')} · {row.get('outcome')} · safe={row.get('safe')} · "
        f"min dist. to ellipse {dist:.2f} m · min h {h:.3f}"
    )
    episode_figures.episode_overview(traj, cell.params, cell.epsilon, Path(path), title=title)
    return Path(path)
