"""mcverify falsify: [falsify] validation, methods, resume equals an uninterrupted search."""

from __future__ import annotations

import copy
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest

from mcverify.analysis import robustness as rb
from mcverify.campaign import executors
from mcverify.campaign.search_space import REQUIREMENT_NAMES
from mcverify.campaign.spec import campaign_from_dict
from mcverify.errors import CampaignError, RunError
from mcverify.falsify import methods, search
from tests.falsify import fake_episodes

RAW = {
    "campaign": {"name": "fz", "seed": 11, "episodes": 1},
    "falsify": {
        "requirement": "ellipse", "population": 4, "stop_at_first": False,
        "bounds": {"scenario.front_speed_mps": [5.0, 9.0], "opposing.speed_mps": [8.0, 19.0]},
    },
}


def _config(method="cma", budget=12, raw=RAW):
    return search.SearchConfig(raw=copy.deepcopy(raw), source="<test>", method=method, budget=budget, seed=3,
                               requirement=raw["falsify"]["requirement"])


def _kw():
    return {"make_executor": executors.SerialExecutor, "episode_fn": fake_episodes.episodes}


def test_requirement_lists_agree():
    assert set(REQUIREMENT_NAMES) == set(rb.REQUIREMENTS)


@pytest.mark.parametrize(
    ("falsify", "message"),
    [
        ({"bounds": {}}, "non-empty [falsify.bounds]"),
        ({"bounds": {"scenario.nope": [0, 1]}}, "unknown model field"),
        ({"bounds": {"scenario.front_speed_mps": [3, 1]}}, "low < high"),
        ({"bounds": {"scenario.front_speed_mps": [1]}}, "[low, high]"),
        ({"bounds": {"mpc.horizon": [10, 20]}}, "only numeric (float)"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "population": 1}, "population"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "requirement": "fast"}, "unknown requirement"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "stop_at_first": "yes"}, "stop_at_first"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "stop_episodes": 1}, "stop_episodes"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "common_noise": "yes"}, "common_noise"),
        ({"bounds": {"noise.opp_x_segments": [-1, 1]}}, 'search its elements as "noise.opp_x_segments[0]"'),
        ({"bounds": {"scenario.front_speed_mps[0]": [1, 2]}}, "selects an element of a list field"),
        ({"bounds": {"noise.opp_x_segments[1]": [-1, 1]}}, "must be [0] to [K-1]"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "budget": 3}, "unknown key"),
        ("x", "must be a table"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "nominal": {"opposing.speed_mps": {"mean": 1, "std": 1}}},
         "not a searched field"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "nominal": {"scenario.front_speed_mps": {"mean": 3,
                                                                                                    "std": 1}}},
         "mean must lie in the bounds [1, 2]"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "nominal": {"scenario.front_speed_mps": {"mean": 1.5,
                                                                                                    "std": 0}}},
         "std must be a positive number"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "nominal": {"scenario.front_speed_mps": [1.5, 0.2]}},
         "expected { mean = m, std = s }"),
        ({"bounds": {"scenario.front_speed_mps": [1, 2]}, "nominal": 3}, "must be a table"),
    ],
)
def test_bad_falsify_tables_are_one_line(falsify, message):
    raw = {"campaign": {"name": "x", "seed": 1, "episodes": 1}, "falsify": falsify}
    with pytest.raises(CampaignError) as err:
        campaign_from_dict(raw, source="f.toml")
    text = str(err.value)
    assert message in text and "\n" not in text and text.startswith("f.toml [falsify]")


def test_a_grid_is_refused(tmp_path):
    raw = {**copy.deepcopy(RAW), "grid": {"scenario.front_speed_mps": [5.0, 6.0]}}
    with pytest.raises(CampaignError, match="defines one target"):
        search.start(_config(raw=raw), tmp_path / "s", **_kw())


def test_cli_bad_falsify_table_exits_2_with_one_line(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text('[campaign]\nname = "b"\nseed = 1\nepisodes = 1\n'
                 '[falsify.bounds]\n"scenario.front_speed_mps" = [2, 1]\n')
    proc = subprocess.run([sys.executable, "-m", "mcverify.cli", "falsify", str(f), "--budget", "4"],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "low < high" in proc.stderr


def _needs(method):
    """bo needs the optional optuna; skip its tests where it is not installed."""
    if method == "bo":
        pytest.importorskip("optuna")


@pytest.mark.parametrize("method", [m for m in methods.METHODS if m != "splitting"])
def test_methods_are_deterministic_for_a_seed(method):
    _needs(method)
    def run(seed):
        s = methods.searcher(method, 3, 6, seed)
        out = []
        for _ in range(4):
            x = s.ask()
            s.tell(x, np.sum((x - 0.7) ** 2, axis=1))
            out.append(x)
        return np.concatenate(out)

    a, b = run(5), run(5)
    assert np.array_equal(a, b) and a.shape == (24, 3)
    assert ((a >= 0) & (a <= 1)).all()
    assert not np.array_equal(a, run(6))


# one method by default: the resume path is the same for all (cross-entropy and bo slow-marked for time)
@pytest.mark.parametrize("method", ["cma", pytest.param("cross-entropy", marks=pytest.mark.slow),
                                    pytest.param("bo", marks=pytest.mark.slow)])
def test_resume_mid_search_equals_an_uninterrupted_search(tmp_path, method):
    _needs(method)
    whole = search.start(_config(method), tmp_path / "whole", **_kw())
    with pytest.raises(RunError, match="test hook"):
        search.start(_config(method), tmp_path / "cut", stop_after_generations=1, **_kw())
    # a generation killed half-way: its folder exists without a finished manifest
    resumed = search.resume(tmp_path / "cut", **_kw())
    assert whole.episodes == resumed.episodes == 12
    a = pq.read_table(tmp_path / "whole" / search.SEARCH)
    b = pq.read_table(tmp_path / "cut" / search.SEARCH)
    assert a.equals(b)
    # every candidate is an ordinary row of its generation, with the candidate's values as overrides
    ev = whole.evaluations[5]
    gen = tmp_path / "whole" / search.GENERATIONS / f"g{ev.generation:03d}"
    manifest = search.store.read_json(gen / search.store.MANIFEST)
    assert manifest["cells"][ev.candidate]["overrides"] == ev.values


@pytest.mark.parametrize("stop_episodes", [False, True])
def test_stop_episodes_makes_every_generation_stop_at_the_requirement(tmp_path, stop_episodes):
    """With stop_episodes the generations' episodes run with sim.stop_at = the searched requirement (the
    rollout then ends them at their first violation: tests/episode/test_stop.py); the manifest keeps it,
    so replay re-simulates the stopped episode."""
    raw = copy.deepcopy(RAW)
    raw["falsify"]["stop_episodes"] = stop_episodes
    config = search.SearchConfig(raw=raw, source="<test>", method="random", budget=8, seed=3, requirement="safe")
    search.start(config, tmp_path / "s", **_kw())
    for gen in sorted((tmp_path / "s" / search.GENERATIONS).iterdir()):
        campaign = search.runner.campaign_from_manifest(search.store.read_json(gen / search.store.MANIFEST))
        assert {c.params.sim.stop_at for c in campaign.cells} == {"safe" if stop_episodes else ""}


@pytest.mark.parametrize("method", ["cma", "bo"])
def test_search_finds_the_counterexample_and_reports_it(tmp_path, method):
    _needs(method)
    raw = copy.deepcopy(RAW)
    raw["falsify"]["stop_at_first"] = True
    res = search.start(_config(method, budget=60, raw=raw), tmp_path / "s", **_kw())
    cex = pq.read_table(tmp_path / "s" / search.COUNTEREXAMPLES).to_pylist()
    assert res.first_counterexample is not None and res.episodes <= 60
    assert cex and all(r["robustness"] < 0 for r in cex)
    assert cex[0]["replay"].startswith(f"mcverify replay {tmp_path / 's' / search.GENERATIONS}")
    report = (tmp_path / "s" / "report.md").read_text()
    assert "first counterexample" in report and "Counterexamples (ellipse)" in report
    # grouped by failure mode and region of the searched space (scaled by its bounds)
    assert all(r["region"] >= 1 and r["failure_mode"] == "ellipse/planned" for r in cex)
    assert all(5.0 <= r["param:scenario.front_speed_mps"] <= 9.0 for r in cex)
    assert "## Failure regions" in report and "scenario.front_speed_mps" in report.split("## Failure regions")[1]
    page = (tmp_path / "s" / "report.html").read_text()  # the same content as one self-contained page
    assert page.count("data:image/png;base64,") == 1 + report.count("![worst counterexample]")
    assert 'id="tab-counterexamples"' in page and 'id="tab-failure_regions"' in page
    assert "<dt><strong>ellipse</strong></dt>" in page.split('id="definitions"')[1].split("</dl>")[0][:200]


def test_a_search_that_finds_nothing_reports_its_minimum(tmp_path):
    raw = copy.deepcopy(RAW)
    raw["falsify"]["bounds"] = {"scenario.front_speed_mps": [5.0, 6.0], "opposing.speed_mps": [8.0, 9.0]}
    res = search.start(_config("random", budget=8, raw=raw), tmp_path / "s", **_kw())
    assert res.first_counterexample is None and res.min_robustness > 0
    report = (tmp_path / "s" / "report.md").read_text()
    assert "none found within 8 episodes" in report and "minimum robustness reached" in report
    page = (tmp_path / "s" / "report.html").read_text()
    assert "none found within 8 episodes" in page and "No episode violated <code>" in page


def test_piecewise_constant_offsets_are_searched_as_list_elements(tmp_path):
    """[falsify.bounds] "noise.opp_x_segments[0]" .. "[K-1]": each element is one coordinate; the
    candidate's cell gets the whole list (so the episode's inputs, and replay, have it)."""
    raw = copy.deepcopy(RAW)
    raw["falsify"]["bounds"] = {"scenario.front_speed_mps": [5.0, 9.0], "noise.structured_share": [0.0, 1.0],
                                "noise.opp_x_segments[0]": [-1.0, 1.0], "noise.opp_x_segments[1]": [-1.0, 1.0],
                                "noise.opp_x_segments[2]": [-1.0, 1.0]}
    res = search.start(_config("cma", budget=8, raw=raw), tmp_path / "s", **_kw())
    assert res.space.dimension == 5
    table = pq.read_table(tmp_path / "s" / search.SEARCH).to_pylist()
    for ev, row in zip(res.evaluations, table, strict=True):
        gen = tmp_path / "s" / search.GENERATIONS / f"g{ev.generation:03d}"
        manifest = search.store.read_json(gen / search.store.MANIFEST)
        segments = [ev.values[f"noise.opp_x_segments[{i}]"] for i in range(3)]
        assert manifest["cells"][ev.candidate]["overrides"]["noise.opp_x_segments"] == segments
        cell = search.runner.campaign_from_manifest(manifest).cells[ev.candidate]
        assert cell.params.noise.opp_x_segments == tuple(segments)
        assert row["noise.opp_x_segments[1]"] == segments[1] and all(-1 <= x <= 1 for x in segments)


def _fake_start(monkeypatch):
    """`mcverify falsify` in this process with the cheap episodes (the command's own folder logic)."""
    real = search.start

    def start(config, out_dir, **kw):
        kw.update(make_executor=executors.SerialExecutor, episode_fn=fake_episodes.episodes)
        return real(config, out_dir, **kw)

    monkeypatch.setattr(search, "start", start)


def test_falsify_out_is_a_parent_folder_and_run_dir_the_folder_like_run(tmp_path, monkeypatch, capsys):
    from mcverify import cli  # noqa: PLC0415

    _fake_start(monkeypatch)
    f = tmp_path / "fz.toml"
    f.write_text('[campaign]\nname = "fz"\nseed = 11\nepisodes = 1\n[falsify]\nrequirement = "ellipse"\n'
                 'population = 4\n[falsify.bounds]\n"scenario.front_speed_mps" = [5.0, 9.0]\n')
    base = ["falsify", str(f), "--budget", "4", "--method", "random", "--no-progress"]
    # --out DIR: a new folder DIR/falsify-<name>-<method>-<timestamp>, twice in the same second too
    assert cli.main([*base, "--out", str(tmp_path / "parent")]) == 0
    assert cli.main([*base, "--out", str(tmp_path / "parent")]) == 0
    made = sorted(p.name for p in (tmp_path / "parent").iterdir())
    assert len(made) == 2 and all(n.startswith("falsify-fz-random-") for n in made)
    assert all((tmp_path / "parent" / n / "report.md").is_file() for n in made)
    # --run-dir OUT: that folder; then --resume OUT
    assert cli.main([*base, "--run-dir", str(tmp_path / "exact")]) == 0
    assert (tmp_path / "exact" / search.CONFIG).is_file()
    assert cli.main(["falsify", "--resume", str(tmp_path / "exact"), "--no-progress"]) == 0
    # default parent: $MCVERIFY_RESULTS
    monkeypatch.setenv("MCVERIFY_RESULTS", str(tmp_path / "env"))
    assert cli.main(base) == 0 and len(list((tmp_path / "env").iterdir())) == 1
    capsys.readouterr()
    for argv, message in (([*base, "--out", "a", "--run-dir", "b"], "not both"),
                          (["falsify", "--resume", str(tmp_path / "exact"), "--run-dir", "b"], "--resume keeps")):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err


def test_bo_without_optuna_is_one_line(tmp_path, monkeypatch, capsys):
    from mcverify import cli  # noqa: PLC0415

    monkeypatch.setitem(sys.modules, "optuna", None)  # `import optuna` now raises ImportError
    with pytest.raises(RunError, match=r"needs optuna \(the optional extra"):
        methods.searcher("bo", 2, 4, 0)
    f = tmp_path / "fz.toml"
    f.write_text('[campaign]\nname = "fz"\nseed = 1\nepisodes = 1\n[falsify.bounds]\n'
                 '"scenario.front_speed_mps" = [5.0, 9.0]\n')
    assert cli.main(["falsify", str(f), "--budget", "4", "--method", "bo", "--run-dir", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert "needs optuna" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "s").exists()  # refused before anything is written


def test_a_nominal_distribution_maps_the_unit_cube_through_its_truncated_normal_quantiles():
    raw = copy.deepcopy(RAW)
    raw["falsify"]["nominal"] = {"scenario.front_speed_mps": {"mean": 6.0, "std": 0.5}}
    space = campaign_from_dict(raw, source="f.toml").falsify
    from statistics import NormalDist  # noqa: PLC0415

    values = [space.values([u, u]) for u in (0.0, 0.1, 0.5, 0.9, 1.0)]
    speeds = [v["scenario.front_speed_mps"] for v in values]
    assert speeds[0] == 5.0 and speeds[-1] == 9.0  # the ends of the cube are the bounds
    lo, hi = NormalDist(6.0, 0.5).cdf(5.0), NormalDist(6.0, 0.5).cdf(9.0)
    for u, x in zip((0.1, 0.5, 0.9), speeds[1:4], strict=True):  # the u-quantile of the truncated normal
        assert NormalDist(6.0, 0.5).cdf(x) == pytest.approx(lo + u * (hi - lo), abs=1e-12)
    assert [v["opposing.speed_mps"] for v in values] == [8.0, 9.1, 13.5, 17.9, 19.0]  # no nominal: uniform
    assert "nominal N(6, 0.5²) truncated" in space.describe()
    rng = np.random.default_rng(0)  # random search on the cube = draws from the nominal distribution
    draws = np.array([space.values([u, 0.5])["scenario.front_speed_mps"] for u in rng.random(4000)])
    assert abs(draws.mean() - 6.0) < 0.05 and abs(draws.std() - 0.5) < 0.05
