"""What every figure of a run shares: fixed pixel sizes, byte-stable PNGs, stored-data loading.

Figures are drawn with matplotlib on the Agg backend (files only). Every figure has a fixed size in
pixels (``figsize`` x :data:`DPI`, no tight bounding box) and is saved without the matplotlib
version in the PNG metadata, so the same data give the same bytes. Each drawing function returns
:func:`artist_counts` of what it drew (through :func:`save`), for tests and the report.

The figure families: :mod:`mcverify.reporting.cell_figures` (campaign level, from the summary) and
:mod:`mcverify.reporting.episode_figures` (one episode, from the stored trajectories).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402

from mcverify.model import ModelParams  # noqa: E402

#: Dots per inch of every figure: pixel size = figsize * DPI.
DPI = 100
#: PNG text chunks: none (matplotlib would write its version; Agg writes no date).
PNG_METADATA: dict[str, Any] = {"Software": None}
#: Most panels in a small-multiples figure (one per cell); more cells skip the figure.
MAX_PANELS = 48


# ----------------------------------------------------------------------------------------- data


def params_dict(params: Any = None) -> dict[str, dict[str, Any]]:
    """Model parameters as nested dicts (``section -> field -> value``), defaults filled in.

    ``params``: a :class:`ModelParams`, the ``params`` dict of a manifest cell, or None."""
    out = dataclasses.asdict(ModelParams())
    if params is None:
        return out
    given = dataclasses.asdict(params) if dataclasses.is_dataclass(params) else params
    for section, values in given.items():
        if isinstance(values, Mapping):
            out.setdefault(section, {}).update(values)
    return out


def load_table(path: Path) -> dict[str, np.ndarray] | None:
    """A parquet file as ``column -> numpy array`` (strings as object arrays), None if missing."""
    path = Path(path)
    if not path.is_file():
        return None
    t = pq.read_table(path)
    return {name: _np(t.column(name)) for name in t.column_names}


def _np(col: pa.ChunkedArray) -> np.ndarray:
    if pa.types.is_floating(col.type) or pa.types.is_integer(col.type):
        return np.asarray(col.to_numpy(), dtype=np.float64)
    if pa.types.is_boolean(col.type):
        return np.asarray(col.to_pylist(), dtype=bool)
    return np.asarray(col.to_pylist(), dtype=object)


def column(data: Mapping[str, np.ndarray] | None, name: str) -> np.ndarray | None:
    """A numeric column, or None when it is missing or holds no finite value."""
    if data is None or name not in data:
        return None
    x = np.asarray(data[name])
    if x.dtype == object:
        return None
    x = x.astype(np.float64)
    return x if np.isfinite(x).any() else None


# --------------------------------------------------------------------------------------- saving


def artist_counts(fig: plt.Figure) -> dict[str, int]:
    """How much was drawn: axes, lines, patches, collections, images and texts over all axes."""
    counts = {"axes": 0, "lines": 0, "patches": 0, "collections": 0, "images": 0, "texts": 0}
    for ax in fig.axes:
        counts["axes"] += 1
        counts["lines"] += len(ax.lines)
        counts["patches"] += len(ax.patches)
        counts["collections"] += len(ax.collections)
        counts["images"] += len(ax.images)
        counts["texts"] += len(ax.texts)
    return counts


def inches(width_in: float, height_in: float) -> tuple[float, float]:
    """A figure size that is a whole number of pixels at :data:`DPI`, so the PNG's size is
    ``round(x * DPI)`` exactly: half a pixel is added because Agg truncates ``x * DPI``, which
    floating point may put just below the integer."""
    return tuple((round(x * DPI) + 0.5) / DPI for x in (width_in, height_in))  # type: ignore[return-value]


def save(fig: plt.Figure, path: Path) -> dict[str, int]:
    """Write ``fig`` as PNG at :data:`DPI` with fixed metadata, close it, return its artist counts
    and its size in pixels (``width_px``, ``height_px``, as the PNG has them)."""
    counts = artist_counts(fig)
    counts["width_px"], counts["height_px"] = (int(x * DPI) for x in fig.get_size_inches())  # Agg truncates
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, format="png", metadata=PNG_METADATA)
    plt.close(fig)
    return counts


def panel_grid(n: int, ncols: int, panel_w: float, panel_h: float, **kw) -> tuple[plt.Figure, list[plt.Axes]]:
    """``n`` panels of ``panel_w`` x ``panel_h`` inches in rows of ``ncols`` (the unused axes removed)."""
    ncols = max(1, min(ncols, n))
    nrows = math.ceil(n / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=inches(panel_w * ncols, panel_h * nrows + 0.6), squeeze=False, **kw)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.remove()
    return fig, flat[:n]
