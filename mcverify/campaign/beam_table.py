"""The ``[falsify.beam]`` table of a campaign file: what ``mcverify falsify --method beam`` searches.

::

    [falsify]
    requirement = "theorem5_certified"   # judges the final frontier (as for every method)

    [falsify.beam]
    window_s = [4.0, 5.6]      # the adversary acts in [a, b) s of the episode (rounded to control steps)
    segment_s = 0.2            # each depth draws the next segment of this length (s; >= one control step)
    branching = 4              # children per frontier node and depth
    width = 4                  # frontier nodes kept per depth
    channels = ["front_y"]     # of front_x, front_y, front_v, opp_x, opp_v (default ["front_y"])
    units = "bang_bang"        # each step's sign per channel; "held": one sign per channel held through the
                               # segment; "uniform": each step's value in [-1, 1] (default "bang_bang")
    score = "theorem5"         # the running score nodes are ranked by: "h_front", "theorem5" or "safe"
                               # (default "h_front")
    front_share = 1.0          # veh_f's share of its noise bounds handed to the adversary (default 1)
    opp_share = 0.0            # veh_o's (default 1)

Times are in seconds so that a table keeps its meaning at another control period; the falsifier turns
them into control steps with the cell's period (:func:`mcverify.falsify.beam.spec_of`). The search itself
is :mod:`mcverify.falsify.beam`. Every problem is one :class:`CampaignError` line.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from mcverify.campaign.validate import _short
from mcverify.errors import CampaignError

#: Running scores a beam ranks nodes by: ``h_front`` (the lowest h_ef so far), ``theorem5`` (the lowest graded
#: Theorem 5 margin so far; +inf before any dual-planner step) and ``safe`` (the requirement's robustness so far:
#: the footprint gaps to veh_f and veh_o in h_ef's unit beside h_ef, so a beam can act on veh_o's channels).
SCORES: tuple[str, ...] = ("h_front", "theorem5", "safe")
#: How a child's units are drawn per channel: a sign per step, one sign held through the segment (a sustained
#: error, which a per-step draw almost never gives over a whole segment), or a uniform value in [-1, 1] per step.
UNITS: tuple[str, ...] = ("bang_bang", "held", "uniform")
#: Largest branching and width a table may ask for (a guard against a typo, not a tuned limit).
MAX_FAN = 1024
_REQUIRED = ("window_s", "segment_s", "branching", "width")
_OPTIONAL = ("channels", "units", "score", "front_share", "opp_share")


@dataclass(frozen=True)
class BeamShape:
    """A beam apart from its time window: how it branches and ranks its nodes, and what its adversary acts on
    (which channels, with which units, at which shares of the noise bounds). Declared once here, held by the
    table (times in seconds) and by :class:`mcverify.falsify.beam.BeamSpec` (times in control steps)."""

    branching: int
    width: int
    channels: tuple[str, ...] = ("front_y",)
    units: str = "bang_bang"
    score: str = "h_front"
    front_share: float = 1.0
    opp_share: float = 1.0


@dataclass(frozen=True)
class BeamTable:
    """A validated ``[falsify.beam]`` table (module docstring), times in seconds."""

    window_s: tuple[float, float]
    segment_s: float
    shape: BeamShape


def read_beam(table: Any, here: str) -> BeamTable:
    """Validate ``[falsify.beam]`` (``here``: where the ``[falsify]`` table is, for the messages)."""
    from mcverify.sim.schedule import CHANNELS  # noqa: PLC0415 - JAX only for a campaign with a beam

    at = f"{here}.beam"
    if not isinstance(table, Mapping):
        raise CampaignError(f"{at}: must be a table ({', '.join(_REQUIRED)}, ...)")
    for key in table:
        if key not in (*_REQUIRED, *_OPTIONAL):
            raise CampaignError(f"{at}: unknown key {_short(key)} (known: {', '.join((*_REQUIRED, *_OPTIONAL))})")
    missing = [k for k in _REQUIRED if k not in table]
    if missing:
        raise CampaignError(f"{at}: missing {', '.join(missing)} (window_s = [a, b], segment_s, branching, width)")
    window = table["window_s"]
    if (not isinstance(window, list) or len(window) != 2 or any(not _number(x) or x < 0 for x in window)
            or not window[0] < window[1]):
        raise CampaignError(f"{at}.window_s: expected [a, b] in seconds with 0 <= a < b, got {_short(window)}")
    segment = table["segment_s"]
    if not _number(segment) or segment <= 0:
        raise CampaignError(f"{at}.segment_s: expected a positive number of seconds, got {_short(segment)}")
    out: dict[str, Any] = {}
    for key in ("branching", "width"):
        v = table[key]
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_FAN:
            raise CampaignError(f"{at}.{key}: expected an integer from 1 to {MAX_FAN}, got {_short(v)}")
        out[key] = v
    channels = table.get("channels", ["front_y"])
    if (not isinstance(channels, list) or not channels or any(c not in CHANNELS for c in channels)
            or len(set(channels)) != len(channels)):
        raise CampaignError(f"{at}.channels: expected distinct names among {', '.join(CHANNELS)}, "
                            f"got {_short(channels)}")
    for key, known in (("units", UNITS), ("score", SCORES)):
        if key in table and table[key] not in known:
            raise CampaignError(f"{at}.{key}: expected one of {', '.join(known)}, got {_short(table[key])}")
        if key in table:
            out[key] = table[key]
    for key in ("front_share", "opp_share"):
        if key in table:
            v = table[key]
            if not _number(v) or not 0.0 <= v <= 1.0:
                raise CampaignError(f"{at}.{key}: expected a number in [0, 1], got {_short(v)}")
            out[key] = float(v)
    return BeamTable((float(window[0]), float(window[1])), float(segment),
                     BeamShape(channels=tuple(channels), **out))


def _number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v)
