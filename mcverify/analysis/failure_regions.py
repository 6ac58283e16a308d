"""Distinct failures: counterexamples grouped by failure mode *and* parameter region.

Rule: each parameter coordinate is scaled to [0, 1] by its bounds (in a search, the bounds of
``[falsify.bounds]``; in a run, the smallest and largest value over the run's cells or episodes).
Within one failure mode (:func:`mcverify.analysis.counterexamples.failure_mode`), two counterexamples
are in the same region when a chain of counterexamples of that mode joins them in which consecutive
ones differ by at most :data:`LINK` in *every* scaled coordinate (single-linkage clustering with an
L-infinity threshold). The rule is deterministic, does not depend on the order of the records, and
needs no number of clusters; a region is reported as the box its counterexamples span per coordinate.
Without coordinates (a one-cell run without sampled values) each failure mode is one region.

Regions are numbered 1, 2, ... by decreasing size, then by worst robustness; every record gets its
region's number in ``region``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, MutableMapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Largest difference in a scaled coordinate (a fraction of its range) between linked counterexamples.
LINK = 0.2


@dataclass(frozen=True)
class Region:
    """One group of counterexamples: its number, failure mode, size, worst robustness (and that
    episode's replay command), and per coordinate the (low, high) box its members span."""

    region: int
    failure_mode: str
    count: int
    worst_robustness: float
    worst_replay: str
    box: dict[str, tuple[float, float]]


def numeric_columns(records: Sequence[Mapping[str, Any]], prefixes: Sequence[str] = ("param:", "sample_")) -> list[str]:
    """The columns with one of ``prefixes`` that hold a finite number in every record."""
    if not records:
        return []
    names = [k for k in records[0] if k.startswith(tuple(prefixes))]
    return [n for n in names if all(_finite(r.get(n)) for r in records)]


def span(values: Sequence[Any]) -> tuple[float, float] | None:
    """(min, max) of the finite numbers in ``values``; None if there are none."""
    finite = [float(v) for v in values if _finite(v)]
    return (min(finite), max(finite)) if finite else None


def assign(records: Sequence[MutableMapping[str, Any]], bounds: Mapping[str, tuple[float, float]],
           link: float = LINK) -> list[Region]:
    """Group ``records`` (each with ``failure_mode``, ``robustness``, ``replay`` and the columns of
    ``bounds``) into regions by the rule of the module docstring; writes ``region`` into every record.

    bounds: coordinate column -> (low, high) used to scale it (low == high: the coordinate is ignored).
    """
    present = [c for c in bounds if all(_finite(r.get(c)) for r in records)]  # a missing value: not a coordinate
    columns = [c for c in present if bounds[c][1] > bounds[c][0]]
    groups: list[list[int]] = []
    for mode in sorted({r["failure_mode"] for r in records}):
        members = [i for i, r in enumerate(records) if r["failure_mode"] == mode]
        points = np.array([[(float(records[i][c]) - bounds[c][0]) / (bounds[c][1] - bounds[c][0]) for c in columns]
                           for i in members]).reshape(len(members), len(columns))
        groups += [[members[j] for j in comp] for comp in _components(points, link)]
    groups.sort(key=lambda g: (-len(g), min(float(records[i]["robustness"]) for i in g),
                               min(int(records[i].get("episode_id", 0)) for i in g)))
    regions = []
    for number, group in enumerate(groups, start=1):
        worst = min(group, key=lambda i: float(records[i]["robustness"]))
        for i in group:
            records[i]["region"] = number
        box = {c: (min(float(records[i][c]) for i in group), max(float(records[i][c]) for i in group))
               for c in present}
        regions.append(Region(number, records[worst]["failure_mode"], len(group),
                              float(records[worst]["robustness"]), str(records[worst].get("replay", "")), box))
    return regions


def from_records(records: Sequence[Mapping[str, Any]]) -> list[Region]:
    """The regions written into ``records`` by :func:`assign` (their ``region`` column), with boxes
    over the records' numeric coordinates (:func:`numeric_columns`), in region order."""
    columns = numeric_columns(records)
    out = []
    for number in sorted({int(r["region"]) for r in records if r.get("region") is not None}):
        group = [r for r in records if r.get("region") == number]
        worst = min(group, key=lambda r: float(r["robustness"]))
        box = {c: (min(float(r[c]) for r in group), max(float(r[c]) for r in group)) for c in columns}
        out.append(Region(number, worst["failure_mode"], len(group), float(worst["robustness"]),
                          str(worst.get("replay", "")), box))
    return out


def _components(points: np.ndarray, link: float) -> list[list[int]]:
    """Connected components of the graph joining points at L-infinity distance <= ``link``;
    points (n, d); each component sorted, components in order of their first point."""
    n = points.shape[0]
    label = list(range(n))

    def root(i: int) -> int:
        while label[i] != i:
            label[i] = label[label[i]]
            i = label[i]
        return i

    for i in range(n):
        if points.shape[1] == 0:
            close = np.arange(i + 1, n)
        else:
            close = i + 1 + np.flatnonzero(np.max(np.abs(points[i + 1:] - points[i]), axis=1) <= link + 1e-12)
        for j in close:
            a, b = root(i), root(int(j))
            if a != b:
                label[max(a, b)] = min(a, b)
    comps: dict[int, list[int]] = {}
    for i in range(n):
        comps.setdefault(root(i), []).append(i)
    return list(comps.values())


def _finite(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(float(v))
