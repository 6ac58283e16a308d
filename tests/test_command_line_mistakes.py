"""What a new user of `mcverify falsify` and `mcverify estimate` sees: the first counterexample named by
the id its replay command takes, and command-line mistakes named as the option's, in one line, before
any folder is made (a new-user audit, stop 39)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import synthetic_episodes as synth

from mcverify import cli
from mcverify.campaign import executors, runner
from mcverify.campaign.spec import load_campaign
from mcverify.errors import CampaignError
from mcverify.falsify import search
from tests.falsify import fake_episodes

CAMPAIGN = ('[campaign]\nname = "fz"\nseed = 11\nepisodes = 1\n[falsify]\nrequirement = "ellipse"\n'
            'population = 4\n[falsify.bounds]\n"scenario.front_speed_mps" = [5.0, 9.0]\n')


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("mcverify: error: "), err
    return lines[0]


def test_the_first_counterexample_is_named_by_the_episode_id_its_replay_takes(tmp_path):
    raw = {"campaign": {"name": "fz", "seed": 11, "episodes": 1},
           "falsify": {"requirement": "ellipse", "population": 4, "stop_at_first": True,
                       "bounds": {"scenario.front_speed_mps": [5.0, 9.0], "opposing.speed_mps": [8.0, 19.0]}}}
    config = search.SearchConfig(raw=copy.deepcopy(raw), source="<test>", method="cma", budget=60, seed=3,
                                 requirement="ellipse")
    res = search.start(config, tmp_path / "s", make_executor=executors.SerialExecutor,
                       episode_fn=fake_episodes.episodes)
    count = res.first_counterexample
    assert count is not None
    first = res.evaluations[count - 1]
    assert first.robustness < 0 and all(e.robustness >= 0 for e in res.evaluations[:count - 1])
    text = res.first_counterexample_text()
    episode = int(first.row["episode_id"])  # 0-based within its generation, what `mcverify replay` takes
    gen_dir = tmp_path / "s" / search.GENERATIONS / f"g{first.generation:03d}"
    assert text.startswith(f"after {count} episode")
    assert f"generation {first.generation}, episode {episode} " in text
    assert f"mcverify replay {gen_dir} {episode}" in text
    assert text in (tmp_path / "s" / "report.md").read_text()


def test_bounds_beyond_a_field_limit_fail_before_the_search_starts(tmp_path, capsys):
    raw = {"campaign": {"name": "fz", "seed": 11, "episodes": 1}, "model": {"opposing": {"kind": "human"}},
           "falsify": {"requirement": "safe", "population": 4,
                       "bounds": {"scenario.front_speed_mps": [5.0, 9.0], "opposing.speed_mps": [8.0, 90.0]}}}
    config = search.SearchConfig(raw=raw, source="f.toml", method="random", budget=8, seed=0, requirement="safe")
    with pytest.raises(CampaignError) as err:
        search.start(config, tmp_path / "s", make_executor=executors.SerialExecutor,
                     episode_fn=fake_episodes.episodes)
    text = str(err.value)
    assert text.startswith("f.toml [falsify.bounds] opposing.speed_mps = [8, 90], at its upper bound 90")
    assert "speed_limit" in text and "\n" not in text
    assert not (tmp_path / "s").exists()  # nothing written: the command can simply be run again, corrected
    # from the command line: one line, and no start line announcing a folder that is never written
    f = tmp_path / "big.toml"
    f.write_text(CAMPAIGN.replace('[5.0, 9.0]\n', '[5.0, 9.0]\n"opposing.speed_mps" = [8.0, 90.0]\n')
                 + '[model.opposing]\nkind = "human"\n')
    assert cli.main(["falsify", str(f), "--budget", "8", "--run-dir", str(tmp_path / "t")]) == 2
    assert "at its upper bound 90" in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize(("options", "fragment"), [
    (["--set", "scenario.front_speed_mps=7"], "--set 'scenario.front_speed_mps=7': scenario.front_speed_mps is "
                                              "searched by the campaign's [falsify.bounds]"),
    (["--set", "scenario.front_speed_kmh=25"], "is searched by the campaign's [falsify.bounds]"),
    (["--set", "noise.scal=2"], "--set 'noise.scal=2': unknown model field 'noise.scal' (did you mean 'noise.scale'"),
    (["--set", "noise.scale=two"], "--set 'noise.scale=two': expected a number"),
    (["--requirement", "saftey"], "--requirement 'saftey': unknown requirement"),
])
def test_command_line_mistakes_are_named_as_the_options(tmp_path, capsys, options, fragment):
    f = tmp_path / "fz.toml"
    f.write_text(CAMPAIGN)
    code = cli.main(["falsify", str(f), "--budget", "4", "--method", "random", "--run-dir", str(tmp_path / "s"),
                     *options])
    assert code == 2
    line = _one_error_line(capsys.readouterr().err)
    assert fragment in line and str(f) not in line, line
    assert not (tmp_path / "s").exists()


def test_a_set_of_a_field_only_falsify_sets_names_the_option(tmp_path, capsys):
    assert cli.main(["run", str(Path(__file__).parent / "fixtures" / "tiny.toml"), "--set", "sim.stop_at=safe",
                     "--dry-run"]) == 2
    assert "--set 'sim.stop_at=safe': sim.stop_at is set by `mcverify falsify` only" in _one_error_line(
        capsys.readouterr().err)


@pytest.mark.parametrize(("options", "fragment"), [
    (["--score", "h_ef"], "--score is for --method splitting or importance, not mc"),
    (["--particles", "10"], "--particles is for --method splitting, not mc"),
    (["--method", "splitting", "--budget", "10"], "--budget is for --method mc, not splitting"),
    (["--method", "importance", "--chunk-size", "4"], "--chunk-size is for --method mc, not importance"),
    (["--method", "importance", "--replicates", "4"],
     "--replicates is for --method splitting or subset, not importance"),
    (["--method", "splitting", "--ce-samples", "4"], "--ce-samples is for --method importance, not splitting"),
    (["--method", "splitting", "--elite-share", "0.2"], "--elite-share is for --method importance, not splitting"),
    (["--method", "importance", "--elite-share", "1"], "--elite-share: must be in (0, 1), got 1.0"),
    (["--method", "importance", "--elite-share", "x"], "--elite-share: expected a number in (0, 1), got 'x'"),
])
def test_estimate_refuses_an_option_its_method_would_ignore(tmp_path, capsys, options, fragment):
    f = Path(__file__).parent / "fixtures" / "tiny.toml"
    assert cli.main(["estimate", str(f), "--run-dir", str(tmp_path / "e"), *options]) == 2
    assert fragment in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "e").exists()


@pytest.mark.parametrize("options", [["--budget", "5000"], ["--target", "ellipse"], ["--level", "0.9"],
                                     ["--chunk-size", "4"], ["--method", "mc"], ["--particles", "4"]])
def test_estimate_resume_refuses_what_it_would_drop(tmp_path, capsys, options):
    assert cli.main(["estimate", "--resume", str(tmp_path / "e"), *options]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--resume keeps the estimate's method, target and options" in line and options[0] in line


def test_a_run_says_what_its_settings_changed_from_the_file(tmp_path):
    f = Path(__file__).parent / "fixtures" / "tiny.toml"
    camp = load_campaign(f, settings=["noise.scale=2"])
    assert camp.settings == ("noise.scale=2",)
    runner.run(camp, tmp_path / "r", executor=executors.SerialExecutor(), progress=False, episode_fn=synth.episodes)
    assert "--set `noise.scale=2`" in (tmp_path / "r" / "report.md").read_text()
    plain = load_campaign(f)
    runner.run(plain, tmp_path / "p", executor=executors.SerialExecutor(), progress=False, episode_fn=synth.episodes)
    assert "--set" not in (tmp_path / "p" / "report.md").read_text()


def test_compare_says_which_run_had_command_line_settings(tmp_path):
    from mcverify.reporting import compare  # noqa: PLC0415

    f = Path(__file__).parent / "fixtures" / "tiny.toml"
    for name, settings in (("a", []), ("b", ["noise.scale=2"])):
        runner.run(load_campaign(f, settings=settings), tmp_path / name, executor=executors.SerialExecutor(),
                   progress=False, episode_fn=synth.episodes)
    result = compare.compare_runs(compare.load_run(tmp_path / "a"), compare.load_run(tmp_path / "b"))
    text = compare.render_markdown(result)
    line_a, line_b = (next(ln for ln in text.splitlines() if ln.startswith(f"- **{x}**")) for x in "AB")
    assert "--set" not in line_a and "--set `noise.scale=2`" in line_b


def test_resuming_a_finished_search_says_so_and_report_rebuilds_it(tmp_path, monkeypatch, capsys):
    real = search.start
    monkeypatch.setattr(search, "start", lambda config, out_dir, **kw: real(
        config, out_dir, **{**kw, "make_executor": executors.SerialExecutor, "episode_fn": fake_episodes.episodes}))
    f = tmp_path / "fz.toml"
    f.write_text(CAMPAIGN)
    assert cli.main(["falsify", str(f), "--budget", "4", "--method", "random", "--run-dir", str(tmp_path / "s")]) == 0
    report = (tmp_path / "s" / "report.md").read_text()
    (tmp_path / "s" / "report.md").unlink()
    capsys.readouterr()
    # the one --resume rule (run, estimate, falsify): a complete folder is no error, and nothing is rewritten
    assert cli.main(["falsify", "--resume", str(tmp_path / "s")]) == 0
    assert "is already complete: nothing to run" in capsys.readouterr().out
    assert not (tmp_path / "s" / "report.md").exists()
    assert cli.main(["report", str(tmp_path / "s")]) == 0  # what rebuilds it, running nothing
    assert (tmp_path / "s" / "report.md").read_text() == report
    assert cli.main(["report", str(tmp_path / "s"), "--method", "wilson"]) == 2
    assert "--method is for run and crude Monte Carlo estimate folders" in capsys.readouterr().err


def test_a_speed_given_in_kmh_is_named_as_given_when_out_of_range():
    from mcverify.campaign.spec import campaign_from_dict  # noqa: PLC0415

    with pytest.raises(CampaignError) as err:
        campaign_from_dict({"campaign": {"name": "x", "seed": 1, "episodes": 1},
                            "model": {"scenario": {"front_speed_kmh": 500}}}, source="f.toml")
    assert str(err.value).endswith("(given as scenario.front_speed_kmh = 500)") and "138.9 m/s" in str(err.value)


def test_the_counterexample_table_leaves_out_sampled_columns_that_say_nothing_new():
    from mcverify.reporting.counterexample_report import _shown_parameters  # noqa: PLC0415

    rows = [{"param:opposing.speed_mps": v, "sample_opp_speed_mps": v, "sample_front_accel_mps2": 0.0,
             "sample_alpha": a} for v, a in ((12.0, 0.3), (15.5, 0.9))]
    assert _shown_parameters(rows) == ["param:opposing.speed_mps", "sample_alpha"]
    # one counterexample: its sampled values are shown, but not a copy of a searched value
    assert _shown_parameters(rows[:1]) == ["param:opposing.speed_mps", "sample_front_accel_mps2", "sample_alpha"]


def test_the_failure_regions_table_shows_the_searched_columns_and_says_when_nothing_clusters():
    from mcverify.reporting.counterexample_report import regions_table  # noqa: PLC0415

    rows = [{"episode_id": i, "failure_mode": "ellipse/planned", "robustness": -0.01 * (i + 1), "region": i + 1,
             "replay": f"mcverify replay run {i}", "param:opposing.speed_mps": v, "sample_opp_speed_mps": v,
             "sample_front_accel_mps2": 0.0} for i, v in enumerate((9.0, 14.0, 19.0))]
    table = regions_table(rows)
    assert table.columns == ["region", "failure mode", "episodes", "worst robustness", "opposing.speed_mps",
                             "replay (worst)"]
    assert table.notes[0].startswith("Every counterexample is a region of its own: no two of the 3")
    rows[1]["region"] = 1  # two in one region: no such note
    assert not regions_table(rows).notes[0].startswith("Every counterexample")


def test_the_robustness_plot_labels_its_axis_in_plain_numbers(tmp_path):
    import matplotlib.image  # noqa: PLC0415
    import matplotlib.pyplot as plt  # noqa: PLC0415

    from mcverify.falsify import report  # noqa: PLC0415

    _, ax = plt.subplots()
    ax.set_yscale("symlog", linthresh=0.05)
    ax.set_ylim(-0.055, 0.002)
    report.label_symlog_axis(ax)
    assert [t.get_text() for t in ax.get_yticklabels()] == ["-0.05", "-0.02", "-0.01", "0"]
    ax.set_ylim(-2.0, 80.0)
    report.label_symlog_axis(ax)
    labels = [t.get_text() for t in ax.get_yticklabels()]
    assert len(labels) <= 9 and "0" in labels and "-1" in labels and "10" in labels
    plt.close("all")
    report.robustness_curves({"random": [0.3, -0.02, 0.1]}, tmp_path / "r.png", "safe")
    assert matplotlib.image.imread(tmp_path / "r.png").shape[0] > 100
