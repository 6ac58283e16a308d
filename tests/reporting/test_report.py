"""mcverify.reporting.run_report: ``mcverify report RUN_DIR`` regenerates every report file from stored data,
byte for byte; the HTML page is self-contained; options and bad input."""

from __future__ import annotations

import base64
import json
import re
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import synthetic

from mcverify import cli
from mcverify.reporting import run_report

OUTPUTS = ("report.md", "report.html", "summary.json", "cells.parquet")


def _files(run_dir: Path) -> dict[str, bytes]:
    """Every report output of a run folder, by relative path."""
    out = {name: (run_dir / name).read_bytes() for name in OUTPUTS}
    for sub in ("tables", "figures"):
        out.update({f"{sub}/{p.name}": p.read_bytes() for p in sorted((run_dir / sub).iterdir())})
    return out


@pytest.fixture(scope="module")
def t4_run(tmp_path_factory) -> Path:
    """A Table IV-like run with opposing traffic and stored trajectories, reported once."""
    run = synthetic.make_run(tmp_path_factory.mktemp("t4") / "run", _small(synthetic.TABLE4), opposing=True,
                             trajectory_cells=(0, 4))
    run_report.write(run)
    return run


def _small(raw: dict, episodes: int = 12) -> dict:
    return {**raw, "campaign": {**raw["campaign"], "episodes": episodes}}


def test_report_reproduces_byte_for_byte(t4_run, tmp_path):
    # Acceptance: `mcverify report` on an existing run reproduces its tables byte for byte; here
    # every output (tables, figures, HTML, summary, cells.parquet), also from another folder path.
    before = _files(t4_run)
    assert cli.main(["report", str(t4_run)]) == 0
    assert _files(t4_run) == before
    moved = tmp_path / "elsewhere" / "copy"
    shutil.copytree(t4_run, moved)
    assert cli.main(["report", str(moved)]) == 0
    assert _files(moved) == before  # no absolute path or timestamp in any output


def test_report_contents(t4_run):
    md = (t4_run / "report.md").read_text()
    assert md.startswith("# mcverify report: t4\n")
    assert "### Table IV: minimum distance with surrounding vehicles" in md
    assert md.index("Table IV") < md.index("### Safety and outcomes per cell")  # the paper's layout first
    for table in ("paper-table-IV", "outcomes", "pivot-safe", "distances", "times", "theorem-checks", "solver"):
        assert (t4_run / "tables" / f"{table}.md").read_text() in md
        tex = (t4_run / "tables" / f"{table}.tex").read_text()
        assert r"\toprule" in tex and r"\bottomrule" in tex
    assert "collision veh_o" in md and "min dist. veh_o" in md  # opposing columns used when present
    solver = (t4_run / "tables" / "solver.md").read_text()
    assert "went back because" in solver and "Table I rows met" in solver and "row 1: " in solver
    thm = (t4_run / "tables" / "theorem-checks.md").read_text()
    assert "first unsafe step driven by" in thm and "h_eo breaches" in thm
    for f in re.findall(r"!\[[^]]*\]\((figures/[^)]+)\)", md):
        assert (t4_run / f).is_file()
    assert str(t4_run) not in md and "/tmp" not in md
    summ = json.loads((t4_run / "summary.json").read_text(), parse_constant=_no_nan)
    assert summ["campaign"] == "t4" and len(summ["cells"]) == 6
    cells = pq.read_table(t4_run / "cells.parquet")
    assert cells.num_rows == 6 and cells.column("label_method").to_pylist()[:3] == [
        "MPC-DC", "VL-CBF eps=0.3", "VL-CBF eps=0.5"]


def _no_nan(token: str):
    raise AssertionError(f"summary.json holds {token}: not strict JSON")


def test_html_is_self_contained(t4_run):
    page = (t4_run / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert "<script" not in page and not re.search(r"""(src|href)=["'](https?:|file:|/)""", page)
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    drawn = sorted((t4_run / "figures").glob("*.png"))
    assert len(images) == len(drawn) >= 7
    assert {base64.b64decode(i) for i in images} == {p.read_bytes() for p in drawn}
    assert page.count("<table") + page.count('<p class="table-title"') == len(list((t4_run / "tables").glob("*.md")))
    assert "Scenario A" in page and "<figcaption>" in page and 'id="definitions"' in page


def test_level_and_method_options(tmp_path):
    run = synthetic.make_run(tmp_path / "run", _small(synthetic.TABLE3, 10), trajectories=False)
    assert cli.main(["report", str(run), "--level", "0.9", "--method", "wilson",
                     "--bootstrap-resamples", "100"]) == 0
    summ = json.loads((run / "summary.json").read_text())
    assert (summ["confidence_level"], summ["interval_method"]) == (0.9, "wilson")
    assert summ["cells"][0]["rates"]["safe"]["method"] == "wilson"
    assert "two-sided 90% Wilson score" in (run / "report.md").read_text()


def test_missing_trajectories_and_plans_are_reported(tmp_path):
    run = synthetic.make_run(tmp_path / "none", _small(synthetic.TABLE3, 5), trajectories=False)
    run_report.write(run)
    md = (run / "report.md").read_text()
    assert "Trajectory snapshots, h(t) and speed profiles: not drawn: no stored trajectory" in md
    assert not list((run / "figures").glob("snapshots-*.png"))
    run2 = synthetic.make_run(tmp_path / "noplans", _small(synthetic.TABLE3, 5), plans_files=False)
    (run2 / "trajectories" / "episode-000005.parquet").unlink()  # cell 1 loses its trajectory
    run_report.write(run2)
    md2 = (run2 / "report.md").read_text()
    assert "planned trajectories not stored for this episode (no plans file)" in md2
    assert "no stored trajectory for 1 cell(s): front_accel_range_mps2=[3,5]" in md2
    assert sorted(p.name for p in (run2 / "figures").glob("snapshots-*.png")) == [
        "snapshots-cell-000.png", "snapshots-cell-002.png"]


def test_replay_trajectories_are_used_when_no_trajectories_folder(tmp_path):
    run = synthetic.make_run(tmp_path / "r", _small(synthetic.TABLE3, 5), plans_files=False)
    (run / "trajectories" / "episode-000005.parquet").rename(run / "replay.parquet")
    (run / "replay").mkdir()
    (run / "replay.parquet").rename(run / "replay" / "episode-000007.parquet")  # replayed: episode 7 of cell 1
    run_report.write(run)
    md = (run / "report.md").read_text()
    assert "Episode 7 (replay/episode-000007.parquet)" in md


def test_errors_are_counted_apart_in_the_report(tmp_path):
    run = synthetic.make_run(tmp_path / "e", _small(synthetic.TABLE3, 20), trajectories=False,
                             probs=lambda c: {"unsafe": 0.1, "overtook": 0.5, "went_back": 0.4, "error": 0.2})
    run_report.write(run)
    outcomes = (run / "tables" / "outcomes.md").read_text()
    assert "| errors |" in outcomes.splitlines()[2]
    summ = json.loads((run / "summary.json").read_text())
    c = summ["cells"][0]
    assert c["rates"]["safe"]["n"] == c["valid"] == c["episodes"] - c["outcomes"]["error"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["report", "{missing}"], "run folder not found"),
        (["report", "{empty}"], "not an mcverify run folder"),
        (["report", "{run}", "--level", "95"], None),  # argparse: usage + one error line
        (["report", "{run}", "--method", "wald"], None),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, argv, message):
    run = synthetic.make_run(tmp_path / "run", _small(synthetic.TABLE3, 3), trajectories=False)
    (tmp_path / "empty").mkdir()
    args = [a.format(missing=tmp_path / "nope", empty=tmp_path / "empty", run=run) for a in argv]
    try:
        code = cli.main(args)
    except SystemExit as exit_:  # argparse rejects the argument itself
        code = exit_.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "Traceback" not in "\n".join(err)
    if message:
        assert len(err) == 1 and message in err[0]


def test_theorem_five_findings_list_every_episode_with_the_replay_command(tmp_path):
    raw = _small(synthetic.TABLE3, episodes=10)
    run = synthetic.make_run(tmp_path / "run", raw, probs=lambda cell: {**synthetic.default_probs(cell), "unsafe": 0.4},
                             opposing=True, trajectories=False)
    run_report.write(run)
    episodes = pq.read_table(run / "episodes.parquet").to_pylist()
    flagged = [e for e in episodes if e["both_infeasible_steps"] > 0]
    assert flagged and any(e["both_certified_infeasible_steps"] for e in flagged)
    findings = (run / "tables" / "theorem-findings.md").read_text()
    for e in flagged:
        line = next(x for x in findings.splitlines() if f"mcverify replay {run} {e['episode_id']} " in x)
        assert e["cell"] in line
        assert f"| {e['both_certified_infeasible_steps']} | {e['both_unsolved_uncertified_steps']} |" in line
    assert findings.count(f"mcverify replay {run} ") == len(flagged)  # the folder as given, as for counterexamples
    assert findings in (run / "report.md").read_text()
    thm = (run / "tables" / "theorem-checks.md").read_text()
    assert "both certified infeasible" in thm and "longest run" in thm
    summ = json.loads((run / "summary.json").read_text())
    assert sum(c["theorem_checks"]["both_certified_infeasible_steps"] for c in summ["cells"]) == sum(
        e["both_certified_infeasible_steps"] for e in flagged)
    solver = (run / "tables" / "solver.md").read_text()
    assert "Q1 failures: certified / presumed / iteration limit / other" in solver


def test_no_findings_table_without_such_steps(tmp_path):
    run = synthetic.make_run(tmp_path / "run", _small(synthetic.TABLE3, episodes=4), trajectories=False)
    run_report.write(run)
    assert not (run / "tables" / "theorem-findings.md").exists()
    assert "Theorem 5 findings: episodes" not in (run / "report.md").read_text()
