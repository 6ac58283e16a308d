"""The episode-row contract (mcverify.schema): the README's metric table, rows and recordings agree with it."""

from __future__ import annotations

import pickle
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from mcverify import schema
from mcverify.analysis import summary
from mcverify.analysis.metrics import VALUE_METRICS
from mcverify.campaign.spec import campaign_from_dict
from mcverify.episode.recording import EpisodeRecording
from mcverify.episode.row import error_row, identity

README = Path(__file__).resolve().parent.parent / "docs" / "metrics.md"  # the metric table lives there
_ROW = re.compile(r"^\| `(?P<name>[^`]+)` \| (?P<type>[^|]*) \| (?P<unit>[^|]*) \| (?P<definition>.*) \|$")


def readme_metric_table() -> list[dict[str, str]]:
    """The rows of the table in the README's "Metrics" section."""
    text = README.read_text()
    section = text.split("## Metrics (`episodes.parquet`", 1)[1].split("\n## ", 1)[0]
    return [m.groupdict() for line in section.splitlines() if (m := _ROW.match(line.strip()))]


def test_the_readme_lists_exactly_the_declared_columns_with_their_types_and_units():
    listed = readme_metric_table()
    assert [r["name"] for r in listed] == list(schema.COLUMN_NAMES)
    declared = {c.name: c for c in schema.EPISODE_COLUMNS}
    for r in listed:
        c = declared[r["name"]]
        assert (r["type"].strip(), r["unit"].strip()) == (str(c.type), c.unit), r["name"]


def test_the_readme_table_is_the_rendered_schema():
    text = README.read_text()
    assert schema.markdown_table() in text, "regenerate the table in docs/metrics.md: mcverify.schema.markdown_table()"


def test_schema_helpers():
    assert schema.IDENTITY_COLUMNS == ("episode_id", "cell_episode", "cell", "cell_index", "seed")
    assert schema.TIMING_COLUMNS == ("solve_time_mean_s", "solve_time_max_s")
    assert schema.COLUMN_NAMES[-1] == schema.ERROR_COLUMN
    assert len(set(schema.COLUMN_NAMES)) == len(schema.COLUMN_NAMES)
    assert schema.column("safe").type == pa.bool_()
    with pytest.raises(KeyError, match="not an episode column"):
        schema.column("nope")
    part = schema.arrow_schema({"safe", "episode_id"})
    assert part.names == ["episode_id", "safe"]  # file order, not the caller's
    assert schema.arrow_schema().names == list(schema.COLUMN_NAMES)


def test_every_column_the_summary_reads_is_declared():
    assert summary.summarised_columns() <= set(schema.COLUMN_NAMES)
    for m in VALUE_METRICS:
        assert m.unit.replace("²", "^2") == schema.column(m.name).unit, m.name


def test_error_rows_hold_identity_level_and_outcome_only():
    cell = campaign_from_dict({"campaign": {"name": "c", "seed": 5, "episodes": 3}}).cells[0]
    row = error_row(cell, 5, 2, "boom")
    assert set(row) <= set(schema.COLUMN_NAMES)
    assert {k: row[k] for k in schema.IDENTITY_COLUMNS} == identity(cell, 5, 2)
    assert row["outcome"] == schema.ERROR_OUTCOME and row[schema.ERROR_COLUMN] == "boom"


def test_recordings_pickle_and_round_trip_their_columns():
    rec = EpisodeRecording({"t_s": np.arange(3.0)}, {"t_s": np.zeros(2), "problem": np.array(["Q1", "Q2"])})
    back = pickle.loads(pickle.dumps(rec))
    assert back.to_columns().keys() == {"", "-plans"}
    assert EpisodeRecording.from_columns(back.to_columns()).plans["problem"].tolist() == ["Q1", "Q2"]
    assert EpisodeRecording({"t_s": np.arange(3.0)}).to_columns().keys() == {""}  # no plans recorded
