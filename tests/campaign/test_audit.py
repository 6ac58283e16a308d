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
