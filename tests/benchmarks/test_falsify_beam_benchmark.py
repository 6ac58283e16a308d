"""``python -m benchmarks.falsify --methods beam``: a beam trial is the beam folder of ``mcverify falsify --method
beam`` read as a Trial (costs in episode-equivalents, its best episode as the counterexample), re-read without
running; the peak-memory column; one-line refusals of beam on a target without ``[falsify.beam]`` and of a
population method on a beam-only target (the real closed loop on test_beam_cli.py's 30-step episode)."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest

from benchmarks import falsify as bench
from benchmarks import memory
from mcverify.falsify import beam, beam_folder
from tests.falsify import test_beam_cli as cli_case

POPULATION = ('[campaign]\nname = "fz"\nseed = 11\nepisodes = 1\n[falsify]\nrequirement = "ellipse"\n'
              'population = 4\n[falsify.bounds]\n"scenario.front_speed_mps" = [5.0, 9.0]\n')


@pytest.fixture(scope="module")
def beam_run(tmp_path_factory):
    """One beam trial (seed 7, budget 3 episode-equivalents): (target file, out dir, trials)."""
    tmp = tmp_path_factory.mktemp("bench-beam")
    target = cli_case._campaign(tmp)
    out, said = tmp / "b", []
    trials = bench.run_trials([target], ["beam"], 1, 3, 7, out, progress=said.append)
    assert said == [f"beam-cli beam trial 0: none in {cli_case.BEAM_STEPS / 30:.3g} episode-equivalents, min "
                    f"robustness {trials[0].min_robustness:.4g}"]
    return target, out, trials


def test_a_beam_trial_is_its_folder_in_episode_equivalents(beam_run, monkeypatch):
    target, out, trials = beam_run
    (trial,) = trials
    where = out / "beam-cli" / "beam" / "trial-00"
    summary = beam_folder.read_summary(where)
    assert (trial.target, trial.method, trial.seed, summary.seed, summary.budget) == ("beam-cli", "beam", 7, 7, 3)
    # both frontier episodes time out at step 29 (test_beam.py), so the search spends its whole bound
    assert trial.episode_equivalents == summary.search_steps / 30 == cli_case.BEAM_STEPS / 30
    assert trial.min_robustness == summary.best_robustness == min(n.robustness for n in summary.frontier)
    assert not trial.counts_episodes and trial.episodes == 0 and trial.curve == ()
    found = trial.min_robustness < 0.0
    assert (trial.first_counterexample is not None) == found == bool(trial.counterexamples)
    assert trial.peak_snapshots == summary.peak_snapshots <= 2 * summary.spec.shape.width + 1
    assert trial.guide == "h_front" and trial.min_guide == min(n.score for n in summary.frontier)
    assert trial.peak_rss_mb is not None and trial.peak_rss_mb > 0.0  # psutil comes with the test extra
    monkeypatch.setattr(beam, "search", lambda *a, **k: pytest.fail("a finished trial is re-read, not run"))
    assert bench.run_trials([target], ["beam"], 1, 3, 7, out) == trials


def test_a_beam_counterexample_is_the_best_episode_after_the_whole_search(beam_run):
    """The best final-frontier episode with negative robustness: ep-eq to it is the search's cost, and it
    replays bit for bit from ``TRIAL/best`` episode 0 (what --replay runs)."""
    _, out, (trial,) = beam_run
    where = out / "beam-cli" / "beam" / "trial-00"
    summary = beam_folder.read_summary(where)
    (only,) = summary.restarts
    assert only.best == 0  # the frontier is in rank order: keep the best first
    frontier = tuple(dataclasses.replace(n, robustness=-1.5 + k) for k, n in enumerate(only.frontier))
    violated = dataclasses.replace(summary, restarts=(dataclasses.replace(only, frontier=frontier),))
    hit = bench.beam_trial("beam-cli", violated, where)
    assert hit.min_robustness == -1.5 and hit.first_counterexample == 0
    assert hit.first_episode_equivalents == hit.episode_equivalents == summary.search_steps / 30
    assert hit.counterexamples == (bench.Counterexample(where / "best", 0),)
    assert hit.counterexamples[0].replay_dir() == where / "replay" / "best"
    (check,) = bench.replay_counterexamples([hit])
    assert check.problem == "" and (where / "replay" / "best").is_dir()
    text = bench.markdown([hit], budget=3, command="c")
    s = bench.summarise([hit])
    assert s.median_episodes is None and s.episodes_spent is None and s.successes == 1
    row = f"| beam-cli | beam | 1 | 1 | 1.00 [0.03, 1.00] | {bench.cost_text(s.mean_eq)} |"
    assert row in text and f"| – | {hit.min_robustness:.4g} | – | {s.eq_spent:.4g} | – |" in text  # no episodes
    assert "the same budget, 3, read as a ceiling in episode-equivalents" in text
    assert f"- beam-cli beam: {summary.peak_snapshots}" in text


def test_the_peak_memory_column_and_what_it_is():
    trials = [bench.Trial("t", "cma", 0, 4, 2, -1.0, (), 3.0, 1.5, peak_rss_mb=811.6),
              bench.Trial("t", "cma", 1, 4, None, 0.5, (), 4.0, None, peak_rss_mb=640.2),
              bench.Trial("t", "random", 0, 4, None, 0.5, (), 4.0, None, peak_rss_mb=512.0),
              bench.Trial("t", "random", 1, 4, None, 0.5, (), 4.0, None)]
    text = bench.markdown(trials, budget=4, command="c")
    assert "| ep-eq spent | peak RSS (MB) |" in text and "|---:|---:|---:|\n" in text
    assert "| -1 | 8 | 7 | 812 |" in text  # the largest over the trials
    assert "| 0.5 | 8 | 8 | 512 (1 of 2 trials) |" in text  # a trial without a measurement is said so
    assert "summed resident set size of the benchmark process and its worker processes, sampled every 0.1 s" in text
    assert "Beam (" not in text


def test_peak_rss_counts_child_processes():
    child_mb = 150
    code = f"import time; x = b'\\x01' * ({child_mb} * 2**20); time.sleep(1.0)"
    with memory.PeakRss(interval_s=0.05) as alone:
        pass
    with memory.PeakRss(interval_s=0.05) as peak:
        subprocess.run([sys.executable, "-c", code], check=True)
    assert peak.peak_mb > alone.peak_mb + 0.8 * child_mb


def _refused(tmp_path, capsys, target: str, methods: str) -> str:
    code = bench.main([target, "--methods", methods, "--trials", "1", "--budget", "4", "--no-write",
                       "--out-dir", str(tmp_path / "b")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("benchmarks.falsify: error: "), err
    assert not (tmp_path / "b").exists(), "nothing ran"
    return err[0]


def test_beam_on_a_target_without_a_beam_table_is_one_line(tmp_path, capsys):
    target = tmp_path / "pop.toml"
    target.write_text(POPULATION)
    assert "--method beam needs a [falsify.beam] table" in _refused(tmp_path, capsys, str(target), "random,beam")


def test_a_population_method_on_a_beam_only_target_is_one_line(tmp_path, capsys):
    line = _refused(tmp_path, capsys, cli_case._campaign(tmp_path), "beam,cma")
    assert "searches with [falsify.beam] only (--method beam); --method cma needs" in line


def test_beam_is_a_method_of_the_benchmark():
    assert bench.chosen_methods("cma,beam") == ["cma", "beam"]


def test_random_schedules_are_the_beam_with_branching_1_paired_by_seed(beam_run, tmp_path):
    """The baseline runs the target's table with branching 1 under the beam's seed, in its own folder; the
    paired sentence counts the pairs where the beam went lower, with the sign test."""
    target, _, (beam_trial,) = beam_run
    (base,) = bench.run_trials([target], [bench.RANDOM_SCHEDULES], 1, 3, 7, tmp_path / "r")
    where = tmp_path / "r" / "beam-cli" / bench.RANDOM_SCHEDULES / "trial-00"
    summary = beam_folder.read_summary(where)
    assert summary.spec.shape.branching == 1 and summary.spec.shape.width == 2 and summary.seed == 7
    assert base.method == bench.RANDOM_SCHEDULES and not base.counts_episodes
    assert summary.spec.children_per_depth() == [2, 2]
    text = bench.paired_sentence([beam_trial, base], "beam-cli", "beam", bench.RANDOM_SCHEDULES)
    lower = int(beam_trial.min_robustness < base.min_robustness)
    assert text.startswith("beam-cli, 1 paired seeds: beam falsified 0, random-schedules 0;")
    assert f"below random-schedules's in {lower} of 1 pairs" in text
    assert bench.paired_sentence([beam_trial], "beam-cli", "beam", bench.RANDOM_SCHEDULES) == ""


def test_audit_reruns_the_counterexample_with_ipopt_once(beam_run, monkeypatch):
    """--audit re-simulates a trial's first counterexample with the reference solver on the trial's requirement,
    keeps the audit (with the reference robustness) beside the episode, and re-reads it on the next run."""
    from mcverify.campaign import audit

    target, out, (trial,) = beam_run
    where = out / "beam-cli" / "beam" / "trial-00"
    hit = dataclasses.replace(trial, first_counterexample=0, counterexamples=(bench.Counterexample(where / "best", 0),))
    assert hit.requirement == "ellipse"  # set from the search's config
    (check,) = bench.audit_counterexamples([hit])
    kept = audit.recorded(where / "best")["0"]
    assert kept["requirement"] == "ellipse" and kept["backend"] == "ipopt"
    assert check.reference_robustness == kept["reference_robustness"]
    # the stored episode holds (the test's beam finds no violation), so "confirmed" is the same verdict: holds
    assert check.confirmed == (kept["reference_violated"] is False)
    assert list((where / "audit" / "best").glob("episode-000000-ipopt*"))
    monkeypatch.setattr(audit, "audit", lambda *a, **k: pytest.fail("a kept audit is re-read, not re-run"))
    assert bench.audit_counterexamples([hit]) == [check]
