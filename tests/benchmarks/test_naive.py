"""The benchmark's naive reference (benchmarks.naive) solves the engine's problem, the paper's way."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks.naive import NaiveOptiSolver, run_naive
from mcverify import ocp
from mcverify.levels import Level
from mcverify.model import ModelParams
from mcverify.solver.mpc import MpcSolver

P = ModelParams()
LEVEL = Level(epsilon=0.3, lambda0=-(0.3 + 0.5 * 0.3**3))
EGO = np.array([10.0, 0.0, 0.0, 10.0])
FRONT = np.array([64.0, 0.0, 25 / 3.6])


@pytest.mark.parametrize("direction", [1, -1])
def test_opti_and_the_compiled_kernel_solve_the_same_problem(direction):
    structure = ocp.OcpStructure.from_params(P)
    naive = NaiveOptiSolver(P, structure).solve(EGO, FRONT, direction, LEVEL)
    engine = MpcSolver(P, structure).solve(EGO, FRONT, direction, LEVEL)
    assert naive.success and engine.success, (naive.status, engine.status)
    assert naive.total_time_s == pytest.approx(engine.total_time_s, rel=1e-4, abs=1e-4)


@pytest.mark.slow  # closed-loop episodes through the naive loop; a benchmark tool, not the engine
def test_naive_loop_runs_the_same_controller():
    from mcverify.campaign.spec import campaign_from_dict

    camp = campaign_from_dict({"campaign": {"name": "t", "seed": 1, "episodes": 1},
                               "model": {"sim": {"control_period_s": 0.1, "substeps": 20, "max_time_s": 1.0}}})
    cell = camp.cells[0]
    row = run_naive(cell, [0], camp.seed)[0]
    assert row["steps"] == 10 and row["solves"] >= 20  # Q1 and Q2 every control step
    assert row["cell_episode"] == 0 and row["outcome"] == "timeout" and row["safe"]
    assert dataclasses.asdict(cell.params) == dataclasses.asdict(camp.cells[0].params)
