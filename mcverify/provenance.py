"""Where a run's numbers come from: the code version, the machine, the packages, the git commit.

:func:`code_version` decides whether a run may be resumed by this code: it hashes the source of the
*simulation layers* (every ``*.py``, ``*.c`` and ``*.h`` file under them) together with the versions
of the packages that compute numbers. The layers are named, not the files, so a new module of a
simulation layer is covered without anyone remembering to list it; ``tests/test_provenance.py``
checks that every part of the package is classified as simulation or presentation.
"""

from __future__ import annotations

import hashlib
import os
import platform
import subprocess
import sys
from collections.abc import Mapping
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Any

PACKAGE_DIR = Path(__file__).resolve().parent

#: Parts of the package (subpackages and root modules) whose source can change an episode row:
#: the model, the plant, the optimal-control problem, the solvers, the controller, the rollout and
#: the run layer (cell expansion, error rows).
SIMULATION_PARTS = (
    "model.py", "levels.py", "cell.py", "schema.py", "requirements.py", "draws.py",
    "sim", "ocp", "solver", "control", "episode", "campaign", "estimate",
)
#: Parts that only read, present or measure stored rows; editing them never refuses a resume.
PRESENTATION_PARTS = (
    "__init__.py", "api.py", "cli.py", "errors.py", "fields.py", "provenance.py", "store.py",
    "analysis", "reporting", "bench",
    # falsify chooses candidates but simulates nothing itself; a resumed search re-checks that the
    # candidates it asks equal those its generation folders recorded (falsify.search._check_same).
    "falsify",
)
#: Source files that enter the hash.
SOURCE_SUFFIXES = (".py", ".c", ".h")
#: Packages whose version can change simulated numbers.
NUMERIC_PACKAGES = ("jax", "jaxlib", "numpy", "scipy", "casadi")

_CODE_VERSION: dict[str, Any] | None = None


def simulation_files(package_dir: Path = PACKAGE_DIR) -> list[Path]:
    """Every source file of :data:`SIMULATION_PARTS` under ``package_dir``, in a fixed order."""
    files: list[Path] = []
    for part in SIMULATION_PARTS:
        path = package_dir / part
        if path.is_dir():
            files += [p for p in path.rglob("*") if p.suffix in SOURCE_SUFFIXES and p.is_file()]
        elif path.is_file():
            files.append(path)
    return sorted(files, key=lambda p: p.relative_to(package_dir).as_posix())


def source_digest(package_dir: Path = PACKAGE_DIR) -> str:
    """SHA-256 (hex) over the relative path and bytes of every :func:`simulation_files` file."""
    h = hashlib.sha256()
    for path in simulation_files(package_dir):
        h.update(path.relative_to(package_dir).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def code_version() -> dict[str, Any]:
    """What the simulated numbers depend on besides the campaign: :func:`source_digest` and the
    versions of :data:`NUMERIC_PACKAGES`. Cached per process."""
    global _CODE_VERSION
    if _CODE_VERSION is None:
        _CODE_VERSION = {"source_sha256": source_digest(), **{p: package_version(p) for p in NUMERIC_PACKAGES}}
    return dict(_CODE_VERSION)


def code_differences(recorded: Mapping[str, Any], current: Mapping[str, Any]) -> list[str]:
    """Human-readable differences between two :func:`code_version` records (empty if the same)."""
    out = []
    for key in sorted(set(recorded) | set(current)):
        a, b = recorded.get(key), current.get(key)
        if a != b:
            if key == "source_sha256":
                out.append(f"mcverify simulation source {str(a)[:12]} -> {str(b)[:12]}")
            else:
                out.append(f"{key} {a} -> {b}")
    return out


def cpu_model() -> str:
    """The processor's model name (``/proc/cpuinfo`` on Linux), else what :mod:`platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def environment_info() -> dict[str, Any]:
    """The machine, Python, package versions and git commit, as recorded in a run's manifest."""
    versions = {pkg: package_version(pkg) for pkg in ("mcverify", *NUMERIC_PACKAGES, "pyarrow", "matplotlib", "ray")}
    return {
        "created_utc": now_utc(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "packages": versions,
        "git_commit": git_commit(),
    }


def git_commit(short: bool = False) -> str | None:
    """HEAD of the checkout this package runs from (``+dirty`` with uncommitted changes), or None."""
    root = PACKAGE_DIR.parent
    try:
        out = subprocess.run(["git", "-C", str(root), "rev-parse", *(["--short"] if short else []), "HEAD"],
                             capture_output=True, text=True, timeout=5)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if out.returncode != 0:
        return None
    return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def package_version(pkg: str) -> str | None:
    try:
        return metadata.version(pkg)
    except metadata.PackageNotFoundError:
        return None


def now_utc() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")
