"""mcverify.campaign.audit: a stored episode re-simulated with the reference solver on the same noise."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from mcverify import cli, store
from mcverify.campaign import audit
from mcverify.campaign.runner import campaign_from_manifest

TINY = Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("audit") / "run"
    assert cli.main(["run", str(TINY), "--episodes", "1", "--run-dir", str(out), "--workers", "1",
                     "--no-progress", "-q"]) == 0
    return out


def test_the_reference_cell_changes_the_backend_only(run_dir):
    cell = campaign_from_manifest(store.read_json(run_dir / store.MANIFEST)).cells[0]
    ref = audit.reference_cell(cell)
    assert cell.params.mpc.backend == "ipm" and ref.params.mpc.backend == "ipopt"
    assert dataclasses.replace(ref.params.mpc, backend="ipm") == cell.params.mpc
    assert (ref.params.noise, ref.params.scenario, ref.level, ref.index) == (
        cell.params.noise, cell.params.scenario, cell.level, cell.index)


def test_an_episode_is_re_simulated_with_ipopt_on_the_same_draws(run_dir, capsys):
    assert cli.main(["replay", str(run_dir), "1", "--backend", "ipopt"]) == 0
    out = capsys.readouterr().out
    res = audit.audit(run_dir, 1, run_dir / "audit-api")
    assert res.reference is not None and res.trajectory_path.is_file() and res.plot_path.is_file()
    assert res.reference["cell_episode"] == res.stored["cell_episode"]
    assert res.reference["sample_front_accel_mps2"] == res.stored["sample_front_accel_mps2"]
    assert "IPM" not in res.reference["solver_statuses"] and "IPM" in res.stored["solver_statuses"]
    same = bool(res.reference["safe"]) == bool(res.stored["safe"])
    assert res.verdict is (audit.AuditVerdict.CONFIRMED if same else audit.AuditVerdict.SOLVER_DEPENDENT)
    assert res.describe() in out and "the reference solver ipopt:" in out
    assert (run_dir / "replay" / "episode-000001-ipopt.parquet").is_file()


def test_a_run_made_with_the_reference_solver_has_nothing_to_audit(tmp_path):
    out = tmp_path / "ref"
    assert cli.main(["run", str(TINY), "--episodes", "1", "--run-dir", str(out), "--workers", "1", "--no-progress",
                     "-q", "--set", "mpc.backend=ipopt"]) == 0
    res = audit.audit(out, 0)
    assert res.verdict is audit.AuditVerdict.REFERENCE_RUN and res.reference is None
    assert "nothing to audit" in res.describe()


def test_audit_mistakes_are_one_line(run_dir, capsys):
    assert cli.main(["replay", str(run_dir), "1", "--backend", "ipopt", "--cell", "x"]) == 2
    assert cli.main(["replay", str(run_dir), "99", "--backend", "ipopt"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("mcverify: error:") for line in err)
    assert "no episode 99" in err[1]


def test_the_report_says_what_the_reference_solver_made_of_each_counterexample(run_dir, tmp_path):
    """audits.json, as `replay --backend ipopt` and `report --audit` keep it, becomes a column of the
    counterexample table; an unsafe episode without an audit reads "not audited"."""
    from mcverify.reporting import counterexample_report

    records = [{"episode_id": e, "cell": "c", "robustness": -0.1, "failure_mode": "ellipse/Q2", "replay": "r",
                "first_unsafe_t_s": 1.0} for e in (3, 4, 5)]
    audits = {"3": {"verdict": "confirmed by the reference solver", "backend": "ipopt", "outcome": "went_back",
                    "safe": False, "reference_outcome": "went_back", "reference_safe": False},
              "4": {"verdict": "solver-dependent", "backend": "ipopt", "outcome": "went_back", "safe": False,
                    "reference_outcome": "overtook", "reference_safe": True}}
    t = counterexample_report.table(records, "safe", 10, audits=audits, run_dir="RUN")
    col = t.columns.index("reference solver")
    assert [r[col] for r in t.rows] == ["confirmed (went_back)", "solver-dependent (ipopt: overtook, safe)",
                                        "not audited"]
    assert any("mcverify report RUN --audit" in n for n in t.notes)
    assert "reference solver" not in counterexample_report.table(records, "safe", 10).columns


def test_an_audit_is_kept_for_the_report(run_dir):
    res = audit.audit(run_dir, 0, run_dir / "audit-keep")
    audit.record(run_dir, res)
    kept = audit.recorded(run_dir)["0"]
    assert kept["verdict"] == res.verdict.value and kept["reference_safe"] == bool(res.reference["safe"])
    table = store.read_episodes(run_dir)
    pending = [e for e, safe in zip(table.column("episode_id").to_pylist(), table.column("safe").to_pylist(),
                                    strict=True) if safe is False and str(e) not in audit.recorded(run_dir)]
    assert [r.episode_id for r in audit.audit_unsafe(run_dir)] == pending  # the unsafe ones not yet audited
    assert audit.audit_unsafe(run_dir) == []  # never repeated
