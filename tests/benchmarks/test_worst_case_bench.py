"""``python -m benchmarks.worst_case``: the section, its headline and the figure from constructed trials, the
trial folders per ε (re-read on a second run) and its one-line refusals."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from benchmarks import falsify, section
from benchmarks import worst_case as wc
from mcverify.campaign import executors
from mcverify.campaign.spec import load_campaign
from mcverify.errors import RunError
from mcverify.falsify import search
from tests.falsify import fake_episodes

CAMPAIGN = ('[campaign]\nname = "fz"\nseed = 11\nepisodes = 1\n[falsify]\nrequirement = "ellipse"\n'
            'population = 4\n[falsify.bounds]\n"scenario.front_speed_mps" = [5.0, 9.0]\n')
SETTING = wc.Setting("campaigns/t.toml", "safe", "within the paper's noise bounds", 12)


def _trial(method: str, seed: int, lowest: float, first_eq: float | None = None, spent_eq: float = 12.0,
           where: Path = Path("out")) -> falsify.Trial:
    """A finished trial as :func:`benchmarks.falsify.trial_of` makes it: a counterexample iff ``first_eq``."""
    first = None if first_eq is None else max(1, round(first_eq))
    found = () if first_eq is None else (falsify.Counterexample(where / f"s{seed}" / "generations" / "g001", 3),)
    return falsify.Trial("t", method, seed, 12, first, lowest, (), spent_eq, first_eq, counterexamples=found)


def _broken() -> list[wc.EpsilonTrials]:
    return [
        wc.EpsilonTrials(0.0, (_trial("cma", 0, -1.5, 3.0), _trial("cma", 1, -0.2, 2.0), _trial("cma", 2, 0.4),
                               _trial("random", 0, 0.3), _trial("random", 1, -0.01, 9.0), _trial("random", 2, 0.05))),
        wc.EpsilonTrials(0.3, (_trial("cma", 0, -0.1, 5.5), _trial("cma", 1, 0.2), _trial("cma", 2, -0.0048, 4.25),
                               _trial("random", 0, 0.31), _trial("random", 1, 0.2), _trial("random", 2, 0.45))),
        wc.EpsilonTrials(0.5, (_trial("cma", 0, 0.02), _trial("cma", 1, 0.6), _trial("cma", 2, 0.03),
                               _trial("random", 0, 0.9), _trial("random", 1, 0.7), _trial("random", 2, 1.2))),
    ]


def test_the_headline_names_the_largest_level_broken_and_its_replay():
    """ε = 0.3 is the largest level with a counterexample; cma's cheaper one (seed 2, 4.25 ep-eq) is named."""
    text = wc.headline(_broken(), SETTING)
    assert text == ("Within the paper's noise bounds, `safe` at ε = 0.3 is broken by cma after 4.25 "
                    f"episode-equivalents (seed 2; replay: `mcverify replay {Path('out/s2/generations/g001')} 3`); "
                    "2 of 3 cma trials broke it within 12 episodes.")


def test_the_headline_without_a_counterexample_gives_the_lowest_robustness():
    unbroken = [wc.EpsilonTrials(e, tuple(_trial(m, s, 0.1 + e + 0.01 * s, spent_eq=11.5 + s) for m in ("cma", "random")
                                          for s in range(2))) for e in (0.0, 0.2)]
    unbroken[1] = wc.EpsilonTrials(0.2, (*unbroken[1].trials[:3], _trial("random", 1, 0.0031, spent_eq=10.25)))
    assert wc.headline(unbroken, SETTING) == (
        "Within the paper's noise bounds, no trial broke `safe` at any ε within 12 episodes; the lowest robustness "
        "found at ε = 0.2 is 0.0031 (random, seed 1) after 10.2 episode-equivalents.")


def test_the_headline_of_beam_trials_states_the_budget_in_episode_equivalents():
    beams = [wc.EpsilonTrials(e, tuple(dataclasses.replace(t, method=m, counts_episodes=False)
                                       for m, t in (("beam", _trial("x", 0, -1.0, 1.9)),
                                                    ("random-schedules", _trial("x", 0, -1.0, 0.7)))))
             for e in (0.0, 0.3)]
    assert wc.headline(beams, SETTING).endswith("1 of 1 random-schedules trials broke it within 12 "
                                                "episode-equivalents.")


def test_the_section_has_a_row_per_level_and_method():
    text = wc.markdown(_broken(), SETTING, command="python -m benchmarks.worst_case t.toml", figure_path=Path("f.png"))
    begin, end = section.markers("worst_case")
    assert text.startswith(begin) and text.rstrip().endswith(end)
    assert "Command: `python -m benchmarks.worst_case t.toml`; commit" in text
    assert "**Headline.** Within the paper's noise bounds, `safe` at ε = 0.3 is broken by cma" in text
    # 2/3 falsified: exact interval [0.094, 0.992]; median over all trials (3, 2, beyond) = 3
    assert "| 0 | cma | 3 | 2/3 [0.09, 0.99] | 3 | -1.5 | -0.2 | -1.5, -0.2, 0.4 |" in text
    assert "| 0 | random | 3 | 1/3 [0.01, 0.91] | beyond the budget | -0.01 | 0.05 | 0.3, -0.01, 0.05 |" in text
    assert "| 0.3 | cma | 3 | 2/3 [0.09, 0.99] | 5.5 | -0.1 | -0.0048 | -0.1, 0.2, -0.0048 |" in text
    assert "| 0.5 | random | 3 | 0/3 [0.00, 0.71] | beyond the budget | 0.7 | 0.9 | 0.9, 0.7, 1.2 |" in text
    rows = [line for line in text.splitlines() if line.startswith("| ") and not line.startswith("| ε")]
    assert len(rows) == 6  # three levels x two methods
    assert "Figure: `f.png`" in text and "Counterexamples not replayed" in text


def test_the_figure_is_drawn(tmp_path):
    path = wc.figure(_broken(), SETTING, tmp_path / "fig" / "worst-case.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000
    assert wc.figure(_broken(), SETTING, tmp_path / "again.png").read_bytes() == path.read_bytes()  # byte-stable


def test_the_trials_go_per_level_and_a_second_run_rereads_them(tmp_path):
    f = tmp_path / "t.toml"
    f.write_text(CAMPAIGN)
    kw = {"make_executor": executors.SerialExecutor, "episode_fn": fake_episodes.episodes}
    first = wc.run(f, (0.0, 0.3), ["random"], 1, 4, 0, tmp_path / "b", **kw)
    assert [r.epsilon for r in first] == [0.0, 0.3] and all(len(r.trials) == 1 for r in first)
    for eps in ("0.0", "0.3"):
        assert (tmp_path / "b" / f"eps-{eps}" / "fz" / "random" / "trial-00" / search.CONFIG).is_file()
    assert wc.run(f, (0.0, 0.3), ["random"], 1, 4, 0, tmp_path / "b", **kw) == first  # re-read, not re-run
    with pytest.raises(RunError, match=r"eps-0.3.* holds a trial of another search \(budget 4, not 5\)"):
        wc.run(f, (0.3,), ["random"], 1, 5, 0, tmp_path / "b", **kw)


def test_the_noise_phrase_reads_the_target(tmp_path):
    def phrase(noise: str = "", bounds: str = "") -> str:
        f = tmp_path / "t.toml"
        f.write_text(CAMPAIGN.replace("[falsify]\n", f"[model.noise]\n{noise}\n[falsify]\n", 1) + bounds)
        return wc.noise_phrase(load_campaign(f))

    assert phrase("") == "within the paper's noise bounds"
    assert phrase("scale = 0.5") == "within the paper's noise bounds"
    assert phrase("scale = 2.0") == "beyond the paper's noise bounds (noise.scale 2)"
    assert phrase("pos_far_m = 0.8") == "beyond the paper's noise bounds (noise.scale 1)"
    assert phrase('kind = "none"') == "without perception noise"
    assert phrase(bounds='"noise.scale" = [0.5, 2.0]\n') == "with the noise half-widths searched (noise.scale)"


def _target(tmp_path, text: str = CAMPAIGN) -> str:
    f = tmp_path / "t.toml"
    f.write_text(text)
    return str(f)


@pytest.mark.parametrize(("options", "fragment"), [
    (["--eps", "0.1,abc"], "--eps: 'abc' is not a number"),
    (["--eps", "1"], "--eps: 1 is outside [0, 1)"),
    (["--eps", "-0.1"], "--eps: -0.1 is outside [0, 1)"),
    (["--eps", "nan"], "--eps: nan is outside [0, 1)"),
    (["--eps", " , "], "--eps ' , ': give at least one level"),
    (["--eps", "0.1,0.1"], "--eps: 0.1 is given twice"),
    (["--methods", "cma,annealing"], "--methods: unknown annealing"),
])
def test_bad_options_are_one_line_and_run_nothing(tmp_path, monkeypatch, capsys, options, fragment):
    monkeypatch.setattr(wc, "run", lambda *a, **k: pytest.fail("nothing may run"))
    argv = [_target(tmp_path), *options, "--out-dir", str(tmp_path / "b"), "--write", str(tmp_path / "B.md")]
    assert wc.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("benchmarks.worst_case: error: ") and fragment in err[0], err
    assert not (tmp_path / "B.md").exists() and not (tmp_path / "b").exists()


@pytest.mark.parametrize(("text", "fragment"), [
    ('[campaign]\nname = "p"\nseed = 1\nepisodes = 1\n', "t.toml: no [falsify] table"),
    (CAMPAIGN.replace("[falsify]", '[model.mpc]\ncontroller = "mpcdc"\n[falsify]'),
     "controller mpcdc keeps no level ε"),
    (CAMPAIGN + '"barrier.epsilon" = [0.0, 0.5]\n', "barrier.epsilon is searched by the campaign's [falsify.bounds]"),
])
def test_bad_targets_are_one_line(tmp_path, capsys, text, fragment):
    assert wc.main([_target(tmp_path, text), "--out-dir", str(tmp_path / "b"), "--no-write"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("benchmarks.worst_case: error: ") and fragment in err[0], err
    assert not (tmp_path / "b").exists()


def test_main_writes_its_section_and_the_figure(tmp_path, monkeypatch, capsys):
    page = tmp_path / "B.md"
    page.write_text("# Benchmarks\n\n" + section.wrap("falsify", "the falsify table"))
    monkeypatch.setattr(wc, "run", lambda *a, **k: _broken())
    argv = [_target(tmp_path), "--eps", "0,0.3,0.5", "--trials", "3", "--budget", "12", "--out-dir",
            str(tmp_path / "b"), "--write", str(page)]
    assert wc.main(argv) == 0 and wc.main(argv) == 0  # rewritten in place, not appended
    text = page.read_text()
    begin, _ = section.markers("worst_case")
    assert text.count(begin) == 1 and "the falsify table" in text
    assert "**Headline.** Within the paper's noise bounds, `ellipse` at ε = 0.3 is broken by cma" in text
    assert (tmp_path / "b" / wc.FIGURE).is_file() and f"Figure: `{tmp_path / 'b' / wc.FIGURE}`" in text
    assert "written: " in capsys.readouterr().err
