"""The cells of a campaign: its ``[grid]`` (one axis per model field, a list of values each) and
its ``[axes]`` (named axes whose values are bundles of overrides), checked at load and expanded into
the cartesian product of cells, each with its own parameters, episode count and episode ids.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from typing import Any

from mcverify.campaign.overrides import apply_overrides, model_fields, suggest
from mcverify.campaign.validate import _short
from mcverify.cell import Cell
from mcverify.errors import CampaignError
from mcverify.levels import Level
from mcverify.model import ModelParams

#: Most episodes per cell: a run plans one chunk per few episodes up front, and an episode id is
#: folded into its JAX key as a 32-bit integer; 10 million closed-loop episodes are months of CPU.
MAX_EPISODES_PER_CELL = 10_000_000


def read_grid(grid: Any, where: str) -> dict[str, list[Any]]:
    """The ``[grid]`` table: each known field (or unit alias) with its non-empty list of distinct values."""
    if not isinstance(grid, Mapping):
        raise CampaignError(f"{where} [grid]: must be a table of 'section.field' = [values]")
    known = model_fields()
    out: dict[str, list[Any]] = {}
    for key, values in grid.items():
        if key not in known:
            raise CampaignError(f"{where} [grid]: unknown field {_short(key)}{suggest(key, known)}")
        if not isinstance(values, list) or not values:
            raise CampaignError(f"{where} [grid].{key}: must be a non-empty list of values")
        labels = [_fmt(v) for v in values]
        twice = next((label for label in labels if labels.count(label) > 1), None)
        if twice is not None:
            raise CampaignError(f"{where} [grid].{key}: the value {_short(twice)} is listed twice (cells must differ)")
        out[key] = list(values)
    return out


def read_axes(axes: Any, where: str) -> dict[str, dict[str, dict[str, Any]]]:
    """``[axes.<axis>.<label>]`` tables: each label a bundle of dotted model overrides (and
    optionally ``episodes``). Checked here; values are applied per cell."""
    if not isinstance(axes, Mapping):
        raise CampaignError(f"{where} [axes]: must be a table of axes, e.g. [axes.method.\"MPC-DC\"]")
    known = model_fields()
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for axis, labels in axes.items():
        if not isinstance(labels, Mapping) or not labels:
            raise CampaignError(f"{where} [axes.{axis}]: must hold one or more tables, e.g. [axes.{axis}.A]")
        out[axis] = {}
        for label, bundle in labels.items():
            here = f"{where} [axes.{axis}.{label}]"
            if not isinstance(bundle, Mapping):
                raise CampaignError(f"{here}: must be a table of 'section.field' = value")
            for key, value in bundle.items():
                if key == "episodes":
                    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_EPISODES_PER_CELL:
                        raise CampaignError(
                            f"{here}.episodes: must be an integer >= 1 and <= {MAX_EPISODES_PER_CELL:,}, "
                            f"got {_short(value)}"
                        )
                elif key not in known:
                    hint = suggest(key, list(known) + ["episodes"])
                    raise CampaignError(f"{here}: unknown field {_short(key)}{hint}")
            out[axis][str(label)] = dict(bundle)
    return out


def expand_cells(
    base: ModelParams,
    axes: dict[str, dict[str, dict[str, Any]]],
    grid: dict[str, list[Any]],
    episodes: int,
    where: str,
    *,
    episodes_forced: bool = False,
):
    """Cells: the product of the axes (in file order) and then the grid fields.

    Episode ids are unique in a run: cell k's episode 0 has id sum of the earlier cells' counts.
    ``episodes_forced`` (the CLI's --episodes) overrides any bundle's own ``episodes``.
    """
    dims: list[list[tuple[str, str, dict[str, Any]]]] = []
    for axis, labels in axes.items():
        dims.append([(axis, label, bundle) for label, bundle in labels.items()])
    for key, values in grid.items():
        dims.append([(key.split(".", 1)[1], _fmt(v), {key: v}) for v in values])
    names: set[str] = set()
    offset = 0
    for index, combo in enumerate(itertools.product(*dims)):
        labels = {axis: label for axis, label, _ in combo}
        overrides: dict[str, Any] = {}
        n_ep = episodes
        for axis, _, bundle in combo:
            for key, value in bundle.items():
                if key == "episodes":
                    n_ep = episodes if episodes_forced else value
                    continue
                if key in overrides:
                    raise CampaignError(
                        f"{where}: cell {_short(labels)} sets {key!r} twice (axis {_short(axis)} and another)"
                    )
                overrides[key] = value
        name = ",".join(f"{axis}={label}" for axis, label in labels.items()) or "all"
        if name in names:
            raise CampaignError(f"{where}: duplicate cell {_short(name)}; grid values and axis labels must be distinct")
        names.add(name)
        params = apply_overrides(base, overrides, f"{where} cell {_short(name)}")
        yield Cell(
            episode_offset=offset,
            index=index,
            name=name,
            overrides=overrides,
            params=params,
            episodes=n_ep,
            level=Level.of_barrier(params.barrier),
            labels=labels,
        )
        offset += n_ep


def _fmt(v: Any) -> str:
    if isinstance(v, float) and v.is_integer():
        return str(int(v))
    if isinstance(v, list):
        return "[" + ",".join(_fmt(x) for x in v) + "]"
    return str(v)
