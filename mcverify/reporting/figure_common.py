"""What every figure of a run shares: fixed pixel sizes, byte-stable PNGs, stored-data loading.

Figures are drawn with matplotlib as :class:`matplotlib.figure.Figure` objects saved to files
(:func:`subplots`, :func:`save`): never through pyplot, so drawing neither needs nor changes
matplotlib's global backend, and importing this package touches no global state. Every figure has a fixed size in
pixels (``figsize`` x :data:`DPI`, no tight bounding box) and is saved without the matplotlib
version in the PNG metadata, so the same data give the same bytes. Each drawing function returns
:func:`artist_counts` of what it drew (through :func:`save`), for tests and the report.

The figure families: :mod:`mcverify.reporting.cell_figures` (campaign level, from the summary) and
:mod:`mcverify.reporting.episode_figures` (one episode, from the stored trajectories).
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import math
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from mcverify.model import ModelParams

#: Dots per inch of every figure: pixel size = figsize * DPI.
DPI = 100
#: PNG text chunks: none (matplotlib would write its version; Agg writes no date).
PNG_METADATA: dict[str, Any] = {"Software": None}
#: Extra file formats a report can write beside each PNG (``mcverify report --format``).
EXPORT_FORMATS = ("png", "svg", "pdf")
#: Metadata that keeps each format's bytes stable (no date, no software version).
_EXPORT_METADATA: dict[str, dict[str, Any]] = {
    "png": PNG_METADATA, "svg": {"Date": None, "Creator": None}, "pdf": {"CreationDate": None, "Creator": None,
                                                                       "Producer": None},
}
#: The extra formats and their dpi for the figures drawn now (set by :func:`exporting`).
_EXPORT: contextvars.ContextVar[tuple[tuple[str, ...], int]] = contextvars.ContextVar("export", default=((), DPI))

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


def artist_counts(fig: Figure) -> dict[str, int]:
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


@contextlib.contextmanager
def exporting(formats: Sequence[str] = (), dpi: int = DPI) -> Iterator[None]:
    """While active, :func:`save` also writes every figure in ``formats`` (png, svg, pdf) at ``dpi``,
    beside the report's PNG: ``<key>.svg``, ``<key>.pdf``, or ``<key>-<dpi>dpi.png`` for a PNG at
    another resolution. The report's own PNG stays at :data:`DPI` (what report.html embeds)."""
    unknown = [f for f in formats if f not in EXPORT_FORMATS]
    if unknown:
        raise ValueError(f"unknown figure format {unknown[0]!r}; valid: {', '.join(EXPORT_FORMATS)}")
    token = _EXPORT.set((tuple(dict.fromkeys(formats)), int(dpi)))
    try:
        yield
    finally:
        _EXPORT.reset(token)


def export_paths(path: Path, formats: Sequence[str], dpi: int) -> list[Path]:
    """The extra files :func:`save` writes for the PNG ``path`` (see :func:`exporting`)."""
    path = Path(path)
    out = []
    for fmt in formats:
        if fmt == "png":
            if dpi != DPI:
                out.append(path.with_name(f"{path.stem}-{dpi}dpi.png"))
        else:
            out.append(path.with_suffix(f".{fmt}"))
    return out


def save(fig: Figure, path: Path) -> dict[str, int]:
    """Write ``fig`` as PNG at :data:`DPI` with fixed metadata (and the formats of :func:`exporting`),
    return its artist counts and its size in pixels (``width_px``, ``height_px``, as the PNG
    has them)."""
    counts = artist_counts(fig)
    counts["width_px"], counts["height_px"] = (int(x * DPI) for x in fig.get_size_inches())  # Agg truncates
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, format="png", metadata=PNG_METADATA)
    formats, dpi = _EXPORT.get()
    for extra in export_paths(path, formats, dpi):
        fmt = extra.suffix[1:]
        if fmt == "svg":
            matplotlib.rcParams["svg.hashsalt"] = "mcverify"  # fixed element ids: the same bytes every time
        fig.savefig(extra, dpi=dpi, format=fmt, metadata=_EXPORT_METADATA[fmt])
    return counts


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], dpi: float | None = None,
             **kw: Any) -> tuple[Figure, Any]:
    """A new figure and its axes, as ``pyplot.subplots`` makes them but outside pyplot: the figure
    is saved by its own canvas (Agg for PNG) and nothing global is registered or switched."""
    fig = Figure(figsize=figsize, dpi=dpi)
    return fig, fig.subplots(nrows, ncols, **kw)


def panel_grid(n: int, ncols: int, panel_w: float, panel_h: float, **kw) -> tuple[Figure, list[Axes]]:
    """``n`` panels of ``panel_w`` x ``panel_h`` inches in rows of ``ncols`` (the unused axes removed)."""
    ncols = max(1, min(ncols, n))
    nrows = math.ceil(n / ncols)
    fig, axes = subplots(nrows, ncols, figsize=inches(panel_w * ncols, panel_h * nrows + 0.6), squeeze=False, **kw)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.remove()
    return fig, flat[:n]
