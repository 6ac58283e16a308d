"""``mcverify falsify --method beam``: the folder and report it writes, a resume after an interruption that ends
where the uninterrupted search ends, one-line refusals of bad [falsify.beam] tables, and a dry run that runs
nothing (the real closed loop on tests/falsify/test_beam.py's 30-step episode)."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json

import pyarrow.parquet as pq
import pytest

from mcverify import cli
from mcverify.cli import falsify as cli_falsify
from mcverify.falsify import beam, beam_folder, methods
from mcverify.schema import TIMING_COLUMNS

HEAD = ('[campaign]\nname = "beam-cli"\nseed = 3\nepisodes = {episodes}\n'
        '[model.sim]\ncontrol_period_s = 0.1\nsubsteps = 20\nmax_time_s = 3.0\n'
        '[model.scenario]\nfront_x_m = 30.0\n[falsify]\nrequirement = "ellipse"\n')
# test_beam.py's SPEC in seconds: steps [5, 15), segments of 5, branching 2, width 2 (with --seed 7)
BEAM = ('[falsify.beam]\nwindow_s = [0.5, 1.5]\nsegment_s = 0.5\nbranching = 2\nwidth = 2\n'
        'channels = ["front_x", "front_y"]\n')
# the prefix (5 steps), 2 + 4 children of 5 steps, the best frontier node run from step 15 to the limit (30)
BOUND_STEPS = 5 + 10 + 20 + 15
# what one beam spends when the budget left covers both frontier nodes' runs (both time out at step 29)
BEAM_STEPS = 5 + 10 + 20 + 2 * 15


def _campaign(tmp_path, beam_table: str = BEAM, episodes: int = 1, extra: str = "") -> str:
    path = tmp_path / "beam.toml"
    path.write_text(HEAD.format(episodes=episodes) + extra + beam_table)
    return str(path)


def _args(campaign: str, out, *more: str) -> list[str]:
    return ["falsify", campaign, "--method", "beam", "--budget", "3", "--seed", "7", "--run-dir", str(out), *more]


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """An uninterrupted CLI beam search: (folder, its stderr lines)."""
    tmp = tmp_path_factory.mktemp("beam-cli")
    out, err = tmp / "whole", io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        assert cli.main(_args(_campaign(tmp), out)) == 0
    return out, err.getvalue().splitlines()


def test_a_beam_search_writes_its_folder_report_and_replayable_best(whole, capsys):
    out, lines = whole
    assert json.loads((out / "falsify.json").read_text())["finished_utc"]
    assert sorted(p.name for p in (out / "beam" / "restart-00").glob("depth-*.npz")) == ["depth-001.npz",
                                                                                         "depth-002.npz"]
    assert not (out / "beam" / "restart-01").exists()  # a second beam's bound does not fit the budget left
    assert [line.split(":")[0] for line in lines if line.startswith("beam depth")] == ["beam depth 1/2",
                                                                                        "beam depth 2/2"]
    summary = beam_folder.read_summary(out)
    # both frontier episodes time out at step 29 (test_beam.py), and the budget (90 steps) covers both runs
    assert summary.search_steps == BEAM_STEPS and summary.episode_equivalents == BEAM_STEPS / 30
    assert len(summary.restarts[0].frontier) == 2
    assert [d[2] for d in summary.restarts[0].depth_log] == [15, 35] and summary.peak_snapshots <= 5
    row = pq.read_table(out / "best" / "episodes.parquet").to_pylist()[0]
    assert row["min_h_front"] == summary.best_robustness  # ellipse's robustness is min h_ef
    report = (out / "report.md").read_text()
    for part in ("## Restarts", "| 0 (chosen) |", "## Depths of restart 0", "## Final frontier of restart 0",
                 "(best)", f"{BEAM_STEPS} control steps", f"cost bound {BOUND_STEPS} control steps per beam",
                 f"mcverify replay {out / 'best'} 0", f"mcverify replay {out / 'best'} 0 --backend ipopt",
                 "control steps [5, 15) = [0.5, 1.5) s"):
        assert part in report, part
    (out / "report.md").unlink()  # `mcverify report` rewrites it from beam/result.json, running nothing
    assert cli.main(["report", str(out)]) == 0
    assert (out / "report.md").read_text() == report
    capsys.readouterr()
    assert cli.main(["replay", str(out / "best"), "0"]) == 0  # bit for bit, from step 0


def test_resume_after_an_interruption_ends_where_the_uninterrupted_search_ends(whole, tmp_path, monkeypatch, capsys):
    real = beam.search

    def interrupted(campaign, spec, out_dir, *, allowance_steps=None, stop_after_depths=None, progress=None):
        def cut(line: str) -> None:  # Ctrl-C right after the first depth file is written
            raise KeyboardInterrupt

        return real(campaign, spec, out_dir, allowance_steps=allowance_steps, progress=cut)

    out = tmp_path / "cut"
    monkeypatch.setattr(beam, "search", interrupted)
    assert cli.main(_args(_campaign(tmp_path), out)) == 130
    assert "finished depths are kept (mcverify falsify --resume" in capsys.readouterr().err
    monkeypatch.setattr(beam, "search", real)
    assert cli.main(["falsify", "--resume", str(out)]) == 0
    assert "1 depth(s) already stored" in capsys.readouterr().err
    a, b = beam_folder.read_summary(whole[0]), beam_folder.read_summary(out)
    assert b.rebuild_steps == 2 * 10  # the two frontier nodes re-simulated to the end of depth 1
    assert dataclasses.replace(a.restarts[0], rebuild_steps=0) == dataclasses.replace(b.restarts[0], rebuild_steps=0)
    rows = [pq.read_table(d / "best" / "episodes.parquet").to_pylist()[0] for d in (out, whole[0])]
    differ = [k for k in rows[1] if k not in TIMING_COLUMNS and rows[0][k] != rows[1][k]
              and not (rows[0][k] != rows[0][k] and rows[1][k] != rows[1][k])]  # NaN equals NaN
    assert differ == []
    assert cli.main(["falsify", "--resume", str(out)]) == 0  # finished: says so, runs nothing
    assert "already complete" in capsys.readouterr().out


def test_without_a_counterexample_the_beam_restarts_while_the_budget_covers_another_bound(whole, tmp_path,
                                                                                          monkeypatch, capsys):
    """Budget 5 (150 steps): restart 0 spends 65 and finds nothing, 65 + the bound 50 <= 150 so restart 1 runs
    with new draws, and 130 + 50 > 150 ends the search. Cut inside restart 1 and resumed, it ends the same."""
    first = beam_folder.read_summary(whole[0])
    assert first.best_robustness >= 0.0  # the test episode has no counterexample
    real = beam.search

    def cut_in_restart_1(campaign, spec, folder, *, allowance_steps=None, stop_after_depths=None, progress=None):
        if spec.restart == 1:  # RunError after its first depth
            return real(campaign, spec, folder, allowance_steps=allowance_steps, stop_after_depths=1)
        return real(campaign, spec, folder, allowance_steps=allowance_steps, progress=progress)

    out = tmp_path / "restarts"
    monkeypatch.setattr(beam, "search", cut_in_restart_1)
    assert cli.main([*_args(_campaign(tmp_path), out), "--budget", "5"]) == 2
    monkeypatch.setattr(beam, "search", real)
    assert cli.main(["falsify", "--resume", str(out)]) == 0
    assert "3 depth(s) already stored" in capsys.readouterr().err  # restart 0's two, restart 1's first
    summary = beam_folder.read_summary(out)
    assert [r.restart for r in summary.restarts] == [0, 1] and summary.search_steps == 2 * BEAM_STEPS
    assert summary.restarts[0] == first.restarts[0]  # restart 0 is the budget-3 search, re-read after the cut
    assert summary.restarts[1].frontier != summary.restarts[0].frontier  # new draws of every child
    robs = [r.best_robustness for r in summary.restarts]
    assert summary.chosen == robs.index(min(robs)) and summary.best_robustness == min(robs)
    row = pq.read_table(out / "best" / "episodes.parquet").to_pylist()[0]
    assert row["min_h_front"] == summary.best_robustness
    report = (out / "report.md").read_text()
    assert f"| {summary.chosen} (chosen) |" in report and "over 2 restart(s)" in report
    assert cli.main(["replay", str(out / "best"), "0"]) == 0


BAD = [
    (BEAM + "beam_width = 3\n", {}, "unknown key 'beam_width'"),
    (BEAM.replace("[0.5, 1.5]", "[0.5, 9.0]"), {}, "must lie in the episode, [0, 3] s"),
    (BEAM.replace("[0.5, 1.5]", "[1.5, 0.5]"), {}, "window_s: expected [a, b]"),
    (BEAM.replace("segment_s = 0.5", "segment_s = 0.01"), {}, "rounds to no control step"),
    (BEAM + 'score = "gap"\n', {}, "score: expected one of h_front, theorem5"),
    (BEAM.replace("width = 2", "width = 0"), {}, "width: expected an integer from 1"),
    (BEAM, {"episodes": 2}, "the beam searches one episode"),
    ("[falsify.bounds]\n\"scenario.front_speed_mps\" = [5.0, 9.0]\n", {}, "needs a [falsify.beam] table"),
    (BEAM, {"extra": "population = 4\n"}, "takes only requirement and [falsify.beam]; remove population"),
]


def test_the_other_final_nodes_run_only_while_the_budget_left_covers_a_run(whole, tmp_path):
    """Budget 2 (60 steps) covers the bound (50): the best final node runs (35 + 15 = 50 steps), the second
    would need 15 more, beyond 60, so it is not run and the beam ends on the best node alone."""
    out = tmp_path / "tight"
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        assert cli.main([*_args(_campaign(tmp_path), out), "--budget", "2"]) == 0
    summary, roomy = beam_folder.read_summary(out), beam_folder.read_summary(whole[0])
    assert summary.search_steps == BOUND_STEPS and len(summary.restarts) == 1
    assert summary.restarts[0].frontier == roomy.restarts[0].frontier[:1]  # the same beam, its best node only


@pytest.mark.parametrize(("table", "kw", "message"), BAD)
def test_a_bad_beam_campaign_is_one_line(tmp_path, capsys, table, kw, message):
    out = tmp_path / "out"
    assert cli.main(_args(_campaign(tmp_path, table, **kw), out)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mcverify: error:") and message in err, err
    assert not out.exists()


@pytest.mark.parametrize(("more", "message"), [
    (["--budget", "1"], "may spend up to 1.67 episode-equivalents (50 control steps of 30 per episode); give "
                        "--budget 2"),
    (["--workers", "2"], "drop --executor and --workers"),
])
def test_a_budget_below_the_bound_and_workers_are_refused(tmp_path, capsys, more, message):
    assert cli.main([*_args(_campaign(tmp_path), tmp_path / "out"), *more]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err


def test_other_methods_refuse_a_beam_only_campaign(tmp_path, capsys):
    args = ["falsify", _campaign(tmp_path), "--method", "cma", "--budget", "4", "--run-dir", str(tmp_path / "o")]
    assert cli.main(args) == 2
    assert "searches with [falsify.beam] only (--method beam)" in capsys.readouterr().err


def test_a_dry_run_describes_the_beam_and_runs_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    assert cli.main([*_args(_campaign(tmp_path), out), "--dry-run"]) == 0
    text = capsys.readouterr().out
    for part in ("2 depth(s)", "children per depth (at most): 2, 4 (6 in all)", f"cost bound: {BOUND_STEPS} control "
                 "steps = 1.67 episode-equivalents", "budget 3 episode-equivalents"):
        assert part in text, part
    assert not out.exists()
    assert cli.main(["run", _campaign(tmp_path), "--dry-run"]) == 0  # run's dry run checks the table too
    assert "[falsify.beam]: requirement ellipse, 2 depth(s)" in capsys.readouterr().out


def test_the_cli_methods_are_the_searchers_and_the_beam(capsys):
    assert cli_falsify.METHODS == (*methods.METHODS, beam.BEAM)
    assert cli.main(["falsify", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "beam: a beam search over the per-step error" in text and "--method beam: a ceiling in episode-" in text
