"""The ``[falsify]`` table of a campaign file: what ``mcverify falsify`` searches over, validated at load.

::

    [falsify]
    requirement = "safe"          # a requirement of mcverify.analysis.robustness (default "safe")
    population = 8                # candidates per generation (one batch), >= 2 (default 8)
    stop_at_first = true          # stop after the generation that found a counterexample (default true)
    stop_episodes = false         # end each episode at its first violation of the requirement (default false)
    common_noise = false          # every candidate of a search sees the same per-step noise (default false)
    guide = "ellipse@go_back"     # what the method minimises instead of the requirement (default: the requirement)
    extremes = ["noise.front_x_bias"]   # searched fields taken at their low or high bound only (default none)

    [falsify.bounds]              # one numeric model field per entry: [low, high], low < high
    "scenario.front_speed_mps" = [5.0, 9.0]
    "opposing.speed_mps" = [8.0, 19.4]
    "noise.opp_x_segments[0]" = [-1.0, 1.0]   # elements [0]..[K-1] of a list field: the whole list
    "noise.opp_x_segments[1]" = [-1.0, 1.0]

    [falsify.nominal]             # optional: a field's nominal distribution inside its bounds
    "scenario.front_speed_mps" = { mean = 6.94, std = 0.5 }   # normal truncated to the bounds

    [falsify.adversary]           # optional: search the perception error itself (issue 49)
    kind = "gap_bands"            # "gap_bands", "windows", "bang_bang" or "full" (every step)
    channels = ["front_y"]        # searched channels of front_x, front_y, front_v, opp_x, opp_v (default all)
    front_share = 1.0             # veh_f's share of its noise bounds handed to the adversary (default 1)
    opp_share = 1.0               # veh_o's (default 1)
    edges_m = [2.0, 3.0, 15.0]    # gap_bands: outer footprint gaps (m) of the bands alongside, jump, approach
    # windows: centres_s = [6.0, 8.0], half_width_s = 1.0, max_steps = 10;  bang_bang: segments = 8

    [falsify.beam]                # optional: a sequential (beam) search over the per-step error, for
    window_s = [4.0, 5.6]         # --method beam only (mcverify.campaign.beam_table)
    segment_s = 0.2
    branching = 4
    width = 4

With ``[falsify.adversary]`` every candidate's perception error is an error schedule
(:mod:`mcverify.sim.schedule`) from the parametrisation's theta (:mod:`mcverify.falsify.parametrisations`),
mapped from its own coordinates of the unit cube (theta = 2u - 1), after the coordinates of the
``[falsify.bounds]`` fields, which may then be empty (the scenario fixed) or not (searched alongside).
Nothing is random: each candidate is one deterministic episode, whose schedule is kept in its
generation's run folder for ``mcverify replay``. ``random`` over ``kind = "full"`` is the uniform random
schedule baseline, over ``kind = "bang_bang"`` the random bang-bang baseline.

Without a ``[falsify.nominal]`` entry a field is uniform on its bounds. A search works on the unit
cube; a coordinate u maps to its field through the inverse CDF of the field's nominal distribution
(:meth:`SearchSpace.values`), so ``random`` draws from the nominal distribution, the other methods
start from it (their first generation is centred on the cube), and every method stays inside the
bounds.

Every candidate is one episode of a one-episode cell whose overrides are the candidate's values (so
its episode is an ordinary row and ``mcverify replay`` re-simulates it bit for bit); the per-step
perception noise still acts as in any run: each candidate draws its own, unless ``common_noise`` gives
every candidate of a search the same noise realisation (``noise.key_seed`` from the search's seed),
which makes the robustness a deterministic function of the searched values. A campaign with a
``[falsify]`` table must define one target: no ``[grid]`` and no ``[axes]`` (checked by :func:`check_single_target`).
Every problem is a :class:`CampaignError` of one line.

``guide`` (one of :data:`~mcverify.requirements.GUIDE_NAMES`): the value the method is told and minimises,
when the requirement's own robustness points the search the wrong way; counterexamples, success and
the early stops are still judged by the requirement. Besides any requirement, ``"<r>@go_back"`` is
requirement r over the sub-steps where the ego goes back (+inf for an episode that never turned
back), e.g. to compare scenarios by how close their turn-backs come, where the overtakes' margins
would lure the search elsewhere, and ``"<r>@run"`` is r's running robustness brought forward by the
current run of steps at which the planner solved neither problem (what ``--method splitting`` can
climb where a violation follows such a run; docs/falsification.md).

``extremes``: searched fields that take only their two bounds (bang-bang): a coordinate u < 1/2 is
the field's low bound, u >= 1/2 its high bound, so ``random`` draws each end with probability 1/2 and
the other methods move the odds. A bounded disturbance that enters additively does its worst at its
bounds (as in Breach's corner-first search, which evaluates the domain's corners before anything else),
so declaring the disturbance fields extreme searches its corners and the scenario together. Such a
field has no ``[falsify.nominal]`` entry.
"""

from __future__ import annotations

import math
import re
import statistics
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from mcverify.analysis import stl
from mcverify.campaign.beam_table import BeamTable, read_beam
from mcverify.campaign.validate import _short
from mcverify.errors import CampaignError
from mcverify.requirements import GUIDE_NAMES, REQUIREMENT_NAMES, STL_PREFIX, is_stl

__all__ = ["ADVERSARY_KINDS", "MAX_POPULATION", "REQUIREMENT_NAMES", "AdversarySpec", "SearchSpace",
           "check_single_target", "read_adversary", "read_search_space", "split_element"]

_KEYS = {"requirement", "population", "stop_at_first", "stop_episodes", "common_noise", "guide", "bounds", "nominal",
         "extremes", "adversary", "beam"}
#: The parametrisations ``[falsify.adversary] kind`` names, and the keys each takes besides the common ones.
ADVERSARY_KINDS: dict[str, tuple[str, ...]] = {
    "gap_bands": ("edges_m",), "windows": ("centres_s", "half_width_s", "max_steps"), "bang_bang": ("segments",),
    "full": (),
}
_ADVERSARY_COMMON = ("kind", "channels", "front_share", "opp_share")
MAX_POPULATION = 1024
_ELEMENT = re.compile(r"(.+)\[(\d+)\]")


@dataclass(frozen=True)
class SearchSpace:
    """A validated ``[falsify]`` table: ``bounds`` maps a model field to (low, high) in its unit,
    in file order; ``nominal`` maps some of them to (mean, std) of a normal truncated to the bounds."""

    requirement: str
    population: int
    stop_at_first: bool
    bounds: tuple[tuple[str, float, float], ...]
    stop_episodes: bool = False
    nominal: tuple[tuple[str, float, float], ...] = ()
    common_noise: bool = False
    guide: str = ""  # "" : the requirement itself
    extremes: tuple[str, ...] = ()  # fields taken at their low or high bound only
    adversary: AdversarySpec | None = None  # the searched perception error, None: the drawn noise
    beam: BeamTable | None = None  # the ``[falsify.beam]`` table (--method beam only), None: none

    @property
    def objective(self) -> str:
        """What the method minimises: the guide, or the requirement when there is none."""
        return self.guide or self.requirement

    @property
    def nominal_by_field(self) -> dict[str, tuple[float, float]]:
        """field -> (mean, std) of the fields with a nominal distribution."""
        return {name: (mean, std) for name, mean, std in self.nominal}

    @property
    def fields(self) -> tuple[str, ...]:
        return tuple(b[0] for b in self.bounds)

    @property
    def dimension(self) -> int:
        """Coordinates of the ``[falsify.bounds]`` fields (an adversary's theta comes after them)."""
        return len(self.bounds)

    def overrides(self, values: Mapping[str, float]) -> dict[str, Any]:
        """The cell overrides of a candidate's ``values``: plain fields as they are, the elements
        ``field[i]`` of a list field gathered into that field's whole list (indices 0..K-1)."""
        out: dict[str, Any] = {}
        for name, value in values.items():
            field, index = split_element(name)
            if index is None:
                out[name] = value
            else:
                out.setdefault(field, []).append((index, value))
        return {k: [x for _, x in sorted(v)] if isinstance(v, list) else v for k, v in out.items()}

    def values(self, unit_point: list[float]) -> dict[str, float]:
        """The model values of a point of the unit cube [0, 1]^dimension (clipped into it)."""
        if len(unit_point) != self.dimension:
            raise ValueError(f"expected {self.dimension} coordinates, got {len(unit_point)}")
        nominal = self.nominal_by_field
        out = {}
        for (name, lo, hi), u in zip(self.bounds, unit_point, strict=True):
            u = min(1.0, max(0.0, float(u)))
            if name in self.extremes:
                out[name] = lo if u < 0.5 else hi
            elif name in nominal:
                out[name] = truncated_normal_ppf(u, *nominal[name], lo, hi)
            else:
                out[name] = float(lo + u * (hi - lo))
        return out

    def describe(self) -> str:
        """One line: each field's bounds and, where given, its nominal distribution or ``(extremes)``."""
        nominal = self.nominal_by_field

        def one(name: str, lo: float, hi: float) -> str:
            if name in self.extremes:
                return f"{name} in {{{lo:g}, {hi:g}}} (extremes)"
            if name in nominal:
                return f"{name} in [{lo:g}, {hi:g}] (nominal N({nominal[name][0]:g}, {nominal[name][1]:g}²) truncated)"
            return f"{name} in [{lo:g}, {hi:g}]"

        return ", ".join(one(n, lo, hi) for n, lo, hi in self.bounds)


@dataclass(frozen=True)
class AdversarySpec:
    """A validated ``[falsify.adversary]`` table (module docstring): the parametrisation's kind and its
    settings; the falsifier turns it into a parametrisation once the episode's control steps are known."""

    kind: str
    channels: tuple[str, ...] = ()  # () : every channel
    front_share: float = 1.0
    opp_share: float = 1.0
    edges_m: tuple[float, ...] = (2.0, 3.0, 15.0)
    centres_s: tuple[float, ...] = ()
    half_width_s: float = 1.0
    max_steps: int = 10
    segments: int = 8

    def describe(self) -> str:
        extra = {"gap_bands": f"edges {list(self.edges_m)} m", "bang_bang": f"{self.segments} segments",
                 "windows": f"centres {list(self.centres_s)} s +- {self.half_width_s:g} s, <= {self.max_steps} steps",
                 "full": "every control step"}[self.kind]
        return (f"adversary {self.kind} ({extra}) on {', '.join(self.channels)}, shares front {self.front_share:g}, "
                f"opposing {self.opp_share:g}")


def read_adversary(table: Any, here: str) -> AdversarySpec:
    """Validate ``[falsify.adversary]``; every problem one :class:`CampaignError` line."""
    from mcverify.sim.schedule import CHANNELS  # noqa: PLC0415 - JAX only for a campaign with an adversary

    at = f"{here}.adversary"
    if not isinstance(table, Mapping):
        raise CampaignError(f"{at}: must be a table (kind = {' | '.join(ADVERSARY_KINDS)}, ...)")
    kind = table.get("kind")
    if kind not in ADVERSARY_KINDS:
        raise CampaignError(f"{at}.kind: expected one of {', '.join(ADVERSARY_KINDS)}, got {_short(kind)}")
    for key in table:
        if key not in (*_ADVERSARY_COMMON, *ADVERSARY_KINDS[kind]):
            raise CampaignError(f"{at}: unknown key {_short(key)} for kind {kind!r} (known: "
                                f"{', '.join((*_ADVERSARY_COMMON, *ADVERSARY_KINDS[kind]))})")
    channels = table.get("channels", list(CHANNELS))
    if (not isinstance(channels, list) or not channels or any(c not in CHANNELS for c in channels)
            or len(set(channels)) != len(channels)):
        raise CampaignError(f"{at}.channels: expected distinct names among {', '.join(CHANNELS)}, "
                            f"got {_short(channels)}")
    out: dict[str, Any] = {"channels": tuple(channels)}
    for key in ("front_share", "opp_share", "half_width_s"):
        if key in table:
            v = table[key]
            lo_ok = (lambda x: 0.0 <= x <= 1.0) if key.endswith("share") else (lambda x: x > 0.0)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or not lo_ok(v):
                want = "a number in [0, 1]" if key.endswith("share") else "a positive number (s)"
                raise CampaignError(f"{at}.{key}: expected {want}, got {_short(v)}")
            out[key] = float(v)
    for key in ("max_steps", "segments"):
        if key in table:
            v = table[key]
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 100_000:
                raise CampaignError(f"{at}.{key}: expected a positive integer, got {_short(v)}")
            out[key] = v
    for key, size in (("edges_m", 3), ("centres_s", None)):
        if key in table:
            v = table[key]
            if (not isinstance(v, list) or not v or (size is not None and len(v) != size)
                    or any(isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x) or x < 0
                           for x in v)):
                raise CampaignError(f"{at}.{key}: expected {size or 'one or more'} non-negative numbers, "
                                    f"got {_short(v)}")
            if key == "edges_m" and any(b < a for a, b in zip(v, v[1:], strict=False)):
                raise CampaignError(f"{at}.edges_m: the band edges must not decrease, got {_short(v)}")
            out[key] = tuple(float(x) for x in v)
    if kind == "windows" and "centres_s" not in out:
        raise CampaignError(f"{at}: kind \"windows\" needs centres_s = [t, ...] (s; one window around each)")
    return AdversarySpec(kind, **out)


_STANDARD_NORMAL = statistics.NormalDist()


def truncated_normal_ppf(u: float, mean: float, std: float, lo: float, hi: float) -> float:
    """The u-quantile (u in [0, 1]) of N(mean, std²) truncated to [lo, hi]; pure Python, so the same
    u gives the same value on every machine. The ends of [0, 1] are the bounds exactly."""
    if u <= 0.0 or u >= 1.0:
        return float(lo if u <= 0.0 else hi)
    cdf_lo = _STANDARD_NORMAL.cdf((lo - mean) / std)
    cdf_hi = _STANDARD_NORMAL.cdf((hi - mean) / std)
    p = cdf_lo + u * (cdf_hi - cdf_lo)
    p = min(max(p, 1e-300), 1.0 - 1e-16)  # inv_cdf needs 0 < p < 1
    return float(min(hi, max(lo, mean + std * _STANDARD_NORMAL.inv_cdf(p))))


def read_search_space(table: Any, where: str, known_fields: Mapping[str, type]) -> SearchSpace:
    """Validate a ``[falsify]`` table; ``known_fields`` is every settable ``section.field`` with its type."""
    here = f"{where} [falsify]"
    if not isinstance(table, Mapping):
        raise CampaignError(f"{here}: must be a table (requirement, population, stop_at_first, stop_episodes, "
                            "[falsify.bounds])")
    for key in table:
        if key not in _KEYS:
            raise CampaignError(f"{here}: unknown key {_short(key)} (known: {', '.join(sorted(_KEYS))})")
    requirement = table.get("requirement", "safe")
    if not isinstance(requirement, str) or (requirement not in REQUIREMENT_NAMES and not is_stl(requirement)):
        raise CampaignError(f"{here}.requirement: unknown requirement {_short(requirement)}; known: "
                            f"{', '.join(REQUIREMENT_NAMES)} or {STL_PREFIX}<formula>")
    if is_stl(requirement):
        try:
            stl.parse(requirement)
        except ValueError as exc:
            raise CampaignError(f"{here}.requirement: {exc}") from None
    guide = table.get("guide", "")
    if guide != "" and guide not in GUIDE_NAMES:
        raise CampaignError(f"{here}.guide: unknown guide {_short(guide)}; known: {', '.join(GUIDE_NAMES)}")
    population = table.get("population", 8)
    if isinstance(population, bool) or not isinstance(population, int) or not 2 <= population <= MAX_POPULATION:
        raise CampaignError(
            f"{here}.population: must be an integer from 2 to {MAX_POPULATION}, got {_short(population)}"
        )
    stop = table.get("stop_at_first", True)
    stop_episodes = table.get("stop_episodes", False)
    common_noise = table.get("common_noise", False)
    for key, flag in (("stop_at_first", stop), ("stop_episodes", stop_episodes), ("common_noise", common_noise)):
        if not isinstance(flag, bool):
            raise CampaignError(f"{here}.{key}: must be true or false, got {_short(flag)}")
    adversary = read_adversary(table["adversary"], here) if "adversary" in table else None
    beam = read_beam(table["beam"], here) if "beam" in table else None
    bounds = table.get("bounds", {} if adversary is not None or beam is not None else None)
    if not isinstance(bounds, Mapping) or (not bounds and adversary is None and beam is None):
        raise CampaignError(f"{here}: needs a non-empty [falsify.bounds] table of 'section.field' = [low, high] "
                            "(or a [falsify.adversary] or [falsify.beam] table)")
    if adversary is not None and common_noise:
        raise CampaignError(f"{here}: common_noise = true fixes the drawn noise; with [falsify.adversary] nothing "
                            "is drawn (remove one)")
    out = []
    elements: dict[str, list[int]] = {}
    for name, pair in bounds.items():
        at = f"{here}.bounds.{name}"
        field, index = split_element(str(name))
        if field not in known_fields:
            raise CampaignError(f"{here}.bounds: unknown model field {_short(name)}")
        if adversary is not None and field.startswith("noise.") and field != "noise.scale":
            raise CampaignError(f"{here}.bounds: {_short(name)} shapes the drawn noise, which [falsify.adversary] "
                                "replaces (search the error through the adversary)")
        kind = known_fields[field]
        if index is not None and kind is not tuple:
            raise CampaignError(f"{at}: [i] selects an element of a list field; {field} is {kind.__name__}")
        if index is None and kind is not float:
            raise CampaignError(f"{at}: only numeric (float) fields can be searched, this one is {kind.__name__}"
                                + (f"; search its elements as \"{field}[0]\", \"{field}[1]\", ..." if kind is tuple
                                   else ""))
        if index is not None:
            elements.setdefault(field, []).append(index)
        if (not isinstance(pair, list) or len(pair) != 2
                or any(isinstance(v, bool) or not isinstance(v, int | float) for v in pair)):
            raise CampaignError(f"{at}: expected [low, high] (two numbers), got {_short(pair)}")
        lo, hi = float(pair[0]), float(pair[1])
        if not (math.isfinite(lo) and math.isfinite(hi)) or not lo < hi:
            raise CampaignError(f"{at}: expected finite low < high, got [{lo:g}, {hi:g}]")
        out.append((str(name), lo, hi))
    for field, indices in elements.items():
        if sorted(indices) != list(range(len(indices))):
            raise CampaignError(f"{here}.bounds: the searched elements of {field} must be [0] to [K-1] (they make "
                                f"the whole list), got {sorted(indices)}")
    nominal = _read_nominal(table.get("nominal", {}), here, {name: (lo, hi) for name, lo, hi in out})
    extremes = _read_extremes(table.get("extremes", []), here, [name for name, _, _ in out],
                              [name for name, _, _ in nominal])
    return SearchSpace(requirement, population, stop, tuple(out), stop_episodes, nominal, common_noise,
                       "" if guide == requirement else guide, extremes, adversary, beam)


def _read_extremes(names: Any, here: str, searched: list[str], with_nominal: list[str]) -> tuple[str, ...]:
    """``extremes = ["field", ...]``: distinct searched fields without a nominal distribution."""
    if not isinstance(names, list) or any(not isinstance(n, str) for n in names):
        raise CampaignError(f"{here}.extremes: expected a list of searched field names, got {_short(names)}")
    for name in names:
        if name not in searched:
            raise CampaignError(f"{here}.extremes: {_short(name)} is not a searched field (give its [low, high] in "
                                "[falsify.bounds] first)")
        if name in with_nominal:
            raise CampaignError(f"{here}.extremes: {_short(name)} has a [falsify.nominal] entry; a field taken at "
                                "its bounds only has none")
    if len(set(names)) != len(names):
        raise CampaignError(f"{here}.extremes: a field is named twice in {_short(names)}")
    return tuple(names)


def _read_nominal(table: Any, here: str,
                  bounds: Mapping[str, tuple[float, float]]) -> tuple[tuple[str, float, float], ...]:
    """``[falsify.nominal]``: ``"field" = { mean = m, std = s }`` for searched fields, m inside the
    bounds, s > 0."""
    if not isinstance(table, Mapping):
        raise CampaignError(f"{here}.nominal: must be a table of \"section.field\" = {{ mean = m, std = s }}")
    out = []
    for name, spec in table.items():
        at = f"{here}.nominal.{name}"
        if name not in bounds:
            raise CampaignError(f"{at}: not a searched field (give its [low, high] in [falsify.bounds] first)")
        if not isinstance(spec, Mapping) or set(spec) != {"mean", "std"} or any(
                isinstance(v, bool) or not isinstance(v, int | float) for v in spec.values()):
            raise CampaignError(f"{at}: expected {{ mean = m, std = s }} (two numbers), got {_short(spec)}")
        mean, std = float(spec["mean"]), float(spec["std"])
        lo, hi = bounds[name]
        if not (math.isfinite(mean) and lo <= mean <= hi):
            raise CampaignError(f"{at}: mean must lie in the bounds [{lo:g}, {hi:g}], got {mean:g}")
        if not (math.isfinite(std) and std > 0.0):
            raise CampaignError(f"{at}: std must be a positive number, got {std:g}")
        out.append((str(name), mean, std))
    return tuple(out)


def split_element(name: str) -> tuple[str, int | None]:
    """``"noise.opp_x_segments[2]"`` -> ("noise.opp_x_segments", 2); a plain name -> (name, None)."""
    match = _ELEMENT.fullmatch(name)
    return (match.group(1), int(match.group(2))) if match else (name, None)


def check_single_target(raw: Mapping[str, Any], where: str) -> None:
    """A falsification campaign searches around one target cell: no [grid], no [axes]."""
    for key in ("grid", "axes"):
        if raw.get(key):
            raise CampaignError(f"{where}: a campaign searched by `mcverify falsify` defines one target; remove "
                                f"[{key}] (set its values in [model] or with --set)")
