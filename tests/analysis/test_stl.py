"""STL requirements (mcverify.analysis.stl, rtamt): robustness on constructed trajectories, one-line
errors, and the acceptance test: a formula restating a built-in requirement gives the built-in's
robustness on stored episodes of a real (tiny) campaign."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mcverify import store
from mcverify.analysis import robustness as rb
from mcverify.analysis import stl
from mcverify.analysis.theorem5 import theorem5_step_margin

REPO = Path(__file__).resolve().parents[2]


def _traj(h, gap=None, opp_gap=None):
    n = len(h)
    return {"t_s": np.arange(1, n + 1) * 0.05, "h_front": np.asarray(h, dtype=float),
            "gap_front_m": np.asarray(gap if gap is not None else np.ones(n), dtype=float),
            "gap_opp_m": np.asarray(opp_gap if opp_gap is not None else np.full(n, np.nan), dtype=float)}


def test_always_and_eventually_on_a_constructed_trajectory():
    traj = _traj([0.9, 0.5, 0.2, 0.7])
    assert rb.robustness({}, "stl:always (h_ef >= 0.3)", traj) == 0.2 - 0.3
    assert rb.robustness({}, "stl:eventually (h_ef >= 0.8)", traj) == pytest.approx(0.1)
    # time bounds in seconds at the recorded sub-steps (0.05 s apart): the first 0.1 s are 3 samples
    assert rb.robustness({}, "stl:always[0:0.1] (h_ef >= 0.3)", traj) == pytest.approx(-0.1)
    assert rb.robustness({}, "stl:always[0:0.05] (h_ef >= 0.3)", traj) == pytest.approx(0.2)
    both = rb.robustness({}, "stl:always (h_ef >= 0 and gap_front_m > 0.5)", _traj([0.9, 0.8], gap=[2.0, 0.6]))
    assert both == pytest.approx(0.1)


def test_nan_samples_read_as_nothing_to_violate():
    """No veh_o: gap_opp_m is NaN, which never violates (the built-in collision_opp's +inf)."""
    assert rb.robustness({}, "stl:always (gap_opp_m > 0)", _traj([0.5, 0.5])) == math.inf
    assert rb.robustness({}, "stl:always (gap_opp_m > 1)", _traj([0.5, 0.5], opp_gap=[np.nan, 0.4])) \
        == pytest.approx(-0.6)


def test_without_a_trajectory_or_for_an_error_row_the_value_is_unknown():
    assert math.isnan(rb.robustness({}, "stl:always (h_ef >= 0)"))
    assert math.isnan(rb.robustness({"outcome": "error"}, "stl:always (h_ef >= 0)", _traj([1.0])))


@pytest.mark.parametrize(("name", "message"), [
    ("stl:always (h_eff >= 0)", "unknown signal 'h_eff'"),
    ("stl:always (h_ef >= ", "Syntax ERROR"),
    ("stl:   ", "empty STL formula"),
])
def test_bad_formulas_are_one_line_value_errors(name, message):
    with pytest.raises(ValueError, match=message) as err:
        rb.check_requirement(name)
    assert "\n" not in str(err.value)


def test_every_declared_signal_is_readable_from_a_recorded_trajectory_shape():
    traj = {c: np.array([0.5, np.nan]) for c in stl.TRAJECTORY_SIGNALS} | {"t_s": np.array([0.1, 0.2])}
    for name in stl.SIGNALS:
        assert stl.signal(traj, name).shape == (2,), name


def _falsify(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mcverify.cli", "falsify", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=300)


@pytest.mark.parametrize(("requirement", "message"), [
    ("stl:always (speed >= 0)", "--requirement: STL formula 'always (speed >= 0)': unknown signal 'speed'"),
    pytest.param("stl:always (h_ef >=", "--requirement: STL formula 'always (h_ef >=': RTAMT Exception",
                 marks=pytest.mark.slow),  # a subprocess each (7 s); the parser's errors are tested above
])
def test_the_command_line_refuses_a_bad_formula_in_one_line(requirement, message):
    out = _falsify("campaigns/falsify_vlcbf_eps03_paper_noise.toml", "--budget", "2", "--dry-run",
                   "--requirement", requirement)
    assert out.returncode == 2, out.stderr
    assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr


@pytest.mark.slow  # about 15 s (subprocesses)
def test_the_command_line_accepts_an_stl_requirement_unless_episodes_stop_at_violations(tmp_path):
    source = (REPO / "campaigns/falsify_vlcbf_eps03_paper_noise.toml").read_text(encoding="utf-8")
    assert "stop_episodes = true" in source
    stopping = _falsify("campaigns/falsify_vlcbf_eps03_paper_noise.toml", "--budget", "2", "--dry-run",
                        "--requirement", "stl:always (h_ef >= 0.3)")
    assert stopping.returncode == 2 and "stop_episodes = true" in stopping.stderr, stopping.stderr
    path = tmp_path / "campaign.toml"
    path.write_text(source.replace("stop_episodes = true", "stop_episodes = false"), encoding="utf-8")
    out = _falsify(str(path), "--budget", "2", "--dry-run", "--requirement", "stl:always (h_ef >= 0.3)")
    assert out.returncode == 0, out.stderr
    assert "stl:always (h_ef >= 0.3)" in out.stdout + out.stderr


# ----------------------------------------------------------------------------- stored episodes


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    from mcverify.campaign import executors, runner  # noqa: PLC0415
    from mcverify.campaign.spec import load_campaign  # noqa: PLC0415

    run_dir = tmp_path_factory.mktemp("stl") / "run"
    runner.run(load_campaign(REPO / "tests" / "fixtures" / "tiny.toml"), run_dir,
               executor=executors.SerialExecutor(), progress=False)
    return run_dir


@pytest.mark.slow
def test_stl_restating_a_built_in_requirement_gives_its_robustness_on_stored_episodes(tiny_run):
    rows = {int(r["episode_id"]): r for r in store.read_episodes(tiny_run).to_pylist()}
    stored = (tiny_run / store.TRAJECTORY_DIR).glob("episode-??????.parquet")
    recorded = sorted(int(p.stem.split("-")[1]) for p in stored)
    assert len(recorded) == 2
    for eid in recorded:
        row, traj = rows[eid], store.read_trajectory(tiny_run, eid)
        assert rb.robustness(row, "stl:always (h_ef >= 0)", traj) == rb.robustness(row, "ellipse")
        eps = float(row["epsilon"])
        if float(row["h0_front"]) >= eps:
            assert rb.robustness(row, f"stl:always (h_ef >= {eps!r})", traj) == rb.robustness(row, "invariance")
        if not row["collision_front"]:
            assert rb.robustness(row, "stl:always (gap_front_m > 0)", traj) == rb.robustness(row, "collision_front")
        # the graded Theorem 5: the row's margin is the trajectory's lowest per-step margin, and STL restates it
        assert math.isfinite(row["theorem5_margin"])
        assert row["theorem5_margin"] == float(theorem5_step_margin(traj).min())
        assert rb.robustness(row, "stl:always (theorem5_margin >= 0)", traj) == rb.robustness(row, "theorem5")
