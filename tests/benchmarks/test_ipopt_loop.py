"""The fair baseline of the engine benchmark (compiled, primal-dual warm-started IPOPT loop) and the
solve-class bookkeeping."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks.ipopt_loop import ExpandedIpoptBackend, expanded_ipopt_solver
from benchmarks.solve_classes import ClassTally, SolveClass, TimedSolver, classify
from mcverify.levels import Level
from mcverify.ocp import OcpStructure
from mcverify.solver.mpc import MpcSolution, MpcSolver
from mcverify.solver.status import SolveOutcome, SolveRoute, SolveStatus


def _sol(success: bool, status: SolveStatus, retried_cold: bool = False) -> MpcSolution:
    z = np.zeros(1)
    return MpcSolution(success, status, 1, 0.0, 1.0, z, z, z, None, retried_cold=retried_cold)


@pytest.mark.parametrize(("success", "status", "cold", "expected"), [
    (True, SolveStatus.ipm("Converged"), False, SolveClass.CONVERGED),
    (True, SolveStatus.ipopt("Solve_Succeeded"), False, SolveClass.CONVERGED),
    (True, SolveStatus.ipopt("Solve_Succeeded").via(SolveRoute.FALLBACK), False, SolveClass.RESCUED),
    (True, SolveStatus.ipopt("Solve_Succeeded"), True, SolveClass.RESCUED),  # the IPOPT loop's cold retry
    (False, SolveStatus.ipopt("Infeasible_Problem_Detected").via(SolveRoute.FALLBACK), True,
     SolveClass.CERTIFIED_INFEASIBLE),
    (False, SolveStatus.ipopt("Infeasible_Problem_Detected"), True, SolveClass.CERTIFIED_INFEASIBLE),
    (False, SolveStatus.ipm("Line_Search_Failed").via(SolveRoute.PRESUMED), False, SolveClass.PRESUMED_INFEASIBLE),
    (False, SolveStatus.ipopt("Infeasible_Problem_Detected").via(SolveRoute.PRESUMED), False,
     SolveClass.PRESUMED_INFEASIBLE),
    (False, SolveStatus.ipopt("Maximum_Iterations_Exceeded").via(SolveRoute.FALLBACK), True, SolveClass.OTHER_FAILURE),
    (False, SolveStatus("x", SolveOutcome.EXCEPTION), False, SolveClass.OTHER_FAILURE),
])
def test_solve_classes(success, status, cold, expected):
    assert classify(_sol(success, status, cold)) is expected


def test_timed_solver_tallies_by_class_and_delegates():
    class Fake:
        kernel_hash = "k"

        def __init__(self):
            self.results = [_sol(True, SolveStatus.ipm("Converged")), _sol(False, SolveStatus.ipm("X"))]

        def solve(self, *args, **kwargs):
            return self.results.pop(0)

    tally = ClassTally()
    timed = TimedSolver(Fake(), tally)
    timed.solve(1, 2, fast_only=True), timed.solve()
    assert timed.kernel_hash == "k"
    d = tally.as_dict()
    assert d["converged"]["solves"] == 1 and d["other failure"]["solves"] == 1 and d["rescued"]["solves"] == 0
    assert list(d) == [c.value for c in SolveClass] and tally.total_cpu_s >= 0.0
    other = ClassTally()
    other.merge(tally), other.merge(tally)
    assert other.count[SolveClass.CONVERGED] == 2


def _start(params):
    """Measured state at Table II's start: the ego at x = 10 m and 10 m/s, veh_f at 64 m and 25 km/h."""
    y = params.road.ego_lane_y_m
    return np.array([10.0, y, 0.0, 10.0]), np.array([64.0, y, 6.944])


@pytest.fixture(scope="module")
def params():
    from mcverify.model import ModelParams

    return ModelParams()


@pytest.mark.slow  # builds and runs the expanded IPOPT baseline (about 35 s)
def test_expanded_ipopt_solves_like_the_reference(params):
    structure = OcpStructure.from_params(params)
    ref = MpcSolver(dataclasses.replace(params, mpc=dataclasses.replace(params.mpc, backend="ipopt")), structure)
    user = expanded_ipopt_solver(params, structure)
    assert isinstance(user.backend, ExpandedIpoptBackend)
    ego, front = _start(params)
    a = ref.solve(ego, front, 1, Level(0.0, 0.0))
    b = user.solve(ego, front, 1, Level(0.0, 0.0))
    assert a.success and b.success and b.status.raw == "Solve_Succeeded"
    assert abs(a.total_time_s - b.total_time_s) < 1e-6
    # warm-started from its own solution (primal-dual, mu_init 1e-7): few iterations, same plan
    c = user.solve(ego, front, 1, Level(0.0, 0.0), warm=b.warm)
    assert c.success and c.iterations <= 5 and abs(c.total_time_s - b.total_time_s) < 1e-6


def test_fast_only_is_one_short_attempt_reported_as_presumed(params):
    """The engine's infeasibility policy: while presumed infeasible, one attempt capped at mpc.max_iter."""
    short = dataclasses.replace(params, mpc=dataclasses.replace(params.mpc, max_iter=2))
    user = expanded_ipopt_solver(short, OcpStructure.from_params(short))
    ego, front = _start(short)
    presumed = user.solve(ego, front, 1, Level(0.0, 0.0), fast_only=True)
    assert not presumed.success and presumed.status.presumed_infeasible
    assert presumed.iterations == 2 and presumed.status.raw == "Maximum_Iterations_Exceeded"
    full = user.solve(ego, front, 1, Level(0.0, 0.0))  # no presumption: the cold solve has max_iter_cold
    assert full.success and full.status.route is SolveRoute.PRIMARY and full.iterations > 2
