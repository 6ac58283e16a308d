"""Where a run's numbers come from: the code version, the numeric settings, the machine, the packages.

:func:`code_version` decides whether a run may be resumed by this code: it hashes the source of the
*simulation layers* (every ``*.py``, ``*.c`` and ``*.h`` file under them, less the few modules of
those layers that only move work or show progress, :data:`NOT_RESULTS`) together with the versions
of the packages that compute numbers and the pinned numeric settings (:data:`PINNED_XLA_FLAGS`). The
layers are named, not the files, so a new module of a simulation layer is covered without anyone
remembering to list it; ``tests/test_provenance.py`` checks that every part of the package is
classified as simulation or presentation.

Pinned numeric settings: XLA's CPU code generation decides the last bits of every plant step (which
instructions, fused multiply-adds or not), and the closed loop amplifies last bits into other solver
iterates and, rarely, another verdict. Cluster schedulers and users set ``XLA_FLAGS``, so every
simulating process replaces whatever ``--xla_cpu_*`` flags its caller set with
:data:`PINNED_XLA_FLAGS` (:func:`pin_xla_flags`, called by :mod:`mcverify.sim` before JAX starts
its backend) and records them in :func:`code_version`, hence in the run's manifest. Thread counts
(``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``, the cores a job may use) change no result: the C
solver runs no threads and the plant no dots.
"""

from __future__ import annotations

import hashlib
import os
import platform
import subprocess
import sys
from collections.abc import Mapping, MutableMapping
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Any

PACKAGE_DIR = Path(__file__).resolve().parent

#: Parts of the package (subpackages and root modules) whose source can change an episode row:
#: the model, the plant, the optimal-control problem, the solvers, the controller, the rollout and
#: the run layer (cell expansion, error rows).
SIMULATION_PARTS = (
    "model", "model_validation.py", "levels.py", "cell.py", "schema.py", "requirements.py", "draws.py",
    "sim", "ocp", "solver", "control", "episode", "campaign", "estimate",
)
#: Modules inside :data:`SIMULATION_PARTS` that cannot change an episode row, with the reason: rows
#: are a function of (campaign, seed, episode id) alone, whoever runs them, in whatever order, and
#: the executors' settings that do matter are pinned (:data:`PINNED_XLA_FLAGS`, hashed by value).
NOT_RESULTS = {
    "campaign/progress.py": "the progress bar",
    "campaign/cost.py": "the dry run's estimate",
    "campaign/episode_cost.py": "cost figures: the dry run's estimate and the scheduler's order of chunks",
    "campaign/lint.py": "warnings about a campaign file",
    "campaign/local.py": "local worker processes (which process runs a chunk)",
    "campaign/ray_executor.py": "Ray tasks (which machine runs a chunk)",
    "campaign/executors.py": "the choice of executor",
    "campaign/replay.py": "re-simulates a stored episode and compares it",
    "campaign/audit.py": "re-simulates a stored episode with the reference solver and compares the verdicts",
}
#: Parts that only read, present or measure stored rows; editing them never refuses a resume.
PRESENTATION_PARTS = (
    "__init__.py", "api.py", "errors.py", "fields.py", "files.py", "provenance.py", "store.py",
    "analysis", "cli", "reporting",
    # falsify chooses candidates but simulates nothing itself; a resumed search re-checks that the
    # candidates it asks equal those its generation folders recorded (falsify.generation_folder.check_same).
    "falsify",
)
#: Source files that enter the hash.
SOURCE_SUFFIXES = (".py", ".c", ".h")
#: Packages whose version can change simulated numbers.
NUMERIC_PACKAGES = ("jax", "jaxlib", "numpy", "scipy", "casadi")
#: XLA's CPU options every simulating process runs with; :func:`pin_xla_flags` drops every other
#: ``--xla_cpu_*`` flag of the caller's ``XLA_FLAGS`` (they choose code generation) and keeps the rest
#: (dumps, device counts). ``max_isa=AVX``: on CPUs with FMA3, XLA contracts ``a*b + c`` into fused
#: multiply-adds differently for a vmapped batch and for a single episode, so a chunk of 8 and a
#: replay of 1 would differ, and a run with FMA differs from one without in every episode's last bits.
#: ``--xla_cpu_multi_thread_eigen=false`` (single-threaded cluster jobs) alone changes no bit: the
#: plant has no dots, so thread settings do not matter once the ISA is pinned.
PINNED_XLA_FLAGS = {"xla_cpu_max_isa": "AVX"}

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
    files = [p for p in files if p.relative_to(package_dir).as_posix() not in NOT_RESULTS]
    return sorted(files, key=lambda p: p.relative_to(package_dir).as_posix())


def source_digest(package_dir: Path = PACKAGE_DIR) -> str:
    """SHA-256 (hex) over the relative path and bytes of every :func:`simulation_files` file."""
    h = hashlib.sha256()
    for path in simulation_files(package_dir):
        h.update(path.relative_to(package_dir).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def code_version() -> dict[str, Any]:
    """What the simulated numbers depend on besides the campaign: :func:`source_digest`, the
    versions of :data:`NUMERIC_PACKAGES` and the pinned :data:`PINNED_XLA_FLAGS`. Cached per process."""
    global _CODE_VERSION
    if _CODE_VERSION is None:
        _CODE_VERSION = {"source_sha256": source_digest(), **{p: package_version(p) for p in NUMERIC_PACKAGES},
                         "xla_flags": pinned_xla_flags()}
    return dict(_CODE_VERSION)


def pinned_xla_flags() -> str:
    """:data:`PINNED_XLA_FLAGS` as ``XLA_FLAGS`` text."""
    return " ".join(f"--{name}={value}" for name, value in PINNED_XLA_FLAGS.items())


def pin_xla_flags(environ: MutableMapping[str, str] | None = None) -> str:
    """Put :data:`PINNED_XLA_FLAGS` into ``environ["XLA_FLAGS"]`` (default: this process's
    environment), dropping every ``--xla_cpu_*`` flag the caller set and keeping the rest; returns
    the new value. Must run before JAX starts its backend (:mod:`mcverify.sim` does it on import)."""
    environ = os.environ if environ is None else environ
    # Pinned first: XLA stops reading flags at the first word that is not one (schedulers' recipes
    # add "intra_op_parallelism_threads=1", a TensorFlow option), which silently dropped a cap
    # appended after it, and reads a value that does not start with "--" as the name of a file.
    kept = [f for f in environ.get("XLA_FLAGS", "").split() if not f.lstrip("-").startswith("xla_cpu_")]
    environ["XLA_FLAGS"] = " ".join([pinned_xla_flags(), *kept])
    return environ["XLA_FLAGS"]


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
        "threads": thread_settings(),
        "packages": versions,
        "git_commit": git_commit(),
    }


#: Thread settings of the caller's environment, recorded to show where a run was made; none of them
#: changes a result (the C solver runs no threads, the plant has no dots, XLA's CPU flags are pinned).
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "XLA_FLAGS")


def thread_settings() -> dict[str, Any]:
    """:data:`THREAD_VARIABLES` as this process sees them (None: unset) and the cores it may use."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {**{name: os.environ.get(name) for name in THREAD_VARIABLES}, "usable_cores": cores}


def git_commit(short: bool = False, ignore: tuple[str, ...] = ()) -> str | None:
    """HEAD of the checkout this package runs from (``+dirty`` with uncommitted changes outside the paths
    ``ignore``, relative to the checkout), or None."""
    root = PACKAGE_DIR.parent
    try:
        out = subprocess.run(["git", "-C", str(root), "rev-parse", *(["--short"] if short else []), "HEAD"],
                             capture_output=True, text=True, timeout=5)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no", "--", ".",
                                *(f":(exclude){p}" for p in ignore)], capture_output=True, text=True, timeout=5)
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
