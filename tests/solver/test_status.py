"""SolveStatus: classification of backend statuses, routes, and the stored (rendered) form."""

from __future__ import annotations

from mcverify.solver.status import SolveOutcome, SolveRoute, SolveStatus


def test_ipopt_and_ipm_statuses_are_classified():
    assert SolveStatus.ipopt("Solve_Succeeded").outcome is SolveOutcome.SOLVED
    assert SolveStatus.ipopt("Solved_To_Acceptable_Level").outcome.converged
    assert SolveStatus.ipopt("Infeasible_Problem_Detected").certified_infeasible
    assert SolveStatus.ipopt("Restoration_Failed").outcome is SolveOutcome.FAILED
    assert SolveStatus.ipm("Converged").outcome is SolveOutcome.SOLVED
    assert SolveStatus.ipm("Max_Iterations").outcome is SolveOutcome.ITERATION_LIMIT
    assert SolveStatus.exception("boom\nmore").raw == "exception: boom"
    assert SolveStatus.invalid_input("nan").outcome is SolveOutcome.INVALID_INPUT


def test_routes_render_the_stored_strings():
    assert str(SolveStatus.ipm("Converged")) == "IPM_Converged"
    fallback = SolveStatus.ipopt("Infeasible_Problem_Detected").via(SolveRoute.FALLBACK)
    assert str(fallback) == "fallback:Infeasible_Problem_Detected"
    assert fallback.fallback and fallback.certified_infeasible and not fallback.presumed_infeasible
    presumed = SolveStatus.ipm("Max_Iterations").via(SolveRoute.PRESUMED)
    assert str(presumed) == "presumed_infeasible:IPM_Max_Iterations"
    assert presumed.presumed_infeasible and not presumed.certified_infeasible
