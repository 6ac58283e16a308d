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
