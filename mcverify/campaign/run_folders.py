"""Where a new run folder goes and what it is called.

``--out`` names a parent folder for new runs, ``--run-dir`` the run folder itself (:func:`new_folder`,
the one rule of every command that makes a new folder: run, estimate, falsify); without either, a new
run goes to ``<results>/<name>-<timestamp>`` (:func:`default_run_dir`), where ``<results>`` is
``$MCVERIFY_RESULTS`` or ``results`` (:func:`default_results_dir`) and the campaign name is made safe
as one folder name (:func:`folder_name`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

from mcverify.campaign.spec import Campaign
from mcverify.errors import RunError

#: Environment variable naming the folder new runs go to when neither --out nor --run-dir is given.
ENV_RESULTS_DIR = "MCVERIFY_RESULTS"
#: Longest run-folder name taken from a campaign name (characters, before the timestamp).
MAX_FOLDER_NAME = 80
_UNSAFE_CHARS = re.compile(r"[^A-Za-z0-9._=,+-]+")


def default_results_dir() -> Path:
    """Where new run folders go by default: ``$MCVERIFY_RESULTS`` if set, else ``results`` under the
    current working directory."""
    env = os.environ.get(ENV_RESULTS_DIR, "").strip()
    return Path(env) if env else Path("results")


def folder_name(name: str) -> str:
    """A campaign name made safe as one folder name: every run of characters other than letters,
    digits and ``. _ = , + -`` (path separators included) becomes ``_``, leading dots and
    underscores are dropped (no ``..``, no hidden folder), and the result is at most
    :data:`MAX_FOLDER_NAME` characters (``campaign`` if nothing is left)."""
    slug = _UNSAFE_CHARS.sub("_", name).lstrip("._")[:MAX_FOLDER_NAME].rstrip("._")
    return slug or "campaign"


def default_run_dir(campaign: Campaign, results_dir: Path | None = None) -> Path:
    """A new folder ``results_dir/<name>-<timestamp>`` that does not exist yet (``-2``, ``-3``, ...
    are appended when runs start within the same second, or a failed try left its folder).

    ``results_dir`` defaults to :func:`default_results_dir`; the campaign name goes through
    :func:`folder_name`, so the folder is always a direct child of ``results_dir``."""
    results_dir = Path(results_dir) if results_dir is not None else default_results_dir()
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = results_dir / f"{folder_name(campaign.name)}-{stamp}"
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f"{base.name}-{n}")
    if path.parent != results_dir:  # cannot happen with folder_name; a guard, not a feature
        raise RunError(f"campaign name {campaign.name!r} does not give a folder inside {results_dir}")
    return path


def new_folder(out: Path | None, run_dir: Path | None, fresh: Callable[[Path | None], Path]) -> Path:
    """The one rule of ``--out`` and ``--run-dir`` for every command that makes a new folder (run,
    estimate, falsify): ``run_dir`` (``--run-dir``) is the folder itself; otherwise ``fresh(out)``
    makes a new folder under the parent ``out`` (``--out``; None: :func:`default_results_dir`)."""
    if out is not None and run_dir is not None:
        raise RunError("give --out (a parent folder for new runs) or --run-dir (the run folder), not both")
    return Path(run_dir) if run_dir is not None else fresh(out)
