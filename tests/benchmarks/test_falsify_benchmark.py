"""``python -m benchmarks.falsify``: the trials, their section of the page and issue 16's verdict."""

from __future__ import annotations

import math

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
    for t in trials:  # costs from the search's own cost column; counterexamples as replay takes them
        assert 0 < t.episode_equivalents <= t.episodes
        assert (t.first_episode_equivalents is None) == (t.first_counterexample is None) == (not t.counterexamples)
        if t.first_counterexample is not None:
            assert 0 < t.first_episode_equivalents <= t.episode_equivalents
            assert all((cx.run_dir / "manifest.json").is_file() for cx in t.counterexamples)
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


def _cost_trial(method: str, seed: int, first_eq: float | None, lowest: float, spent_eq: float = 10.0):
    first = None if first_eq is None else max(1, round(first_eq))
    return bench.Trial("t", method, seed, 12, first, lowest, (), spent_eq, first_eq)


def test_episode_equivalent_statistics_of_constructed_trials():
    """Mean and median episode-equivalents to the first counterexample over the successful trials, the
    median over all trials with a failure beyond the budget, and the totals."""
    group = [_cost_trial("cma", 0, 2.5, -1.0), _cost_trial("cma", 1, None, 0.25), _cost_trial("cma", 2, 4.0, -2.0),
             _cost_trial("cma", 3, 1.5, -1.0)]
    s = bench.summarise(group)
    assert (s.trials, s.successes) == (4, 3)
    assert s.low == pytest.approx(0.194, abs=1e-3) and s.high == pytest.approx(0.994, abs=1e-3)  # Clopper-Pearson
    assert s.mean_eq == pytest.approx(8.0 / 3.0) and s.median_eq == 2.5
    assert s.median_eq_all == 3.25  # (2.5 + 4.0) / 2, the failure counting as beyond the budget
    assert s.median_episodes == 2 and s.episodes_spent == 48 and s.eq_spent == 40.0
    assert s.eq_to_first == (2.5, None, 4.0, 1.5) and s.lowest == (-1.0, 0.25, -2.0, -1.0)
    mostly_failed = [_cost_trial("random", k, None, 0.5) for k in range(3)] + [_cost_trial("random", 3, 7.0, -1.0)]
    r = bench.summarise(mostly_failed)
    assert r.median_eq_all == math.inf and r.mean_eq == r.median_eq == 7.0
    none = bench.summarise([_cost_trial("random", 0, None, 0.5)])
    assert none.mean_eq is None and none.median_eq is None and none.median_episodes is None
    text = bench.markdown(group + mostly_failed, budget=12, command="c")
    assert "| t | cma | 4 | 3 | 0.75 [0.19, 0.99] | 2.67 | 2.5 | 3.25 | 2 | -2 | 48 | 40 |" in text
    assert "| t | random | 4 | 1 | 0.25 [0.01, 0.81] | 7 | 7 | beyond the budget | 7 |" in text
    assert "| t | cma | 2.5, –, 4, 1.5 | -1, 0.25, -2, -1 |" in text


def test_lowest_robustness_keeps_the_sign_of_tiny_negatives():
    assert [bench.compact(x) for x in (-0.0048, 1.7e-06, -1e-09, -0.0004999, 0.0, 1.0, None)] == [
        "-0.0048", "1.7e-06", "-1e-09", "-0.0005", "0", "1", "–"]
    trials = [bench.Trial("t", "cma", k, 5, None, x, ()) for k, x in enumerate((-3e-12, 4.2e-05, -0.0048))]
    assert "| t | cma | –, –, – | -3e-12, 4.2e-05, -0.0048 |" in bench.markdown(trials, budget=5, command="c")


def test_guided_targets_list_each_trials_lowest_guide():
    trials = [bench.Trial("t", "cma", k, 5, None, 1.0, (), 5.0, None, "theorem5", g)
              for k, g in enumerate((-0.0031, 0.12))]
    text = bench.markdown(trials, budget=5, command="c")
    assert "| target | method | ep-eq to 1st | lowest robustness | lowest guide |" in text
    assert "| t | cma | –, – | 1, 1 | theorem5: -0.0031, 0.12 |" in text


def _synthetic_run(monkeypatch, trials):
    monkeypatch.setattr(bench, "run_trials", lambda *a, **k: trials)
    monkeypatch.setattr(bench, "draw_curves", lambda *a, **k: [])


def test_section_option_writes_its_own_section(tmp_path, monkeypatch, capsys):
    f = tmp_path / "t.toml"
    f.write_text(CAMPAIGN)
    page = tmp_path / "B.md"
    page.write_text("# Benchmarks\n\n" + section.wrap("falsify", "the default targets' table"))
    _synthetic_run(monkeypatch, [_cost_trial("cma", 0, 2.5, -1.0)])
    argv = [str(f), "--methods", "cma", "--section", "falsify_adversary", "--write", str(page)]
    assert bench.main(argv) == 0
    assert bench.main(argv) == 0  # rewritten in place, not appended
    text = page.read_text()
    begin, end = bench.markers("falsify_adversary")
    assert text.count(begin) == 1 and text.count(end) == 1 and "the default targets' table" in text
    assert "generated by python -m benchmarks.falsify --section falsify_adversary" in begin
    assert "--section falsify_adversary" in text.split(begin)[1]  # the command that made it
    assert "Counterexamples not replayed" in text
    assert "written: " in capsys.readouterr().err


@pytest.mark.parametrize(("name", "fragment"), [
    ("Falsify-Adv", "--section 'Falsify-Adv': lower-case letters and _ only"),
    ("", "--section '': lower-case letters and _ only"),
    ("rare", "--section rare: that is the section of python -m benchmarks.rare"),
])
def test_a_bad_section_name_is_one_line(tmp_path, monkeypatch, capsys, name, fragment):
    f = tmp_path / "t.toml"
    f.write_text(CAMPAIGN)
    monkeypatch.setattr(bench, "run_trials", lambda *a, **k: pytest.fail("nothing may run"))
    assert bench.main([str(f), "--section", name, "--write", str(tmp_path / "B.md")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("benchmarks.falsify: error: ") and fragment in err[0]
    assert not (tmp_path / "B.md").exists()


def test_replay_names_the_counterexamples_that_do_not_reproduce(tmp_path, monkeypatch):
    from mcverify.campaign import replay

    good, bad = bench.Counterexample(tmp_path / "generations" / "g000", 3), bench.Counterexample(tmp_path / "g001", 0)
    calls = []

    def fake_replay(run_dir, episode_id, out_dir=None):
        calls.append((run_dir, episode_id, out_dir))
        if run_dir == bad.run_dir:
            raise replay.ReplayMismatch(f"episode {episode_id} does not reproduce: robustness: stored 1 vs replayed 2")

    monkeypatch.setattr(replay, "replay", fake_replay)
    trials = [bench.Trial("t", "cma", 0, 1, 1, -1.0, (), 1.0, 1.0, counterexamples=(good,)),
              bench.Trial("t", "random", 4, 2, 2, -1.0, (), 2.0, 2.0, counterexamples=(bad,)),
              bench.Trial("t", "random", 5, 2, None, 1.0, ())]
    checks = bench.replay_counterexamples(trials)
    assert [(c.counterexample, bool(c.problem)) for c in checks] == [(good, False), (bad, True)]
    assert calls[0] == (good.run_dir, 3, tmp_path / "replay" / "g000")  # beside the generations
    sentence = bench.replay_sentence(checks)
    assert sentence.startswith("Replay: 1 of 2 counterexamples replay bit for bit; these do not: t random seed 4")
    assert "stored 1 vs replayed 2" in sentence
    assert bench.replay_sentence(checks[:1]) == ("Replay: 1 of 1 counterexamples replay bit for bit "
                                                "(`mcverify replay`).")
    assert "no counterexample was found" in bench.replay_sentence([])
    assert "Replay: 1 of 2" in bench.markdown(trials, budget=2, command="c", replays=checks)


def test_audit_counts_the_counterexamples_the_reference_solver_confirms(tmp_path, monkeypatch):
    """The audit column and sentence: confirmed (the reference solver violates too) out of audited, per method;
    only each trial's first counterexample is audited, on the trial's requirement."""
    from mcverify.campaign import audit

    calls = []

    def fake_audit(run_dir, episode_id, out_dir=None, requirement="safe"):
        calls.append((run_dir, episode_id, out_dir, requirement))
        low = -0.5 if run_dir.name == "g000" else 0.25
        return audit.AuditResult(episode_id, audit.AuditVerdict.CONFIRMED if low < 0 else
                                 audit.AuditVerdict.SOLVER_DEPENDENT, {"outcome": "x", "safe": True},
                                 {"outcome": "x", "safe": True, "min_h_front": low}, None, None, requirement)

    monkeypatch.setattr(audit, "audit", fake_audit)
    monkeypatch.setattr(audit, "robustness", lambda row, requirement: row["min_h_front"])
    first = bench.Counterexample(tmp_path / "generations" / "g000", 3)
    second = bench.Counterexample(tmp_path / "g001", 0)
    trials = [bench.Trial("t", "cma", 0, 1, 1, -1.0, (), 1.0, 1.0, counterexamples=(first, second),
                          requirement="ellipse"),
              bench.Trial("t", "random", 4, 2, 2, -1.0, (), 2.0, 2.0, counterexamples=(second,), requirement="ellipse"),
              bench.Trial("t", "random", 5, 2, None, 1.0, (), requirement="ellipse")]
    checks = bench.audit_counterexamples(trials)
    assert [(c.counterexample, c.confirmed, c.reference_robustness) for c in checks] == [
        (first, True, -0.5), (second, False, 0.25)]
    assert calls[0] == (first.run_dir, 3, tmp_path / "audit" / "g000", "ellipse")
    sentence = bench.audit_sentence(checks)
    assert "1 of 2 still violate the requirement" in sentence
    assert "cma seed 0: confirmed, robustness -0.5; random seed 4: solver-dependent, robustness 0.25" in sentence
    text = bench.markdown(trials, budget=2, command="c", audits=checks)
    assert "| peak RSS (MB) | confirmed by IPOPT |" in text
    assert text.count("| 1 of 1 |") == 1 and text.count("| 0 of 1 |") == 1
    assert "not audited with the reference solver" in bench.markdown(trials, budget=2, command="c")
    assert "none was audited" in bench.audit_sentence([])


def test_a_search_run_with_the_reference_solver_is_its_own_audit(tmp_path, monkeypatch):
    """A counterexample of a run made with IPOPT has nothing to audit: confirmed, at its own robustness."""
    from mcverify.campaign import audit

    row = {"outcome": "overtook", "safe": True, "min_h_front": -0.25}
    monkeypatch.setattr(audit, "audit", lambda run_dir, episode_id, out_dir=None, requirement="safe": audit.AuditResult(
        episode_id, audit.AuditVerdict.REFERENCE_RUN, row, None, None, None, requirement))
    cx = bench.Counterexample(tmp_path / "g000", 0)
    trial = bench.Trial("t", "cma", 0, 1, 1, -0.25, (), 1.0, 1.0, counterexamples=(cx,), requirement="ellipse")
    (check,) = bench.audit_counterexamples([trial])
    assert check.confirmed and check.reference_robustness == -0.25
    assert not (tmp_path / "g000" / "audits.json").exists()  # nothing kept: the run is the reference's
