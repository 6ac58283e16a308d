"""The campaign guide's field table (docs/campaigns.md) is generated from the model's field docstrings
and cannot drift: every field documented, the copy equal to `mcverify fields`."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from mcverify import cli, fields, model
from mcverify.campaign.overrides import model_fields

GUIDE = Path(__file__).resolve().parent.parent / "docs" / "campaigns.md"


def test_every_field_has_a_docstring_and_a_row():
    docs = fields.field_docs()
    assert [d for d in docs if not d.doc] == []
    settable = {k for k in model_fields() if k not in fields.UNIT_ALIASES}
    assert {d.key for d in docs} == settable
    n = sum(len(dataclasses.fields(f.default_factory())) for f in dataclasses.fields(model.ModelParams))
    assert len(docs) == n


def test_units_defaults_and_types_come_from_the_code():
    by_key = {d.key: d for d in fields.field_docs()}
    assert (by_key["road.lane_width_m"].unit, by_key["road.lane_width_m"].default) == ("m", "3.5")
    assert by_key["scenario.front_accel_duration_s"].default == "inf"
    assert by_key["barrier.lambdas_m"].unit == "" and by_key["barrier.lambdas_m"].type == "list of floats"
    assert by_key["mpc.horizon"].type == "int" and by_key["mpc.backend"].default == '"ipm"'
    assert by_key["opposing.cruise_gain_per_s"].unit == "1/s"


def test_the_guide_holds_the_generated_table():
    text = GUIDE.read_text()
    assert fields.markdown_table() in text, "regenerate docs/campaigns.md: mcverify.fields.markdown_table()"


def test_mcverify_fields_prints_the_table_and_filters(capsys):
    assert cli.main(["fields"]) == 0
    assert capsys.readouterr().out.strip() == fields.markdown_table()
    assert cli.main(["fields", "noise."]) == 0
    rows = capsys.readouterr().out.strip().splitlines()[2:]
    assert rows and all(r.startswith("| `noise.") for r in rows)
    assert cli.main(["fields", "nope"]) == 2
