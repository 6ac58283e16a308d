"""The errors a user sees: each carries one line that names the problem; the CLI prints it and
exits with status 2 (never a traceback). Lower layers raise their own subclass; the CLI catches
:class:`UserError` alone."""

from __future__ import annotations


class UserError(Exception):
    """A problem with the user's input or environment, explained in one line."""

    def __init__(self, message: str) -> None:
        # One line whatever the input held (a label or key may contain a line break).
        super().__init__(str(message).replace("\r", "\\r").replace("\n", "\\n"))


class CampaignError(UserError, ValueError):
    """A campaign file or parameter is invalid."""


class RunError(UserError, ValueError):
    """A run folder is missing or unusable, or a run cannot proceed."""


class KernelBuildError(UserError, RuntimeError):
    """The solver kernel cannot be generated or compiled (no C compiler, a failed build)."""


#: Interrupts raised in the main thread while a C++ solver held it. CasADi's IPOPT interface catches a
#: KeyboardInterrupt raised in its signal check, prints a warning and returns the status
#: "NonIpopt_Exception_Thrown": the interrupt would be lost and the solve counted as a failure. So
#: the command line's signal handlers note the interrupt here (:func:`note_interrupt`) and the IPOPT
#: backend raises it again (:func:`raise_noted_interrupt`) instead of returning a failed solve.
_noted_interrupts: list[KeyboardInterrupt] = []


def note_interrupt(exc: KeyboardInterrupt) -> KeyboardInterrupt:
    """Remember ``exc`` (about to be raised by a signal handler) and return it."""
    _noted_interrupts.append(exc)
    return exc


def raise_noted_interrupt(evidence: str | None = None) -> None:
    """Raise the last noted interrupt, if any (and forget them all); with ``evidence`` (an error
    message), only if it names the interrupt's class (CasADi wraps it: "... [Terminated()]")."""
    if _noted_interrupts and (evidence is None or type(_noted_interrupts[-1]).__name__ in evidence):
        exc = _noted_interrupts[-1]
        _noted_interrupts.clear()
        raise exc


def clear_noted_interrupts() -> None:
    """Forget noted interrupts (a command starts)."""
    _noted_interrupts.clear()
