"""An exact lower bound on an event's probability from boxes of the decisive draws (issue 50's reference ii).

A stratum is a box in an episode's random inputs (:class:`~mcverify.estimate.input_vector.ClosedLoopProblem`'s
law): a sub-range of some scenario draws' values and a sub-interval of some per-step perception-error units
(control step, channel). Every other input keeps its own law. Because the inputs are independent and each
is uniform in its unit, the box's probability is exact:

    P(R) = prod over boxed draws (|value sub-range| / |draw's range|) * prod over boxed units ((high - low) / 2).

Crude Monte Carlo inside the box (the boxed coordinates drawn uniformly in it, the rest from their law)
gives k events in n episodes, so P(event and R) = P(R) P(event | R) with P(event | R) >= the one-sided
Clopper-Pearson bound of k/n. Strata whose boxes are disjoint (different sub-ranges of one draw, say) add
up; with m strata each bound is taken at level 1 - (1 - level) / m (Bonferroni), so the sum is a lower
bound on P(event) at ``level`` whatever the strata are. It guards an estimator against reading low: no
estimate below it is credible. It cannot say an estimate reads high (the event outside the boxes is not
counted).

Where the boxes come from: the episodes a rare-event estimator or crude Monte Carlo found, re-simulated
with their measurements recorded (docs/rare_events.md, "a stratified lower bound"). Any box is valid; a
box around the decisive draws makes the bound tight.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tomllib
from scipy.special import ndtri

from mcverify.analysis.intervals import clopper_pearson_arrays
from mcverify.errors import RunError
from mcverify.sim.schedule import CHANNELS

__all__ = ["Bound", "Stratum", "StratumCount", "UnitBox", "check_disjoint", "load_strata", "lower_bound"]


@dataclass(frozen=True)
class UnitBox:
    """The perception-error unit of ``channel`` (one of :data:`~mcverify.sim.schedule.CHANNELS`) at control
    step ``step`` restricted to [low, high] within [-1, 1]."""

    step: int
    channel: str
    low: float
    high: float


@dataclass(frozen=True)
class Stratum:
    """A box: ``draws`` maps a scenario draw's name to a (low, high) sub-range of its values; ``units`` the
    boxed error units; ``episodes`` the crude Monte Carlo episodes to run inside it."""

    name: str
    draws: tuple[tuple[str, float, float], ...]
    units: tuple[UnitBox, ...]
    episodes: int

    def coordinates(self, problem) -> list[tuple[int, float, float]]:
        """(index in x, low, high) of every boxed coordinate as a uniform unit: [0, 1] for a draw (the rollout's
        transform :func:`~mcverify.episode.draws.value_of_unit`, value = hi - (hi - lo) u), [-1, 1] for an
        error unit. One line (RunError) for a draw the cell does not draw, a range outside the draw's, a
        step outside the episode or a channel the cell does not measure."""
        out = []
        names = [d.name for d in problem.draws]
        for name, low, high in self.draws:
            if name not in names:
                raise RunError(f"stratum {self.name!r}: {name} is not a random draw of this cell "
                               f"(its draws: {', '.join(names) or 'none'})")
            draw = problem.draws[names.index(name)]
            lo, hi = (float(v) for v in draw.range_of(problem.cell.params))
            if draw.sd(problem.cell.params) > 0:
                raise RunError(f"stratum {self.name!r}: {name} is drawn from a truncated normal; a box needs a "
                               "uniform draw")
            if not lo <= low < high <= hi:
                raise RunError(f"stratum {self.name!r}: {name} in [{low:g}, {high:g}] is not a sub-range of its "
                               f"range [{lo:g}, {hi:g}]")
            out.append((names.index(name), (hi - high) / (hi - lo), (hi - low) / (hi - lo)))
        s = len(problem.draws)
        measured = [CHANNELS[j] for j in problem.channels]
        for box in self.units:
            if box.channel not in measured:
                raise RunError(f"stratum {self.name!r}: channel {box.channel!r} is not measured in this cell "
                               f"(channels: {', '.join(measured)})")
            if not 0 <= box.step < problem.steps:
                raise RunError(f"stratum {self.name!r}: step {box.step} is outside the episode's control steps "
                               f"0 to {problem.steps - 1}")
            out.append((s + box.step * len(problem.channels) + measured.index(box.channel), box.low, box.high))
        if len({i for i, _, _ in out}) < len(out):
            raise RunError(f"stratum {self.name!r} boxes one input twice")
        return out

    def probability(self, problem) -> float:
        """P(R), exact (the boxed coordinates are independent uniforms)."""
        s = len(problem.draws)
        return math.prod((high - low) / (1.0 if i < s else 2.0) for i, low, high in self.coordinates(problem))

    def inputs(self, problem, rng: np.random.Generator, n: int) -> np.ndarray:
        """n input vectors (standard normals, the layout of ``problem``) drawn from the law conditioned on the
        box: the boxed coordinates uniform in it (as units), mapped back to normals; the rest as drawn."""
        x = rng.standard_normal((n, problem.dimension))
        s = len(problem.draws)
        for i, low, high in self.coordinates(problem):
            u = rng.uniform(low, high, n)
            x[:, i] = ndtri(u) if i < s else ndtri((u + 1.0) / 2.0)
        return x


def check_disjoint(strata: Sequence[Stratum], problem) -> None:
    """Refuse (one line) two strata whose boxes meet: their bounds would count the shared part twice. Two boxes
    are disjoint when some input both box has intervals that do not overlap (meeting at one end point is a
    null set)."""
    boxes = [{i: (low, high) for i, low, high in s.coordinates(problem)} for s in strata]
    for a in range(len(boxes)):
        for b in range(a + 1, len(boxes)):
            shared = boxes[a].keys() & boxes[b].keys()
            if not any(boxes[a][i][1] <= boxes[b][i][0] or boxes[b][i][1] <= boxes[a][i][0] for i in shared):
                raise RunError(f"strata {strata[a].name!r} and {strata[b].name!r} overlap: give them an input whose "
                               "ranges do not meet (a burst sub-range each, say), or merge them")


@dataclass(frozen=True)
class StratumCount:
    """A stratum's P(R) and its k events in n episodes."""

    name: str
    probability: float
    events: int
    episodes: int


@dataclass(frozen=True)
class Bound:
    """``lower``: the lower bound on P(event) at ``level`` (Bonferroni over the strata); ``point``: the strata's
    contribution sum P(R_i) k_i / n_i (an unbiased estimate of P(event and some R_i)); ``per_stratum``: each
    stratum's (lower bound at the corrected level, point)."""

    lower: float
    point: float
    level: float
    per_stratum: tuple[tuple[float, float], ...]


def clopper_pearson_lower(k: int, n: int, level: float) -> float:
    """The exact one-sided lower confidence bound of a binomial rate (0 when k = 0): the lower end of the
    two-sided Clopper-Pearson interval at level 2 level - 1."""
    low, _ = clopper_pearson_arrays(k, n, 2.0 * level - 1.0)
    return float(low)


def lower_bound(counts: Sequence[StratumCount], level: float = 0.95) -> Bound:
    """The exact lower bound of the module docstring from each stratum's count."""
    if not counts:
        raise ValueError("a lower bound needs at least one stratum")
    each = 1.0 - (1.0 - level) / len(counts)
    per = tuple((c.probability * clopper_pearson_lower(c.events, c.episodes, each),
                 c.probability * c.events / c.episodes if c.episodes else math.nan) for c in counts)
    return Bound(sum(lo for lo, _ in per), sum(pt for _, pt in per), level, per)


def load_strata(path: Path) -> list[Stratum]:
    """The strata of a TOML file (``[[stratum]]`` tables: ``name``, ``episodes``, ``draws = {NAME = [low,
    high]}``, ``units = [{step = K, channel = "front_y", range = [low, high]}]``); one line (RunError) naming
    what is wrong."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as err:
        raise RunError(f"{path}: cannot read the strata: {err}") from None
    tables = data.get("stratum")
    if not isinstance(tables, list) or not tables:
        raise RunError(f"{path}: no [[stratum]] table")
    return [_stratum(path, i, t) for i, t in enumerate(tables)]


def _stratum(path: Path, i: int, t: dict) -> Stratum:
    at = f"{path}: stratum {i}"
    unknown = set(t) - {"name", "episodes", "draws", "units"}
    if unknown:
        raise RunError(f"{at}: unknown key(s) {', '.join(sorted(unknown))} (known: name, episodes, draws, units)")
    episodes = t.get("episodes")
    if not isinstance(episodes, int) or isinstance(episodes, bool) or episodes < 1:
        raise RunError(f"{at}: episodes must be a positive integer, got {episodes!r}")
    draws = []
    for name, rng in (t.get("draws") or {}).items():
        low, high = _pair(f"{at}: draws.{name}", rng)
        draws.append((str(name), low, high))
    units = []
    for j, u in enumerate(t.get("units") or []):
        where = f"{at}: units[{j}]"
        if not isinstance(u, dict) or set(u) != {"step", "channel", "range"}:
            raise RunError(f"{where}: needs exactly step, channel and range")
        if not isinstance(u["step"], int) or isinstance(u["step"], bool) or u["step"] < 0:
            raise RunError(f"{where}: step must be a control step (integer >= 0), got {u['step']!r}")
        if u["channel"] not in CHANNELS:
            raise RunError(f"{where}: channel must be one of {', '.join(CHANNELS)}, got {u['channel']!r}")
        low, high = _pair(f"{where}.range", u["range"])
        if not -1.0 <= low < high <= 1.0:
            raise RunError(f"{where}.range must lie in [-1, 1] with low < high, got [{low:g}, {high:g}]")
        units.append(UnitBox(u["step"], u["channel"], low, high))
    if not draws and not units:
        raise RunError(f"{at}: boxes nothing (give draws or units)")
    return Stratum(str(t.get("name", f"stratum {i}")), tuple(draws), tuple(units), episodes)


def _pair(where: str, value: object) -> tuple[float, float]:
    ok = isinstance(value, list) and len(value) == 2 and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if not ok or not value[0] < value[1]:
        raise RunError(f"{where} must be [low, high] with low < high, got {value!r}")
    return float(value[0]), float(value[1])
