"""mcverify: Monte-Carlo verification and falsification of VL-CBF / TO-CBF-MPC overtaking controllers.

The public API (see :mod:`mcverify.api`)::

    load_campaign(path)            read and validate a campaign file
    run(campaign_or_path, out)     run it into a run folder and report it -> Run
    resume(run_dir)                finish an interrupted run -> Run
    open_run(run_dir)              a run folder -> Run (.episodes(), .cells(), .summary())
    replay(run_dir, episode_id)    re-simulate one episode, bit for bit
    report(run_dir)                regenerate the report from stored data
    compare(run_a, run_b)          per-cell differences with intervals

Importing the package has no side effects: JAX is configured (64-bit floats, the XLA ISA cap) only
when the simulation layer :mod:`mcverify.sim` is imported, which the functions above do on demand.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

__all__ = [
    "Run", "UserError", "CampaignError", "RunError",
    "load_campaign", "run", "resume", "open_run", "replay", "report", "compare", "__version__",
]

_API = {"Run", "load_campaign", "run", "resume", "open_run", "replay", "report", "compare"}
_ERRORS = {"UserError", "CampaignError", "RunError"}


def __getattr__(name: str) -> Any:  # PEP 562: import the API on first use, not at import
    if name in _API:
        from mcverify import api

        return getattr(api, name)
    if name in _ERRORS:
        from mcverify import errors

        return getattr(errors, name)
    raise AttributeError(f"module 'mcverify' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
