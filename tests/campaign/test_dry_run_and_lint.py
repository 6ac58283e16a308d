"""`mcverify run --dry-run` (counts and a CPU estimate, nothing run or written), the warnings for
campaigns that cannot do what they seem to, and the -q / -v levels of the notices."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from mcverify import cli
from mcverify.campaign import cost, lint
from mcverify.campaign.spec import campaign_from_dict, load_campaign
from mcverify.solver import kernels

REPO = Path(__file__).resolve().parents[2]

# The first grid: epsilon x front-acceleration range, the burst left at its default (forever).
NO_OVERTAKE = {"campaign": {"name": "g", "seed": 1, "episodes": 2},
               "grid": {"barrier.epsilon": [0.1, 0.3], "scenario.front_accel_range_mps2": [[1.0, 3.0], [3.0, 5.0]]}}


def test_a_burst_that_lasts_forever_warns_that_no_episode_can_overtake():
    (warning,) = lint.warnings(campaign_from_dict(NO_OVERTAKE))
    assert warning.startswith("no episode can overtake in every cell")
    assert "front_accel_duration_s" in warning and "19.4" in warning


def test_a_limited_burst_gives_no_warning_and_a_mixed_grid_names_its_cells():
    raw = {**NO_OVERTAKE, "model": {"scenario": {"front_accel_duration_s": 2.0}}}
    assert lint.warnings(campaign_from_dict(raw)) == []
    raw = {"campaign": {"name": "g", "seed": 1, "episodes": 2},
           "grid": {"scenario.front_speed_kmh": [25, 72]}}  # 72 km/h = 20 m/s > the ego's 19.4 m/s
    (warning,) = lint.warnings(campaign_from_dict(raw))
    assert "'front_speed_kmh=72'" in warning and "'front_speed_kmh=25'" not in warning


def test_a_drawn_burst_warns_by_its_shortest_duration_and_names_the_fixed_value_it_replaces():
    raw = {**NO_OVERTAKE, "model": {"scenario": {"front_accel_duration_range_s": [7.0, 9.0]}}}
    (warning,) = lint.warnings(campaign_from_dict(raw))  # 1 m/s^2 for 7 s takes veh_f past the ego's 19.4 m/s
    assert warning.startswith("no episode can overtake") and "front_accel_duration_range_s's 7 s" in warning
    raw["model"]["scenario"] = {"front_accel_duration_range_s": [1.0, 9.0], "front_accel_onset_s": 3.5,
                                "front_accel_onset_range_s": [1.0, 4.0]}
    (warning,) = lint.warnings(campaign_from_dict(raw))
    assert warning == ("scenario.front_accel_onset_s is ignored in every cell: scenario.front_accel_onset_range_s "
                       "draws it per episode")


def test_a_time_limit_too_short_to_reach_vehf_warns():
    (warning,) = lint.warnings(load_campaign(REPO / "tests/fixtures/tiny.toml"))
    assert "ends as a timeout" in warning and "sim.max_time_s = 1 s" in warning


@pytest.mark.parametrize("name", ["smoke", "table2", "table3", "table4", "eps_sweep", "lambda0_grid", "fig7"])
def test_the_shipped_campaigns_raise_no_warning(name):
    assert lint.warnings(load_campaign(REPO / "campaigns" / f"{name}.toml")) == []


def test_estimate_scales_with_rate_backend_and_episodes():
    table2 = load_campaign(REPO / "campaigns/table2.toml")
    est = cost.estimate(table2, 8)
    assert est.episodes == 120 and est.cells == 4 and est.chunks == 16
    lo, hi = cost.SECONDS_PER_EPISODE[("vlcbf", False)]
    assert (est.cpu_s_low, est.cpu_s_high) == pytest.approx((120 * lo, 120 * hi))
    ipopt = cost.estimate(load_campaign(REPO / "campaigns/table2.toml", settings=["mpc.backend=ipopt"]), 8)
    assert ipopt.cpu_s_low == pytest.approx(cost.IPOPT_FACTOR * est.cpu_s_low)
    smoke = load_campaign(REPO / "campaigns/smoke.toml")  # 10 Hz: a fifth of the steps, each about twice the cost
    assert cost.cell_seconds(smoke.cells[0])[0] == pytest.approx(lo * 0.2**cost.RATE_EXPONENT)
    assert 0.38 < cost.cell_seconds(smoke.cells[0])[0] / lo < 0.42


def test_dry_run_prints_counts_and_writes_nothing(tmp_path: Path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", str(REPO / "campaigns/table2.toml"), "--dry-run", "--workers", "2"]) == 0
    out = capsys.readouterr().out
    assert "table2: 4 cells, 120 episodes" in out and "120 episodes in 16 chunks of up to 8" in out
    assert "estimated CPU: 9.0 min to 10.4 min; wall time on 2 worker(s): 4.5 min to 5.2 min" in out
    assert list(tmp_path.iterdir()) == []


def test_dry_run_shows_the_warnings(tmp_path: Path, capsys):
    path = tmp_path / "g.toml"
    path.write_text('[campaign]\nname = "g"\nepisodes = 3\n[grid]\n"barrier.epsilon" = [0.1, 0.3]\n'
                    '"scenario.front_accel_range_mps2" = [[1.0, 3.0], [3.0, 5.0]]\n')
    assert cli.main(["run", str(path), "--dry-run"]) == 0
    captured = capsys.readouterr()
    assert "mcverify: warning: no episode can overtake in every cell" in captured.err
    assert "g: 4 cells, 12 episodes" in captured.out
    assert cli.main(["run", str(path), "--dry-run", "-q"]) == 0
    assert "no episode can overtake" in capsys.readouterr().err, "-q keeps warnings"


def test_kernel_compilation_is_announced_with_its_expected_duration(tmp_path: Path, caplog):
    (tmp_path / "tocbf-N50-m2-000000000000").mkdir()
    (tmp_path / "tocbf-N50-m2-000000000000" / "manifest.json").write_text(
        '{"generate_seconds": 1.0, "compile_seconds": 29.0}')
    assert kernels.expected_build_time(tmp_path, "tocbf-N50-m2-123456789abc") == \
        "about 30 s; 1 such build(s) here took 30-30 s"
    assert "1-3 minutes" in kernels.expected_build_time(tmp_path, "tocbf-N50-m2-opp-123456789abc")

    def build(tmp: Path) -> dict:
        (tmp / "x.so").write_text("")
        (tmp / "manifest.json").write_text("{}")
        return {}

    with caplog.at_level(logging.INFO, logger="mcverify"):
        kernels._get_or_build(tmp_path, "tocbf-N50-m2-123456789abc", build, so_file="x.so")
        kernels._get_or_build(tmp_path, "tocbf-N50-m2-123456789abc", build, so_file="x.so")  # cached: silent
    notices = [r.getMessage() for r in caplog.records if "compiling" in r.getMessage()]
    assert notices == [f"compiling tocbf-N50-m2-123456789abc into {tmp_path} (once per machine; about 30 s; "
                       "1 such build(s) here took 30-30 s)"]


@pytest.mark.parametrize("flags, level", [([], logging.INFO), (["-q"], logging.WARNING), (["-v"], logging.DEBUG)])
def test_verbosity_flags_set_the_notice_level(flags, level, monkeypatch):
    seen = []
    monkeypatch.setattr(cli, "_cmd_kernels_list", lambda args: seen.append(logging.getLogger("mcverify").level))
    before = logging.getLogger("mcverify").level
    assert cli.main(["kernels", "list", *flags]) == 0
    assert seen == [level]
    assert logging.getLogger("mcverify").level == before, "main() leaves logging as it found it"


def _fake_kernel(root: Path, structure) -> None:
    """A cache entry as :func:`kernels._read_kernel` accepts it (a manifest and a shared object)."""
    folder = root / kernels.kernel_name(structure)
    folder.mkdir(parents=True)
    (folder / "manifest.json").write_text("{}")
    (folder / kernels.SO_FILE).write_text("")


def test_dry_runs_count_the_solver_kernels_not_yet_compiled(tmp_path: Path, capsys, monkeypatch):
    """Issue 51: run, falsify and estimate dry runs say how many kernels they would build (each 1-3
    minutes, once per machine), looking at the cache only."""
    from mcverify.ocp.layout import OcpStructure

    monkeypatch.setenv("MCVERIFY_KERNEL_DIR", str(tmp_path / "k"))
    campaign = load_campaign(REPO / "campaigns/falsify_theorem5_opposing.toml")
    assert cost.kernels_to_build(campaign.cells) == cost.KernelCount(2, 2)  # plain and with veh_o
    assert not (tmp_path / "k").exists(), "a count builds nothing"
    assert cli.main(["falsify", str(REPO / "campaigns/falsify_theorem5_opposing.toml"), "--dry-run",
                     "--budget", "10"]) == 0
    assert "2 of the 2 solver kernels it needs are not compiled yet: add 1-3 minutes for each" in \
        capsys.readouterr().out
    _fake_kernel(tmp_path / "k", OcpStructure.from_params(campaign.cells[0].params, with_opposing=True))
    assert cost.kernels_to_build(campaign.cells).text() == ("1 of the 2 solver kernels it needs is not compiled "
                                                            "yet: add 1-3 minutes for it (once per machine)")
    smoke = load_campaign(REPO / "campaigns/smoke.toml")
    assert cli.main(["run", str(REPO / "campaigns/smoke.toml"), "--dry-run"]) == 0
    assert "1 of the 1 solver kernel it needs is not compiled yet" in capsys.readouterr().out
    _fake_kernel(tmp_path / "k", OcpStructure.from_params(smoke.cells[0].params))
    assert cli.main(["estimate", str(REPO / "campaigns/smoke.toml"), "--dry-run", "--budget", "8"]) == 0
    assert "the solver kernel it needs (1) is compiled already" in capsys.readouterr().out
