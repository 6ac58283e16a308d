"""The second new-user audit (stop 40): what a user tripped over in the benchmarks, the dry runs and
the folders that are not runs, each now one clear line (exit 2) or a report that says why."""

from __future__ import annotations

import synthetic

from mcverify import cli
from mcverify.falsify import search
from tests.falsify import fake_episodes
from tests.test_command_line_mistakes import CAMPAIGN, _one_error_line


def _kw():
    from mcverify.campaign import executors  # noqa: PLC0415

    return {"make_executor": executors.SerialExecutor, "episode_fn": fake_episodes.episodes}


def test_the_serial_executor_refuses_workers(tmp_path, capsys):
    code = cli.main(["estimate", "campaigns/smoke.toml", "--method", "mc", "--budget", "1", "--executor", "serial",
                     "--workers", "2", "--run-dir", str(tmp_path / "e")])
    assert code == 2 and "--workers 2 is for the local and Ray executors" in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "e").exists()


def test_dry_runs_check_the_falsify_table(tmp_path, capsys):
    good, bad = tmp_path / "good.toml", tmp_path / "bad.toml"
    good.write_text(CAMPAIGN)
    bad.write_text(CAMPAIGN.replace("[5.0, 9.0]", "[5.0, 90.0]"))
    assert cli.main(["run", str(good), "--dry-run"]) == 0
    assert "[falsify]: requirement ellipse, 1 searched field(s), every bound within" in capsys.readouterr().out
    assert cli.main(["run", str(bad), "--dry-run"]) == 2
    out = capsys.readouterr()
    assert out.out == "" and "at its upper bound 90" in _one_error_line(out.err)
    assert cli.main(["falsify", str(good), "--budget", "16", "--dry-run", "--run-dir", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert "random" not in out and "cma, budget 16 episodes, requirement ellipse, seed 11" in out
    assert "search space: 1 field(s): scenario.front_speed_mps" in out and "estimated CPU" in out
    assert not (tmp_path / "s").exists(), "a dry run makes no folder"
    assert cli.main(["falsify", str(bad), "--budget", "16", "--dry-run"]) == 2
    assert "at its upper bound 90" in _one_error_line(capsys.readouterr().err)


def test_a_search_report_says_why_it_stopped_before_its_budget(tmp_path):
    raw = {"campaign": {"name": "fz", "seed": 11, "episodes": 1},
           "falsify": {"requirement": "ellipse", "population": 4, "bounds": {"scenario.front_speed_mps": [5.0, 9.0]}}}
    config = search.SearchConfig(raw=raw, source="<test>", method="random", budget=400, seed=3, requirement="ellipse")
    res = search.start(config, tmp_path / "s", **_kw())
    assert res.first_counterexample is not None and res.episodes < 400
    assert "it stopped after the generation that found its first counterexample (`[falsify] stop_at_first`" in (
        tmp_path / "s" / "report.md").read_text()


def test_folders_that_are_not_runs_say_what_they_are(tmp_path, capsys):
    est = tmp_path / "est"
    est.mkdir()
    (est / "manifest.json").write_text('{"campaign": {"name": "x"}, "cells": [], "estimate": {"method": "splitting"}}')
    (est / "estimate.json").write_text('{"spec": {"method": "splitting"}, "cells": []}')
    assert cli.main(["report", str(est)]) == 2  # report rebuilds such a folder's report once it is complete
    assert f"is not complete: `mcverify estimate --resume {est}` finishes it" in _one_error_line(
        capsys.readouterr().err)
    assert cli.main(["compare", str(est), str(est)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "it is an `estimate --method splitting` folder, which stores its estimate" in line
    assert f"`mcverify replay {est} K [--cell NAME]` replays one" in line
    assert cli.main(["replay", str(est), "0"]) == 2  # replay knows the folder: nothing estimated yet
    assert "no cell is estimated yet: nothing to replay" in _one_error_line(capsys.readouterr().err)
    fal = tmp_path / "fal"
    fal.mkdir()
    (fal / "falsify.json").write_text("{}")
    assert cli.main(["report", str(fal)]) == 2
    assert f"is not complete: `mcverify falsify --resume {fal}` finishes it" in _one_error_line(
        capsys.readouterr().err)
    assert cli.main(["compare", str(fal), str(fal)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "it is a falsification search" in line and f"`mcverify report {fal}` rebuilds its report" in line


def test_theorem_five_findings_name_the_folder_as_the_counterexamples_do(tmp_path):
    from mcverify.reporting import run_report  # noqa: PLC0415

    raw = {**synthetic.TABLE3, "campaign": {**synthetic.TABLE3["campaign"], "episodes": 6}}
    run = synthetic.make_run(tmp_path / "run", raw, opposing=True, trajectories=False,
                             probs=lambda cell: {**synthetic.default_probs(cell), "unsafe": 0.4})
    run_report.write(run)
    text = (run / "tables" / "theorem-findings.md").read_text()
    assert "RUN_DIR" not in text and f"mcverify replay {run} " in text


def test_an_interrupt_says_what_the_folder_keeps(tmp_path):
    folder = tmp_path / "e"
    folder.mkdir()
    assert cli._what_is_kept("run", folder) == "finished chunks are kept"
    for method, kept in (("splitting", "finished AMS runs are kept"),
                         ("importance", "finished cells and the finished batches of the cell in progress are kept"),
                         ("mc", "finished chunks are kept")):
        (folder / "manifest.json").write_text(f'{{"estimate": {{"method": "{method}"}}}}')
        assert cli._what_is_kept("estimate", folder) == kept
