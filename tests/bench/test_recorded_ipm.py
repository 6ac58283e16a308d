"""Recording the engine's backend solves and replaying them on the C interior point
(mcverify.bench.recorded_ipm): the replay reproduces the recorded IPM attempts, and the phase-1 /
restoration verdicts are computed per solve."""

from __future__ import annotations

import dataclasses

import numpy as np

from mcverify.bench import recorded_ipm as R
from mcverify.campaign.spec import campaign_from_dict
from mcverify.levels import Level
from mcverify.solver import kernels
from mcverify.solver.backends import Start
from mcverify.solver.ipm import COLD, WARM_ATTEMPTS


def _short_cell():
    raw = {"campaign": {"name": "rec", "seed": 3, "episodes": 1},
           "model": {"sim": {"max_time_s": 0.2}, "noise": {"kind": "paper"}}}
    return campaign_from_dict(raw).cells[0]


def test_replay_reproduces_the_recorded_attempts(tmp_path):
    cell = _short_cell()
    rec = R.record_engine([cell], 3, [0])
    assert len(rec.solves) >= 10 and len(rec.problems) >= 1
    R.save(rec, tmp_path / "rec.pkl")
    rec = R.load(tmp_path / "rec.pkl")
    rp = R.Replayer(rec, kernels.get_runtime_library("ipm").so_path)
    tol = cell.params.mpc.tol
    warm = [dataclasses.replace(o, tol=tol) for o in WARM_ATTEMPTS]
    for s in rec.solves:
        replayed = rp.engine_attempts(s, warm, dataclasses.replace(COLD, tol=tol))
        assert tuple(r.status for r in replayed) == tuple(t.split(":", 1)[1] for t in s.attempts)
        assert s.success == (replayed[-1].success or s.rescued_by_ipopt)


def test_verdicts_of_a_recorded_infeasible_solve():
    """A recorded solve whose warm start is the cold guess of an infeasible problem (front too fast)."""
    from mcverify.model import ModelParams
    from mcverify.solver.mpc import MpcSolver

    params = ModelParams()
    solver = MpcSolver(params)
    rec = R.Recording()
    solver.backend = R.RecordingBackend(solver.backend, rec)
    ego = np.array([10.0, 0.0, 0.0, 10.0])
    solver.solve(ego, np.array([64.0, 0.0, 18.0]), 1, Level(0.3, -(0.3 + 0.5 * 0.3**3)))
    (s,) = rec.solves
    assert s.certified_by_ipopt and R.engine_class(s) == "certified" and s.attempts == ("cold1:Line_Search_Failed",)
    s = dataclasses.replace(s, warm=Start(s.guess, np.zeros(s.guess.size), np.zeros(rec.problems[0].lbg.size)))
    v = R.verdicts(R.Replayer(rec, kernels.get_runtime_library("ipm").so_path), s, params.mpc.tol)
    assert (v.phase1_warm, v.phase1_cold, v.verdict) == ("Infeasible_Problem_Detected",) * 2 + ("infeasible",)
    assert not v.resto_converged and v.phase1_cpu_s > 0
    assert v.central_converged is False and v.central_cpu_s > 0  # infeasible: nothing converges
    table = R.verdict_table([v])
    assert table == {"certified": {"solves": 1, "infeasible": 1, "feasible": 0, "undecided": 0,
                                   "warm_only_infeasible": 0, "resto_converged": 0, "warm_started": 1,
                                   "central_converged": 0}}


def test_the_command_records_a_campaign_and_refuses_bad_input_in_one_line(tmp_path, capsys):
    toml = tmp_path / "c.toml"
    toml.write_text('[campaign]\nname = "c"\nseed = 3\nepisodes = 1\n[model.sim]\nmax_time_s = 0.2\n'
                    '[model.noise]\nkind = "paper"\n')
    out = tmp_path / "rec.pkl"
    assert R.main([str(toml), "--out", str(out), "--episodes", "0"]) == 0
    rec = R.load(out)
    assert len(rec.solves) >= 10 and capsys.readouterr().out.startswith(f"{len(rec.solves)} solves of 1 cell(s)")
    assert R.main([str(toml), "--out", str(out), "--cell", "nope"]) == 2
    assert R.main([str(toml), "--out", str(out), "--episodes", "zero"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0] == "mcverify: error: no cell 'nope' in " + str(toml) and len(err) == 2


def test_a_recording_pickled_under_dunder_main_loads(tmp_path, monkeypatch):
    """``python -m mcverify.bench.recorded_ipm`` used to pickle its classes as ``__main__.Recording``."""
    import sys

    rec = R.Recording(solves=[R.RecordedSolve(0, np.ones(2), None, np.zeros(3), False, "Solve_Succeeded", True,
                                              ("cold1:Converged",))])
    for cls in (R.Recording, R.RecordedSolve):
        monkeypatch.setattr(cls, "__module__", "__main__")
        monkeypatch.setattr(sys.modules["__main__"], cls.__name__, cls, raising=False)
    R.save(rec, tmp_path / "rec.pkl")
    monkeypatch.undo()
    assert b"__main__" in (tmp_path / "rec.pkl").read_bytes()
    loaded = R.load(tmp_path / "rec.pkl")
    assert isinstance(loaded, R.Recording) and loaded.solves[0].attempts == ("cold1:Converged",)


def test_a_recording_with_the_old_after_hard_flag_loads_as_a_hard_run(tmp_path):
    """Recordings made before ``Start.hard_run`` held a boolean ``after_hard``; it loads as a run of 1 or 0."""
    def old_start(flag: bool) -> Start:
        start = Start(np.zeros(2), np.zeros(2), np.zeros(1))
        del start.__dict__["hard_run"]  # the instance as an old pickle restores it: after_hard, no hard_run
        start.__dict__["after_hard"] = flag
        return start

    solves = [R.RecordedSolve(0, np.ones(2), old_start(flag), np.zeros(2), False, "IPM_Converged", True,
                              ("warm1:Converged",)) for flag in (True, False)]
    R.save(R.Recording(solves=solves), tmp_path / "old.pkl")
    loaded = R.load(tmp_path / "old.pkl")
    assert [s.warm.hard_run for s in loaded.solves] == [1, 0]
    assert all("after_hard" not in vars(s.warm) for s in loaded.solves)
