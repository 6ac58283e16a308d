"""Ctrl-C or SIGTERM inside IPOPT: CasADi catches the KeyboardInterrupt raised in its signal check and
returns "NonIpopt_Exception_Thrown". The command line's handlers note the interrupt and the IPOPT
backend raises it again, so an interrupted solve stops the command instead of being counted as a
failed solve (which would enter the episode's statistics)."""

from __future__ import annotations

import os
import signal
import threading

import numpy as np
import pytest
from test_backends import EGO, LEVEL, P

from mcverify import cli, errors
from mcverify.solver import backends
from mcverify.solver.mpc import MpcSolver

FRONT = np.array([64.0, 0.0, 25.0 / 3.6])


class _Interrupted:
    """Stands in for a CasADi nlpsol whose IPOPT run was interrupted."""

    def __call__(self, **kw):
        return {"x": np.zeros(kw["x0"].size), "lam_x": np.zeros(kw["x0"].size), "lam_g": np.zeros(kw["lbg"].size)}

    def stats(self):
        return {"return_status": backends.IPOPT_INTERRUPTED, "iter_count": 3}


def test_a_noted_interrupt_is_raised_again_by_the_ipopt_backend():
    solver = MpcSolver(P)  # the ipopt backend
    solver.backend._cold = _Interrupted()
    errors.clear_noted_interrupts()
    # without a noted interrupt the status is an ordinary failed solve, as before
    assert not solver.solve(EGO, FRONT, 1, LEVEL).success
    errors.note_interrupt(cli.Terminated())
    with pytest.raises(cli.Terminated):
        solver.solve(EGO, FRONT, 1, LEVEL)
    assert not errors._noted_interrupts  # raised once, then forgotten


class _Wrapped(_Interrupted):
    """CasADi's other way: the interrupt wrapped in its own error."""

    def __call__(self, **kw):
        raise RuntimeError("Error in Function::call for 'tocbf_cold' [IpoptInterface]: [Terminated()]")


def test_an_interrupt_wrapped_in_a_casadi_error_is_raised_again():
    solver = MpcSolver(P)
    solver.backend._cold = _Wrapped()
    errors.clear_noted_interrupts()
    assert str(solver.solve(EGO, FRONT, 1, LEVEL).status).startswith("exception")  # no interrupt: a failure
    errors.note_interrupt(KeyboardInterrupt())  # another interrupt than the one named: still a failure
    assert not solver.solve(EGO, FRONT, 1, LEVEL).success
    errors.note_interrupt(cli.Terminated())
    with pytest.raises(cli.Terminated):
        solver.solve(EGO, FRONT, 1, LEVEL)


@pytest.mark.skipif(threading.current_thread() is not threading.main_thread(), reason="signals need the main thread")
def test_the_command_line_handlers_note_sigterm_and_sigint():
    with cli._sigterm_as_interrupt():
        for sig, kind in ((signal.SIGTERM, cli.Terminated), (signal.SIGINT, KeyboardInterrupt)):
            with pytest.raises(kind):
                os.kill(os.getpid(), sig)
                signal.sigtimedwait([], 0.1) if hasattr(signal, "sigtimedwait") else None
            assert isinstance(errors._noted_interrupts[-1], kind)
            errors.clear_noted_interrupts()
