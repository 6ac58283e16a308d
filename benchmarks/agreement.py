"""Agreement of two runs of the same episodes, compared episode by episode.

The correctness check of both benchmarks: ``python -m benchmarks.engine`` (engine against the naive reference,
:mod:`benchmarks.engine`) and ``python -m benchmarks.solver`` (a backend against the IPOPT reference,
:mod:`benchmarks.solver`). Rows are episode rows as :func:`mcverify.episode.rollout.run_episodes`
writes them, matched by an id column.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Sequence
from typing import Any

import numpy as np

from mcverify.analysis.stats import proportion_interval

#: Verdicts compared for equality (each with an exact interval on its agreement rate).
VERDICTS = ("safe", "outcome")
#: Values compared by their absolute differences.
VALUES = ("min_dist_front_m", "overtake_time_s")


def agreement(
    rows_ref: list[dict],
    rows_new: list[dict],
    level: float = 0.95,
    *,
    key: str = "episode_id",
    verdicts: Sequence[str] = VERDICTS,
    values: Sequence[str] = VALUES,
    status_column: str | None = None,
) -> dict[str, Any]:
    """Episode-by-episode comparison of two paired runs (rows matched by their ``key`` column).

    Returns ``paired`` (the number of episodes in both runs), per verdict ``{v}_agree`` (how many
    are equal) and ``{v}_agree_ci`` (its two-sided Clopper-Pearson interval at ``level`` as a
    proportion, None without pairs), per value ``{c}_absdiff_median`` and ``{c}_absdiff_max`` of
    ``|ref - new|`` over the pairs where both are finite (NaN when none), and ``disagreements``:
    one dict per episode where any verdict differs (``key``, ``cell``, and ``{name}_ref``,
    ``{name}_new`` of every verdict and value), in ``key`` order. With ``status_column`` (a JSON
    object of status counts per row), also ``new_statuses``: the new run's statuses summed.
    """
    ref = {r[key]: r for r in rows_ref}
    new = {r[key]: r for r in rows_new}
    ids = sorted(set(ref) & set(new))
    out: dict[str, Any] = {"paired": len(ids)}
    for name in verdicts:
        same = sum(ref[i][name] == new[i][name] for i in ids)
        ci = proportion_interval(same, len(ids), level) if ids else None
        out[f"{name}_agree"] = same
        out[f"{name}_agree_ci"] = [ci.low, ci.high] if ci else None
    for col in values:
        d = np.array([abs(ref[i][col] - new[i][col]) for i in ids
                      if math.isfinite(ref[i][col]) and math.isfinite(new[i][col])])
        out[f"{col}_absdiff_median"] = float(np.median(d)) if d.size else math.nan
        out[f"{col}_absdiff_max"] = float(d.max()) if d.size else math.nan
    out["disagreements"] = [
        {key: i, "cell": ref[i].get("cell"),
         **{f"{k}_ref": ref[i][k] for k in (*verdicts, *values)},
         **{f"{k}_new": new[i][k] for k in (*verdicts, *values)}}
        for i in ids if any(ref[i][k] != new[i][k] for k in verdicts)
    ]
    if status_column is not None:
        statuses: Counter[str] = Counter()
        for i in ids:
            statuses.update(json.loads(new[i][status_column]))
        out["new_statuses"] = dict(statuses.most_common())
    return out
