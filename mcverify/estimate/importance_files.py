"""What an importance-sampling estimate leaves in its folder besides ``estimate.json``: each cell's final
draws (``samples_cellNNN.parquet``) and figure, and the text of a noise tilt."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcverify import files
from mcverify.estimate import importance
from mcverify.estimate.folder import num
from mcverify.sim import tilt as tilt_mod
from mcverify.sim.tilt import NoiseTilt

__all__ = ["SAMPLE_COLUMNS", "draw_cell", "figure_file", "samples_file", "tilt_text", "write_samples"]


#: The row values kept per final draw in ``samples_cellNNN.parquet`` (those a row has).
SAMPLE_COLUMNS = ("outcome", "collision_front", "collision_opp", "min_gap_front_m", "min_h_front",
                  "ellipse_violation", "switched_to_q2_at_s", "steps", "noise_log_lr")


def samples_file(out: Path, cell_index: int) -> Path:
    """Where a cell's final draws are kept."""
    return Path(out) / f"samples_cell{cell_index:03d}.parquet"


def figure_file(cell_index: int) -> str:
    """A cell's figure (nominal and proposal densities, the final draws), relative to the folder."""
    return f"figures/importance_cell{cell_index:03d}.png"


def draw_cell(out: Path, result: dict[str, Any], bounds: dict[str, tuple[float, float]], alpha: float,
              final: Mapping[str, np.ndarray], nominal: importance.Nominal | None = None) -> None:
    """Draw a finished cell's figure (:mod:`mcverify.reporting.importance_figures`); ``nominal``: the cell's
    nominal distribution (default: uniform on the bounds)."""
    from mcverify.reporting import importance_figures  # noqa: PLC0415 - matplotlib only where a figure is drawn
    nominal_logpdf = (nominal or importance.Nominal.uniform(list(bounds.values()))).marginal_logpdf
    title = (f"{result['cell']}: P({result['target']}) = {num(result['estimate'])} "
             f"[{num(result['low'])}, {num(result['high'])}], {result['failures']} failing of {len(final['weight'])}")
    importance_figures.draw_importance_cell(Path(out) / figure_file(result["cell_index"]), title, list(bounds),
                                            list(bounds.values()), result["proposal_a"], result["proposal_b"],
                                            alpha, final["theta"], final["failed"], nominal_logpdf=nominal_logpdf)


def write_samples(out: Path, cell_index: int, names: Sequence[str], rows: Sequence[dict[str, Any]],
                  final: Mapping[str, np.ndarray]) -> None:
    """Keep a cell's final draws: its episode id (``cell_episode``, which replays the episode with the
    same scenario values and noise tilt), the scenario values, the weight (nominal over proposal,
    noise included), whether it failed and the row values of :data:`SAMPLE_COLUMNS`. The cell's
    estimate is ``mean(weight * failed)`` over this file, exactly."""
    import pyarrow as pa  # noqa: PLC0415 - only when writing
    import pyarrow.parquet as pq  # noqa: PLC0415

    weight = np.asarray(final["weight"], dtype=float)
    rows = rows if len(rows) == weight.size else []  # a score function that runs no episodes has no rows
    table: dict[str, Any] = {"cell_episode": [int(r["cell_episode"]) for r in rows]} if rows else {}
    table.update({f"sample_{n}": np.asarray(final["theta"])[:, j].astype(float) for j, n in enumerate(names)})
    table["weight"] = weight
    table["failed"] = np.asarray(final["failed"], dtype=bool)
    for key in SAMPLE_COLUMNS:
        if any(key in r for r in rows):
            table[key] = [r.get(key) for r in rows]
    files.atomic_write(samples_file(out, cell_index), lambda tmp: pq.write_table(pa.table(table), tmp))


def tilt_text(tilt: NoiseTilt) -> str:
    """The tilts per band and unit, e.g. "approach y -5, jump y +5" (zeros left out), and the window."""
    pairs = ((b, u) for b in tilt_mod.TILT_BANDS for u in tilt_mod.TILT_UNITS)
    parts = [f"{band} {unit} {t:+.2g}" for (band, unit), t in zip(pairs, tilt.theta, strict=True) if t != 0.0]
    return (f"{', '.join(parts) or 'all tilts 0'}; gap window {tilt.gap_max_m:g} / {tilt.split_m:g} m, "
            f"{tilt.band_steps:g} steps per band, defensive {tilt.defensive:g}")
