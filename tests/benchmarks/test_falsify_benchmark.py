"""``python -m benchmarks.falsify``: the trials, their section of the page and issue 16's verdict."""

from __future__ import annotations

import pytest

from benchmarks import falsify as bench
from benchmarks import section
from mcverify.campaign import executors
from mcverify.errors import RunError
from tests.falsify import fake_episodes

CAMPAIGN = ('[campaign]\nname = "fz"\nseed = 11\nepisodes = 1\n[falsify]\nrequirement = "ellipse"\n'
            'population = 4\n[falsify.bounds]\n"scenario.front_speed_mps" = [5.0, 9.0]\n')


def _kw():
    return {"make_executor": executors.SerialExecutor, "episode_fn": fake_episodes.episodes}


def test_bench_trials_and_section(tmp_path):
    f = tmp_path / "t.toml"
    f.write_text('[campaign]\nname = "t"\nseed = 5\nepisodes = 1\n[falsify]\nrequirement = "ellipse"\npopulation = 4\n'
                 '[falsify.bounds]\n"scenario.front_speed_mps" = [5.0, 9.0]\n"opposing.speed_mps" = [8.0, 19.0]\n')
    trials = bench.run_trials([f], ["cma", "random"], 2, 8, 0, tmp_path / "b", **_kw())
    assert [(t.method, t.seed) for t in trials] == [("cma", 0), ("cma", 1), ("random", 0), ("random", 1)]
    assert all(t.first_counterexample is None or t.first_counterexample <= t.episodes <= 8 for t in trials)
    again = bench.run_trials([f], ["cma", "random"], 2, 8, 0, tmp_path / "b", **_kw())  # re-read, not re-run
    assert again == trials
    text = bench.markdown(trials, budget=8, command="python -m benchmarks.falsify t.toml")
    begin, _ = section.markers("falsify")
    assert text.count("| t | ") == 4 and text.startswith(begin)  # the table and the per-trial table
    assert "Command: `python -m benchmarks.falsify t.toml`; commit" in text
    md = tmp_path / "B.md"
    md.write_text("# Benchmarks\n\nintro\n")
    bench.write_section(md, text)
    bench.write_section(md, text)
    assert md.read_text().count(begin) == 1 and "intro" in md.read_text()
    assert bench.draw_curves(trials, tmp_path / "b")[0].is_file()


def _trials(method: str, firsts: list[int | None], budget: int = 100) -> list:
    return [bench.Trial("t", method, seed, budget if f is None else f, f, -1.0 if f else 0.5)
            for seed, f in enumerate(firsts)]


def test_goal_verdict_reads_rarity_and_the_goal_from_the_trials():
    """Issue 16's goal: rare when random search's median (failures beyond the budget) is >= 50; met when a
    method succeeds in >= 90 % of its trials with a median <= a tenth of random's."""
    common = _trials("random", [3, 5, 9, None]) + _trials("cma", [1, 2, 2, 4])
    assert "not rare" in bench.goal_verdict(common, "t", 100)
    rare = _trials("random", [60, 80, 90, None, 70, 75, 85, 65, 95, 55])  # median 77.5
    met = rare + _trials("cma", [3, 4, 5, 6, 7, 7, 5, 4, 3, None])  # 9/10, median 5 <= 7.75
    assert "cma met (9/10, median 5)" in bench.goal_verdict(met, "t", 100)
    slow = rare + _trials("cma", [20] * 10)
    assert "cma not met (10/10, median 20)" in bench.goal_verdict(slow, "t", 100)
    unreliable = rare + _trials("cma", [1] * 8 + [None] * 2)
    assert "cma not met (8/10" in bench.goal_verdict(unreliable, "t", 100)
    # random fails in most trials: a tenth of its median is known only to exceed budget / 10
    beyond = _trials("random", [None] * 9 + [20])
    assert "median beyond the budget of 32" in bench.goal_verdict(beyond, "t", 32)
    assert "cma met" in bench.goal_verdict(beyond + _trials("cma", [2, 3, 1, 2, 3, 2, 2, 1, 3, 2], 32), "t", 32)
    assert "cma undecided" in bench.goal_verdict(beyond + _trials("cma", [9] * 10, 32), "t", 32)
    assert "cma not met" in bench.goal_verdict(beyond + _trials("cma", [None] * 9 + [1], 32), "t", 32)
    assert "no random-search trials" in bench.goal_verdict(_trials("cma", [1]), "t", 8)
    assert "Issue 16's goal" in bench.markdown(met, budget=100, command="c")


def test_trial_folders_of_another_search_are_refused(tmp_path):
    f = tmp_path / "t.toml"
    f.write_text(CAMPAIGN)
    first = bench.run_trials([f], ["random"], 1, 4, 0, tmp_path / "b", **_kw())
    assert bench.run_trials([f], ["random"], 1, 4, 0, tmp_path / "b", **_kw()) == first  # the same search: re-read
    with pytest.raises(RunError, match=r"holds a trial of another search \(budget 4, not 8\); give another --out-dir"):
        bench.run_trials([f], ["random"], 1, 8, 0, tmp_path / "b", **_kw())
    with pytest.raises(RunError, match="another campaign content or --set"):
        bench.run_trials([f], ["random"], 1, 4, 0, tmp_path / "b", settings=["noise.scale=2"], **_kw())


def test_every_target_is_checked_before_the_first_trial(tmp_path, capsys):
    good, plain = tmp_path / "good.toml", tmp_path / "plain.toml"
    good.write_text(CAMPAIGN)
    plain.write_text('[campaign]\nname = "p"\nseed = 1\nepisodes = 1\n')
    code = bench.main([str(good), str(plain), "--methods", "random", "--trials", "1", "--budget", "4",
                       "--no-write", "--out-dir", str(tmp_path / "b")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("benchmarks.falsify: error: ")
    assert "plain.toml: no [falsify] table" in err[0]
    assert not (tmp_path / "b").exists(), "nothing ran: the bad target was found first"
