"""Every settable model field of a campaign, documented from the field docstrings of
:mod:`mcverify.model` (the string under each field): ``mcverify fields`` prints the table, and
``docs/campaigns.md`` holds it (``tests/test_fields.py`` keeps the two equal, and fails on a field
without a docstring), so the guide cannot drift from the code.

A field's unit comes from its name's suffix (``_m``, ``_mps``, ...), its default from the dataclass;
the docstring gives its meaning, its valid values ("Valid: ...") and the paper's value ("Paper: ...").
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import math
from dataclasses import dataclass

from mcverify import model

#: Name suffix -> unit (the model's naming convention).
UNIT_SUFFIXES = (("_mps2", "m/s^2"), ("_mps", "m/s"), ("_kmh", "km/h"), ("_rad", "rad"), ("_per_s", "1/s"),
                 ("_s", "s"), ("_m", "m"))
#: Fields that may also be given in another unit, converted on load (:mod:`mcverify.campaign.overrides`):
#: alias -> (field, factor).
UNIT_ALIASES: dict[str, tuple[str, float]] = {
    "scenario.front_speed_kmh": ("scenario.front_speed_mps", 1.0 / 3.6),
    "scenario.ego_speed_kmh": ("scenario.ego_speed_mps", 1.0 / 3.6),
    "ego.speed_max_kmh": ("ego.speed_max_mps", 1.0 / 3.6),
}


@dataclass(frozen=True)
class FieldDoc:
    key: str        # section.field, as written in [model.section] or a grid axis
    type: str       # float, int, str, list of floats, float or unset
    unit: str       # from the name's suffix; empty for dimensionless values
    default: str
    doc: str        # the field docstring, whitespace collapsed


def field_docs() -> list[FieldDoc]:
    """One entry per field of every section of :class:`~mcverify.model.ModelParams`, in model order."""
    out = []
    for section in dataclasses.fields(model.ModelParams):
        cls = type(section.default_factory())  # type: ignore[misc]
        docs = _docstrings(cls)
        instance = cls()
        for f in dataclasses.fields(cls):
            value = getattr(instance, f.name)
            out.append(FieldDoc(f"{section.name}.{f.name}", _type(f.type), unit_of(f.name), _show(value),
                                docs.get(f.name, "")))
    return out


def unit_of(name: str) -> str:
    if name.endswith("lambdas_m"):  # the m of "order m", not metres: lambda_i's units depend on h's
        return ""
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return ""


def markdown_table() -> str:
    """The fields as a Markdown table (what ``mcverify fields`` prints and docs/campaigns.md holds)."""
    lines = ["| field | type | unit | default | meaning, valid values, the paper's value |", "|---|---|---|---|---|"]
    for d in field_docs():
        lines.append(f"| `{d.key}` | {d.type} | {d.unit} | {d.default} | {d.doc.replace('|', '/')} |")
    return "\n".join(lines)


def _docstrings(cls: type) -> dict[str, str]:
    """Field name -> the string literal right under its annotated assignment in the class body."""
    tree = ast.parse(inspect.getsource(cls))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs = {}
    for stmt, nxt in zip(body, body[1:], strict=False):
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) and isinstance(nxt, ast.Expr) \
                and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str):
            docs[stmt.target.id] = " ".join(nxt.value.value.split())
    return docs


def _type(annotation: object) -> str:
    text = str(annotation)
    return {"float": "float", "int": "int", "str": "str", "tuple[float, ...]": "list of floats",
            "float | None": "float or unset"}.get(text, text)


def _show(value: object) -> str:
    if isinstance(value, float):
        return "inf" if math.isinf(value) else f"{value:.6g}"
    if isinstance(value, tuple):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if value is None:
        return "unset"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)
