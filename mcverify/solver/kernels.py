"""Compiled TO-CBF-MPC kernels: generate C once per :class:`~mcverify.ocp.problem.OcpStructure`, cache on disk.

A kernel is the C code of the NLP's functions (objective, constraints, their derivatives and the
Lagrangian Hessian, from ``nlpsol(...).generate_dependencies``) compiled to a shared object that
``nlpsol("S", "ipopt", "<path>/nlp.so", opts)`` loads.

Cache directory (:func:`resolve_kernel_dir`): ``$MCVERIFY_KERNEL_DIR`` if set, else ``<repo>/kernels``
when the package sits in a source checkout (``pyproject.toml`` next to the ``mcverify`` package),
else ``~/.cache/mcverify/kernels``. Each kernel lives in ``<name>-<hash12>/`` with ``nlp.c``,
``nlp.so`` and ``manifest.json``.

The hash covers only what changes the compiled code: :data:`mcverify.ocp.problem.FORMULATION_VERSION`, a
digest of the NLP's maths (:func:`mcverify.ocp.problem.formulation_digest`, so that no edit of the
formulation can be served a stale kernel), the :class:`~mcverify.ocp.problem.OcpStructure`, the CasADi
version, the compiler command and flags, and the machine architecture. Numeric values (bounds,
lambdas, ellipse axes, l_r, phi, eps_y, weights,
measurements) are runtime parameters or bounds, not compiled in, so they do not enter the hash.

Concurrency: a kernel is built in a temporary folder next to its final place and moved there with
one ``os.replace``, under an ``fcntl`` lock per kernel, so two processes asking for the same missing
kernel compile it once and never see a half-written one. A cached kernel is loaded without calling
the compiler.
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import logging
import os
import platform
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import casadi as ca

from mcverify.errors import KernelBuildError
from mcverify.ocp.problem import FORMULATION_VERSION, OcpStructure, build_nlp, formulation_digest

log = logging.getLogger(__name__)

COMPILER = "gcc"
# -O2: the NLP's functions are about 15 % faster than at -O1 (the Hessian of the Table IV kernel with
# veh_o 37 against 45 us), which counts in the C interior point, and it compiles in about the same
# time; the same bits, since neither level contracts into FMAs or reorders floating-point operations
# (docs/decisions.md). No -mavx2 here: it gained little more and would make the kernel names differ
# between machines.
CFLAGS: tuple[str, ...] = ("-O2", "-fPIC", "-shared")
KERNEL_PREFIX = "tocbf"
C_FILE, SO_FILE, MANIFEST_FILE = "nlp.c", "nlp.so", "manifest.json"
ENV_KERNEL_DIR = "MCVERIFY_KERNEL_DIR"
_KERNEL_DIR_RE = re.compile(rf"^{KERNEL_PREFIX}-N\d+-m\d+(-opp)?(-freedt)?-[0-9a-f]{{12}}$")
#: Runtime libraries: hand-written C shipped in ``mcverify/solver/csrc`` (the interior-point solver),
#: compiled once per machine into the same cache. -O3 vectorises the banded LU's inner loops (85 us
#: per factorisation of the N = 50 KKT system at -O3, 187 us at -O2); AVX2 is added where the CPU
#: has it (-25%), but never FMA (-mfma): without fused multiply-adds every element-wise operation
#: rounds exactly as in the SSE2 build and gcc does not reorder reductions without -ffast-math,
#: so the results are the same bits with or without AVX2.
RUNTIME_PREFIX = "rt"


def _runtime_cflags() -> tuple[str, ...]:
    flags = ["-O3", "-fPIC", "-shared"]
    try:
        cpuinfo = Path("/proc/cpuinfo").read_text()
    except OSError:
        cpuinfo = ""
    if platform.machine() in ("x86_64", "AMD64") and re.search(r"^flags\s*:.*\bavx2\b", cpuinfo, re.M):
        flags.append("-mavx2")
    return tuple(flags)


RUNTIME_CFLAGS: tuple[str, ...] = _runtime_cflags()
CSRC_DIR = Path(__file__).resolve().parent / "csrc"
_RUNTIME_DIR_RE = re.compile(rf"^{RUNTIME_PREFIX}-[a-z0-9_]+-[0-9a-f]{{12}}$")


@dataclass(frozen=True)
class Kernel:
    """A compiled kernel on disk."""

    name: str  # folder name, <prefix>-N<N>-m<m>[-opp]-<hash12> (runtime libraries: rt-<name>-<hash12>)
    path: Path  # the folder
    manifest: dict
    so_file: str = SO_FILE

    @property
    def so_path(self) -> Path:
        return self.path / self.so_file

    @property
    def c_path(self) -> Path:
        return self.path / C_FILE

    @property
    def hash(self) -> str:
        return self.manifest["hash"]


def compiler_command() -> list[str]:
    """The compiler and flags, without file names (enters the hash)."""
    return [COMPILER, *CFLAGS]


def resolve_kernel_dir(kernel_dir: str | os.PathLike | None = None) -> Path:
    """The cache directory: the argument, else $MCVERIFY_KERNEL_DIR, else <repo>/kernels, else ~/.cache."""
    if kernel_dir is not None:
        return Path(kernel_dir)
    env = os.environ.get(ENV_KERNEL_DIR)
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[2]
    if (repo / "pyproject.toml").is_file():
        return repo / "kernels"
    return Path.home() / ".cache" / "mcverify" / "kernels"


def kernel_hash(structure: OcpStructure) -> str:
    """SHA-256 (hex) over formulation version, structure, CasADi version, compiler command, arch."""
    key = {
        "formulation_version": FORMULATION_VERSION,
        "formulation_digest": formulation_digest(structure),
        "structure": dataclasses.asdict(structure),
        "casadi_version": ca.__version__,
        "compiler_command": " ".join(compiler_command()),
        "machine": platform.machine(),
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()


def kernel_name(structure: OcpStructure) -> str:
    """Folder name of the kernel, e.g. ``tocbf-N50-m2-0123456789ab``."""
    opp = "-opp" if structure.with_opposing else ""
    free = "" if structure.uniform_dt else "-freedt"
    return f"{KERNEL_PREFIX}-N{structure.horizon}-m{structure.order_m}{opp}{free}-{kernel_hash(structure)[:12]}"


def get_kernel(structure: OcpStructure, kernel_dir: str | os.PathLike | None = None) -> Kernel:
    """The kernel for ``structure``: loaded from the cache, or generated and compiled once."""
    name = kernel_name(structure)
    return _get_or_build(resolve_kernel_dir(kernel_dir), name, lambda tmp: _build(structure, name, tmp))


def is_cached(structure: OcpStructure, kernel_dir: str | os.PathLike | None = None) -> bool:
    """Whether the kernel of ``structure`` is compiled in the cache already (nothing is built)."""
    return _read_kernel(resolve_kernel_dir(kernel_dir) / kernel_name(structure)) is not None


def runtime_headers() -> list[Path]:
    """The headers of ``csrc`` (sorted): every runtime library may include any of them."""
    return sorted(CSRC_DIR.glob("*.h"))


def runtime_hash(name: str) -> str:
    """SHA-256 (hex) over the C source ``csrc/<name>.c``, the headers of ``csrc``, the compiler
    command and the architecture."""
    key = {
        "source": (CSRC_DIR / f"{name}.c").read_text(),
        "headers": {h.name: h.read_text() for h in runtime_headers()},
        "compiler_command": " ".join([COMPILER, *RUNTIME_CFLAGS]),
        "machine": platform.machine(),
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()


def get_runtime_library(name: str, kernel_dir: str | os.PathLike | None = None) -> Kernel:
    """The shared object of the shipped C source ``mcverify/solver/csrc/<name>.c`` (with the headers
    of ``csrc``), compiled once and cached (same locking and atomic replace as the kernels); its
    ``so_path`` is ``<name>.so``."""
    folder = f"{RUNTIME_PREFIX}-{name}-{runtime_hash(name)[:12]}"

    def build(tmp: Path) -> dict:
        t0 = time.perf_counter()
        src = CSRC_DIR / f"{name}.c"
        for file in (src, *runtime_headers()):  # the folder holds everything the library was built from
            shutil.copy(file, tmp / file.name)
        so = tmp / f"{name}.so"
        compile_runtime(tmp / src.name, so, what=f"the {name} runtime library")
        manifest = {
            "name": folder,
            "hash": runtime_hash(name),
            "source": src.name,
            "compiler_command": " ".join([COMPILER, *RUNTIME_CFLAGS]),
            "machine": platform.machine(),
            "compile_seconds": round(time.perf_counter() - t0, 3),
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "so_file": so.name,
        }
        (tmp / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
        return manifest

    return _get_or_build(resolve_kernel_dir(kernel_dir), folder, build, so_file=f"{name}.so")


def compile_runtime(c_file: Path, so_path: Path, what: str) -> None:
    """Compile a runtime library's C file (its headers next to it) with :data:`RUNTIME_CFLAGS`."""
    _run_compiler([COMPILER, *RUNTIME_CFLAGS, str(c_file), "-o", str(so_path), "-lm"], so_path, what=what)


def _get_or_build(root: Path, name: str, build, so_file: str = SO_FILE) -> Kernel:
    """Load ``root/name`` if complete, else build it once under a per-name lock (atomic replace)."""
    final = root / name
    cached = _read_kernel(final, so_file)
    if cached is not None:
        return cached
    root.mkdir(parents=True, exist_ok=True)
    with open(root / f".{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        cached = _read_kernel(final, so_file)  # another process may have built it while we waited
        if cached is not None:
            return cached
        log.info("compiling %s into %s (once per machine; %s)", name, root, expected_build_time(root, name))
        for stale in root.glob(f".tmp-{name}-*"):  # left by a killed build; we hold the lock
            shutil.rmtree(stale, ignore_errors=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{name}-", dir=root))
        try:
            manifest = build(tmp)
            os.chmod(tmp, 0o755)  # mkdtemp makes it 0700
            os.replace(tmp, final)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            cached = _read_kernel(final, so_file)  # lost a race with a builder that bypassed the lock
            if cached is None:
                raise
            return cached
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return Kernel(name=name, path=final, manifest=manifest, so_file=so_file)


def expected_build_time(root: Path, name: str) -> str:
    """How long building ``name`` should take, from the build times recorded by the kernels of the
    same kind already in ``root`` (e.g. "about 35 s, as the 2 cached ones took 27-55 s"), or a
    rough figure when there are none."""
    kind = name.rsplit("-", 1)[0]
    seconds = []
    for manifest in root.glob(f"{kind}-*/{MANIFEST_FILE}"):
        try:
            data = json.loads(manifest.read_text())
            seconds.append(float(data.get("generate_seconds", 0.0)) + float(data["compile_seconds"]))
        except (OSError, ValueError, KeyError, TypeError):
            continue
    if not seconds:
        return "a few seconds" if name.startswith(RUNTIME_PREFIX) else "about 1-3 minutes on a laptop core"
    median = sorted(seconds)[len(seconds) // 2]
    return f"about {median:.0f} s; {len(seconds)} such build(s) here took {min(seconds):.0f}-{max(seconds):.0f} s"


def _read_kernel(folder: Path, so_file: str = SO_FILE) -> Kernel | None:
    """A complete kernel folder (manifest and shared object present), else None."""
    try:
        manifest = json.loads((folder / MANIFEST_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not (folder / so_file).is_file():
        return None
    return Kernel(name=folder.name, path=folder, manifest=manifest, so_file=so_file)


def _build(structure: OcpStructure, name: str, folder: Path) -> dict:
    """Generate C into ``folder``, compile it, write the manifest (last); returns the manifest."""
    t0 = time.perf_counter()
    generate_c(structure, folder)
    generate_s = time.perf_counter() - t0
    compile_s = compile_c(folder / C_FILE, folder / SO_FILE)
    manifest = {
        "name": name,
        "hash": kernel_hash(structure),
        "formulation_version": FORMULATION_VERSION,
        "structure": dataclasses.asdict(structure),
        "casadi_version": ca.__version__,
        "compiler_command": " ".join(compiler_command()),
        "machine": platform.machine(),
        "generate_seconds": round(generate_s, 3),
        "compile_seconds": round(compile_s, 3),
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "c_file": C_FILE,
        "so_file": SO_FILE,
    }
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    return manifest


def generate_c(structure: OcpStructure, folder: Path) -> Path:
    """Write the C of the NLP's functions to ``folder/nlp.c``; returns its path.

    Same content as ``nlpsol(...).generate_dependencies("nlp.c")`` (the oracle ``nlp`` and its
    derived ``nlp_f``, ``nlp_g``, ``nlp_grad_f``, ``nlp_jac_g``, ``nlp_hess_l``, ...), but written
    into ``folder`` instead of the working directory, so the process never has to ``chdir``.
    """
    solver = ca.nlpsol("kernel_gen", "ipopt", build_nlp(structure))
    gen = ca.CodeGenerator(C_FILE)
    gen.add(solver.oracle())
    for fname in solver.get_function():
        gen.add(solver.get_function(fname))
    return Path(gen.generate(f"{folder}{os.sep}"))


def compile_c(c_path: Path, so_path: Path) -> float:
    """Compile ``c_path`` to the shared object ``so_path``; returns the seconds it took.

    Raises :class:`KernelBuildError` with a one-line message if the compiler is missing or fails.
    """
    t0 = time.perf_counter()
    _run_compiler([*compiler_command(), str(c_path), "-o", str(so_path), "-lm"], so_path,
                  what="the TO-CBF-MPC kernel")
    return time.perf_counter() - t0


def _run_compiler(cmd: list[str], so_path: Path, what: str) -> None:
    shown = " ".join(cmd)
    hint = "install a C compiler (e.g. `apt-get install gcc`, `conda install -c conda-forge gcc`)"
    if shutil.which(COMPILER) is None:
        raise KernelBuildError(f"cannot compile {what}: `{COMPILER}` not found on PATH "
                               f"(command: {shown}); {hint}")
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    except OSError as exc:
        raise KernelBuildError(f"cannot compile {what}: `{shown}` could not run ({exc}); {hint}") from exc
    if proc.returncode != 0 or not so_path.is_file():
        last = (proc.stderr or proc.stdout or "").strip().splitlines()
        detail = last[-1] if last else f"exit status {proc.returncode}"
        raise KernelBuildError(f"cannot compile {what}: `{shown}` failed ({detail}); {hint}")


def list_kernels(kernel_dir: str | os.PathLike | None = None) -> list[dict]:
    """Manifests of the complete kernels in the cache directory, sorted by name (with "path" added)."""
    root = resolve_kernel_dir(kernel_dir)
    if not root.is_dir():
        return []
    out = []
    for folder in sorted(root.iterdir()):
        if folder.is_dir() and _KERNEL_DIR_RE.match(folder.name):
            kernel = _read_kernel(folder)
        elif folder.is_dir() and _RUNTIME_DIR_RE.match(folder.name):
            so_file = f"{folder.name.split('-')[1]}.so"
            kernel = _read_kernel(folder, so_file)
        else:
            continue
        if kernel is not None:
            out.append({**kernel.manifest, "path": str(folder)})
    return out


def clear_kernels(kernel_dir: str | os.PathLike | None = None) -> int:
    """Remove the kernel folders this module recognises (name pattern); returns how many.

    Anything else in the directory (README.md, other files, in-progress ``.tmp-*`` builds) is kept.
    """
    root = resolve_kernel_dir(kernel_dir)
    if not root.is_dir():
        return 0
    removed = 0
    for folder in sorted(root.iterdir()):
        recognised = _KERNEL_DIR_RE.match(folder.name) or _RUNTIME_DIR_RE.match(folder.name)
        if folder.is_dir() and not folder.is_symlink() and recognised:
            shutil.rmtree(folder)
            removed += 1
    return removed
