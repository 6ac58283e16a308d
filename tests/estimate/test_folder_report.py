"""What an estimate folder of the splitting or importance method writes besides ``estimate.json``:
``summary.json`` (the results as a run folder's ``summary.json`` gives an estimate), ``report.html``
and, where the campaign sweeps a numeric axis such as ε, the estimates against it (issue 17: the
P(collision)-versus-ε figure shows estimates, not only bounds)."""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path

import pytest

from mcverify.campaign.spec import load_campaign
from mcverify.estimate import folder

SWEEP = """
[campaign]
name = "sweep"
seed = 5
episodes = 2
[model.sim]
control_period_s = 0.1
max_time_s = 1.0
[axes.noise."paper"]
"noise.scale" = 1.0
[axes.noise."2x paper"]
"noise.scale" = 2.0
[grid]
"barrier.epsilon" = [0.0, 0.1, 0.3]
"""

COLUMNS: list[folder.Column] = [("cell", lambda c: c["cell"]),
                                ("estimate", lambda c: folder.estimate_text(c["estimate"])),
                                ("interval", lambda c: folder.interval_text(c["low"], c["high"]))]


def _result(index: int, name: str, estimate: float, low: float, high: float) -> dict:
    return {"cell_index": index, "cell": name, "method": "splitting", "target": "collision", "estimate": estimate,
            "low": low, "high": high, "interval": "asymptotic: Student t on independent AMS replicates",
            "steps": 1000, "cpu_s": 10.0, "warnings": []}


@pytest.fixture
def sweep_folder(tmp_path: Path) -> tuple[Path, list]:
    source = tmp_path / "sweep.toml"
    source.write_text(SWEEP, encoding="utf-8")
    campaign = load_campaign(source)
    out = tmp_path / "est"
    folder.create(out, campaign, {"method": "splitting"}, None)
    return out, campaign.cells


def _write(out: Path, results: dict) -> None:
    folder.write(out, "mcverify splitting estimate: sweep", "the estimator, described",
                 {"method": "splitting", "target": "collision", "level": 0.95}, results, COLUMNS)


def test_summary_json_gives_the_estimates_as_a_run_folder_does(sweep_folder):
    out, cells = sweep_folder
    results = {0: _result(0, cells[0].name, 0.01, 0.004, 0.016), 4: _result(4, cells[4].name, 0.0, 0.0, 0.002)}
    _write(out, results)
    summ = json.loads((out / "summary.json").read_text())
    assert summ["kind"] == "estimate" and summ["campaign"] == "sweep" and not summ["finished"]
    assert summ["cells_expected"] == 6 and set(summ["axes"]) == {"noise", "epsilon"}
    est = summ["estimates"]
    assert est["spec"]["method"] == "splitting" and est["method_description"] == "the estimator, described"
    assert [c["cell_index"] for c in est["cells"]] == [0, 4]
    assert est["cells"][0]["estimate"] == 0.01 and est["cells"][1]["labels"] == cells[4].labels
    folder.finish(out)
    _write(out, results)
    assert json.loads((out / "summary.json").read_text())["finished"]


def test_the_estimates_are_drawn_against_epsilon_and_embedded_in_report_html(sweep_folder):
    out, cells = sweep_folder
    results = {i: _result(i, c.name, 0.02 / (1 + i), 0.01 / (1 + i), 0.03 / (1 + i)) for i, c in enumerate(cells)}
    results[5] = _result(5, cells[5].name, 0.0, 0.0, 0.001)  # an estimate of 0: its upper end, as a bound
    _write(out, results)
    png = out / "figures" / "estimate-vs-epsilon.png"
    assert png.is_file() and png.stat().st_size > 5000
    md = (out / "report.md").read_text()
    assert "![estimate-vs-epsilon](figures/estimate-vs-epsilon.png)" in md
    assert f"| {cells[0].name} | 0.02 | [0.01, 0.03] |" in md
    page = (out / "report.html").read_text()
    assert base64.b64encode(png.read_bytes()).decode("ascii") in page
    assert "Estimated collision probability against level ε of the VL-CBF" in page
    assert "6 of 6" in page and "mcverify estimate --resume" in page  # not finished: how to finish it


def test_a_folder_with_no_estimate_yet_says_why_there_is_no_figure(sweep_folder):
    out, cells = sweep_folder
    _write(out, {0: {**_result(0, cells[0].name, math.nan, math.nan, math.nan)}})
    assert not (out / "figures" / "estimate-vs-epsilon.png").exists()
    assert "not drawn: no cell has an estimate" in (out / "report.md").read_text()
    assert "not drawn: no cell has an estimate" in (out / "report.html").read_text()


def test_a_sweep_of_two_values_gets_its_figure(tmp_path):
    campaign = load_campaign(Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml")  # 2 speeds only
    out = tmp_path / "est"
    folder.create(out, campaign, {"method": "splitting"}, None)
    _write(out, {0: _result(0, campaign.cells[0].name, 0.01, 0.005, 0.015)})
    assert [p.name for p in (out / "figures").glob("estimate-vs-*")] == ["estimate-vs-front_speed_kmh.png"]
    assert (out / "report.html").is_file() and "1 of 2" in (out / "report.html").read_text()
