"""Campaign files: TOML specs, validated at load, expanded into cells.

A campaign file looks like::

    [campaign]
    name = "table2"
    seed = 2024
    episodes = 30                 # per cell

    [model.barrier]               # any field of mcverify.model.ModelParams, by section
    epsilon = 0.3

    [grid]                        # one axis per field: cells are the cartesian product
    "scenario.front_speed_kmh" = [25, 28, 32, 36]

    [axes.method."MPC-DC"]        # a named axis whose values are bundles of overrides
    "mpc.controller" = "mpcdc"
    [axes.method."VL-CBF eps=0.3"]
    "barrier.epsilon" = 0.3
    episodes = 60                 # a bundle may set its cells' episode count

    [reference]                   # optional: the paper's numbers, shown beside ours in report.md
    table = "II"
    [reference.cells."front_speed_kmh=25"]
    overtake_time_min_s = 4.13

Every problem is reported as a :class:`CampaignError` whose message names the file, the field and
what to do; the CLI prints that one line and exits with status 2.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomllib

from mcverify.campaign.grid import MAX_EPISODES_PER_CELL, expand_cells, read_axes, read_grid
from mcverify.campaign.overrides import apply_overrides, coerce, flatten_model, model_fields, suggest
from mcverify.campaign.search_space import SearchSpace, read_search_space
from mcverify.campaign.validate import _short
from mcverify.cell import Cell
from mcverify.errors import CampaignError
from mcverify.fields import UNIT_ALIASES
from mcverify.model import ModelParams

#: Largest seed (jax.random.PRNGKey takes a signed 64-bit integer).
MAX_SEED = 2**63 - 1

_CAMPAIGN_KEYS = {"name", "description", "seed", "episodes", "common_random_numbers"}
_TOP_KEYS = {"campaign", "model", "grid", "axes", "reference", "falsify"}


@dataclass(frozen=True)
class Campaign:
    name: str
    description: str
    seed: int
    episodes_per_cell: int
    common_random_numbers: bool
    base: ModelParams
    grid: dict[str, list[Any]]
    cells: tuple[Cell, ...]
    axes: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    reference: dict[str, Any] = field(default_factory=dict)
    source: str = "<memory>"
    raw: dict[str, Any] = field(default_factory=dict)
    #: The ``[falsify]`` table (what ``mcverify falsify`` searches), None if the file has none.
    falsify: SearchSpace | None = None
    #: The command line's ``--set SECTION.FIELD=VALUE`` settings, already written into ``raw`` and the
    #: cells; kept apart so that a run's report can say what it changed from the file.
    settings: tuple[str, ...] = ()

    @property
    def total_episodes(self) -> int:
        return sum(c.episodes for c in self.cells)

    def cell(self, name_or_index: str | int) -> Cell:
        for c in self.cells:
            if c.name == name_or_index or c.index == name_or_index:
                return c
        names = ", ".join(repr(c.name) for c in self.cells)
        raise CampaignError(f"campaign {self.name!r} has no cell {name_or_index!r}; its cells: {names}")


# --------------------------------------------------------------------------------------------- load


def load_campaign(
    path: str | Path, *, episodes: int | None = None, seed: int | None = None, settings: Sequence[str] = ()
) -> Campaign:
    """Read, validate and expand a campaign file; ``episodes``/``seed`` override the file's values.

    settings: ``"SECTION.FIELD=VALUE"`` strings (``mcverify run --set``), each written into the
    file's ``[model.SECTION]`` table before validation (see :func:`apply_settings`).
    """
    path = Path(path)
    if path.is_dir():
        raise CampaignError(f"{path} is a folder, not a campaign file (give a .toml file)")
    if not path.is_file():
        raise CampaignError(f"campaign file not found: {path}")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # -sig: a byte-order mark is not TOML
    except tomllib.TOMLDecodeError as err:
        raise CampaignError(f"{path}: malformed TOML: {err}") from None
    except UnicodeDecodeError:
        raise CampaignError(f"{path}: not a text file (UTF-8 TOML expected)") from None
    except OSError as err:
        raise CampaignError(f"cannot read campaign file {path}: {err.strerror or err}") from None
    campaign = campaign_from_dict(apply_settings(raw, settings), source=str(path), episodes=episodes, seed=seed)
    campaign = dataclasses.replace(campaign, settings=tuple(settings))
    if any(cell.params.sim.stop_at for cell in campaign.cells):
        # an episode ended at its first violation has every other metric cut short: never in statistics
        raise CampaignError(f"{path}: sim.stop_at is set by `mcverify falsify` only (stop_episodes = true in "
                            "[falsify]); remove it from the campaign file")
    return campaign


def apply_settings(raw: Mapping[str, Any], settings: Sequence[str]) -> dict[str, Any]:
    """``raw`` (a campaign file's content) with ``"SECTION.FIELD=VALUE"`` settings written into its
    ``[model.SECTION]`` table; VALUE is read as a TOML value (``3``, ``0.5``, ``true``, ``[1, 2]``), else
    as a string (``ipopt``). The result is what a run records, so ``--resume`` rebuilds the same cells;
    a setting of a field that the grid or an axis varies is refused (the cell's value would win).
    Unknown sections and fields are rejected by the validation that follows, like the file's own.
    """
    model = raw.get("model", {})
    if not settings:
        return dict(raw)
    if not isinstance(model, Mapping):
        raise CampaignError(f"--set: the campaign file's [model] is not a table (got {type(model).__name__})")
    out = {**raw, "model": {k: dict(v) if isinstance(v, Mapping) else v for k, v in model.items()}}
    for item in settings:
        key, sep, text = item.partition("=")
        section, dot, name = key.strip().partition(".")
        if not sep or not dot or not section or not name or "." in name:
            raise CampaignError(f"--set {item!r}: expected SECTION.FIELD=VALUE, e.g. --set mpc.backend=ipopt")
        try:
            value = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = text.strip()
        _check_setting(f"{section}.{name}", value, item)
        _refuse_varied_field(raw, f"{section}.{name}", item)
        table = out["model"].setdefault(section, {})
        if not isinstance(table, dict):
            raise CampaignError(f"--set {item!r}: model.{section} is not a table in the campaign file")
        table[name] = value
    return out


def _check_setting(key: str, value: Any, item: str) -> None:
    """A ``--set``'s own mistakes (an unknown field, a value of the wrong type, a field only
    ``mcverify falsify`` sets) named as the option's, not blamed on the campaign file."""
    known = model_fields()
    if key not in known:
        raise CampaignError(f"--set {item!r}: unknown model field {_short(key)}{suggest(key, known)}")
    if key == "sim.stop_at":
        raise CampaignError(f"--set {item!r}: sim.stop_at is set by `mcverify falsify` only "
                            "(stop_episodes = true in [falsify])")
    coerce(value, known[key], f"--set {item!r}")


def _refuse_varied_field(raw: Mapping[str, Any], key: str, item: str) -> None:
    """A ``--set`` of a field that the file's grid or an axis varies would be silently overridden per
    cell (a cell's own value wins); refuse it with one line instead. Unit aliases count as their field."""
    def field_of(k: str) -> str:
        return UNIT_ALIASES[k][0] if k in UNIT_ALIASES else k

    target = field_of(key)
    grid = raw.get("grid", {})
    if isinstance(grid, Mapping) and any(field_of(str(k)) == target for k in grid):
        raise CampaignError(f"--set {item!r}: {key} is a grid axis of the campaign ([grid]), so every cell sets it "
                            "itself; change the [grid] list in the file instead")
    axes = raw.get("axes", {})
    for axis, labels in (axes.items() if isinstance(axes, Mapping) else ()):
        for label, bundle in (labels.items() if isinstance(labels, Mapping) else ()):
            if isinstance(bundle, Mapping) and any(field_of(str(k)) == target for k in bundle):
                raise CampaignError(f"--set {item!r}: {key} is set by the campaign's axis {axis!r} "
                                    f"([axes.{axis}.{label}]), which wins in its cells; change the axis in the file")
    bounds = raw.get("falsify", {}).get("bounds", {}) if isinstance(raw.get("falsify"), Mapping) else {}
    if isinstance(bounds, Mapping) and any(field_of(str(k).split("[", 1)[0]) == target for k in bounds):
        raise CampaignError(f"--set {item!r}: {key} is searched by the campaign's [falsify.bounds], so every "
                            "candidate sets it itself; change its bounds in the file instead")


def campaign_from_dict(
    raw: Mapping[str, Any],
    *,
    source: str = "<memory>",
    episodes: int | None = None,
    seed: int | None = None,
) -> Campaign:
    where = source
    _check_keys(raw, _TOP_KEYS, where)
    head = raw.get("campaign")
    if not isinstance(head, Mapping):
        raise CampaignError(f"{where}: missing [campaign] table (name, seed, episodes)")
    _check_keys(head, _CAMPAIGN_KEYS, f"{where} [campaign]")
    name = _typed(head, "name", str, f"{where} [campaign]", required=True)
    if not name.strip():
        raise CampaignError(f"{where} [campaign].name: must not be empty")
    seed_v = seed if seed is not None else _typed(head, "seed", int, f"{where} [campaign]", default=0)
    n_ep = episodes if episodes is not None else _typed(
        head, "episodes", int, f"{where} [campaign]", required=True
    )
    if not 1 <= n_ep <= MAX_EPISODES_PER_CELL:
        raise CampaignError(
            f"{where} [campaign].episodes: must be >= 1 and <= {MAX_EPISODES_PER_CELL:,} per cell, got {n_ep}"
        )
    if not 0 <= seed_v <= MAX_SEED:
        raise CampaignError(f"{where} [campaign].seed: must be >= 0 and < 2**63, got {seed_v}")
    crn = _typed(head, "common_random_numbers", bool, f"{where} [campaign]", default=False)

    base = apply_overrides(ModelParams(), flatten_model(raw.get("model", {}), where), where)
    grid = read_grid(raw.get("grid", {}), where)
    axes = read_axes(raw.get("axes", {}), where)
    cells = tuple(expand_cells(base, axes, grid, n_ep, where, episodes_forced=episodes is not None))
    falsify = read_search_space(raw["falsify"], where, model_fields()) if "falsify" in raw else None
    reference = raw.get("reference", {})
    if not isinstance(reference, Mapping):
        raise CampaignError(f"{where} [reference]: must be a table")
    return Campaign(
        name=name,
        description=_typed(head, "description", str, f"{where} [campaign]", default=""),
        seed=seed_v,
        episodes_per_cell=n_ep,
        common_random_numbers=crn,
        base=base,
        grid=grid,
        cells=cells,
        axes=axes,
        reference=dict(reference),
        source=source,
        raw=dict(raw),
        falsify=falsify,
    )


# ------------------------------------------------------------------------------------- helpers


def _typed(
    table: Mapping[str, Any],
    key: str,
    expected: type,
    where: str,
    *,
    required: bool = False,
    default: Any = None,
) -> Any:
    if key not in table:
        if required:
            raise CampaignError(f"{where}: missing required field {key!r}")
        return default
    value = table[key]
    ok = isinstance(value, expected) and not (expected is int and isinstance(value, bool))
    if not ok:
        raise CampaignError(
            f"{where}.{key}: expected {expected.__name__}, got {type(value).__name__} {_short(value)}"
        )
    return value


def _check_keys(table: Mapping[str, Any], valid: set[str], where: str) -> None:
    for key in table:
        if key not in valid:
            raise CampaignError(f"{where}: unknown key {_short(key)}{suggest(key, valid)}")
