"""`mcverify report SEARCH_DIR --audit`: every counterexample of a search re-simulated with the reference
solver and judged on the search's requirement (mcverify.falsify.audit)."""

from __future__ import annotations

import json
from pathlib import Path

from mcverify import cli

CAMPAIGN = """
[campaign]
name = "tiny_audit"
description = "h_ef starts at 0.51 and falls below eps = 0.3 within 1 s: every episode breaks invariance."
seed = 11
episodes = 1

[model.sim]
control_period_s = 0.1
substeps = 20
max_time_s = 1.0

[model.noise]
kind = "paper"

[model.scenario]
front_x_m = 18.5
front_speed_kmh = 25

[falsify]
requirement = "invariance"
population = 2

[falsify.bounds]
"scenario.front_speed_kmh" = [24.0, 26.0]
"""


def test_report_audit_labels_every_counterexample_of_a_search(tmp_path: Path, capsys) -> None:
    campaign = tmp_path / "c.toml"
    campaign.write_text(CAMPAIGN)
    out = tmp_path / "s"
    assert cli.main(["falsify", str(campaign), "--method", "random", "--budget", "2", "--run-dir", str(out),
                     "--no-progress", "-q"]) == 0
    assert "reference solver" not in (out / "report.md").read_text()  # no audit yet: no column
    capsys.readouterr()
    assert cli.main(["report", str(out), "--audit"]) == 0
    said = capsys.readouterr().err
    assert said.count("auditing counterexample g000/") == 2 and "invariance violated" in said
    kept = json.loads((out / "generations" / "g000" / "audits.json").read_text())
    assert set(kept) == {"0", "1"} and all(e["requirement"] == "invariance" for e in kept.values())
    table = (out / "report.md").read_text().split("### Counterexamples (invariance)")[1].split("\n\n")[1]
    assert "| reference solver |" in table
    verdicts = ["confirmed (" if e["reference_violated"] else "solver-dependent (" for e in kept.values()]
    assert all(v in table for v in verdicts)
    assert cli.main(["report", str(out), "--audit"]) == 0  # nothing left to audit: none re-simulated
    assert "auditing" not in capsys.readouterr().err
