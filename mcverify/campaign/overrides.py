"""The settable fields of a campaign's model: every ``section.field`` of
:class:`~mcverify.model.ModelParams` with its type (plus the fields given in other units), and the
typed, validated application of dotted overrides to a :class:`~mcverify.model.ModelParams`.

The campaign file's ``[model]`` tables, its grid values, its axis bundles and the command line's
``--set`` all name fields this way; every mistake is a one-line :class:`CampaignError`.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Mapping
from typing import Any

from mcverify.campaign.validate import _short, validate_params
from mcverify.errors import CampaignError
from mcverify.fields import UNIT_ALIASES
from mcverify.model import ModelParams


def model_fields() -> dict[str, type]:
    """Every settable ``section.field`` of ModelParams with its type, plus the unit aliases."""
    out: dict[str, type] = {}
    for sec in dataclasses.fields(ModelParams):
        sub = sec.default_factory()  # type: ignore[misc]
        for f in dataclasses.fields(sub):
            out[f"{sec.name}.{f.name}"] = type(getattr(sub, f.name)) if getattr(sub, f.name) is not None else float
    for alias in UNIT_ALIASES:
        out[alias] = float
    return out


def apply_overrides(params: ModelParams, overrides: Mapping[str, Any], where: str) -> ModelParams:
    """Return ``params`` with dotted ``section.field`` overrides applied, each type-checked."""
    known = model_fields()
    sections: dict[str, dict[str, Any]] = {}
    for key, value in overrides.items():
        if key not in known:
            raise CampaignError(f"{where}: unknown model field {_short(key)}{suggest(key, known)}")
        value = coerce(value, known[key], f"{where}: {key}")
        if key in UNIT_ALIASES:
            key, factor = UNIT_ALIASES[key]
            value = value * factor
        sec, name = key.split(".", 1)
        sections.setdefault(sec, {})[name] = value
    barrier = sections.get("barrier", {})
    if "lambda0" in barrier and "epsilon" in barrier:
        raise CampaignError(f"{where}: set barrier.epsilon or barrier.lambda0, not both (one defines the other)")
    # The level is given one way or the other: setting one clears the other's inherited value.
    if "lambda0" in barrier:
        barrier["epsilon"] = None
    elif "epsilon" in barrier:
        barrier["lambda0"] = None
    new = params
    for sec, values in sections.items():
        new = dataclasses.replace(new, **{sec: dataclasses.replace(getattr(new, sec), **values)})
    try:
        validate_params(new, where)
    except CampaignError as err:  # a value given in km/h is checked in m/s: say what the user wrote
        given = [f"{k} = {overrides[k]:g}" for k in overrides if k in UNIT_ALIASES
                 and UNIT_ALIASES[k][0] in str(err) and isinstance(overrides[k], int | float)]
        if given:
            raise CampaignError(f"{err} (given as {', '.join(given)})") from None
        raise
    return new


def flatten_model(model: Any, where: str) -> dict[str, Any]:
    """The ``[model.SECTION]`` tables as dotted ``section.field`` overrides (sections checked, fields not yet)."""
    if not isinstance(model, Mapping):
        raise CampaignError(f"{where} [model]: must be a table of sections, e.g. [model.barrier]")
    sections = {f.name for f in dataclasses.fields(ModelParams)}
    flat: dict[str, Any] = {}
    for sec, values in model.items():
        if sec not in sections:
            raise CampaignError(f"{where}: unknown model section [model.{sec}]{suggest(sec, sections)}")
        if not isinstance(values, Mapping):
            raise CampaignError(f"{where} [model.{sec}]: must be a table")
        for k, v in values.items():
            flat[f"{sec}.{k}"] = v
    return flat


def coerce(value: Any, expected: type, where: str) -> Any:
    """``value`` as a field of type ``expected`` (an int is a valid float; a list of numbers a tuple)."""
    if expected is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CampaignError(f"{where}: expected a number, got {type(value).__name__} {_short(value)}")
        return float(value)
    if expected is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise CampaignError(f"{where}: expected an integer, got {type(value).__name__} {_short(value)}")
        return value
    if expected is tuple:
        if not isinstance(value, list) or any(
            isinstance(x, bool) or not isinstance(x, int | float) for x in value
        ):
            raise CampaignError(f"{where}: expected a list of numbers, got {_short(value)}")
        return tuple(float(x) for x in value)
    if not isinstance(value, expected):
        raise CampaignError(
            f"{where}: expected {expected.__name__}, got {type(value).__name__} {_short(value)}"
        )
    return value


def suggest(key: str, valid) -> str:
    """A " (did you mean ...?)" hint naming the closest of ``valid``, or ""."""
    close = difflib.get_close_matches(key, list(valid), n=1, cutoff=0.5)
    return f" (did you mean {close[0]!r}?)" if close else ""
