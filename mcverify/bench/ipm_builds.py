"""Two builds of the C interior point compared on recorded solves: the same bits, and which is faster.

``csrc/ipm.c`` promises that a refactoring keeps the exact order of its floating-point operations,
checked by comparing recorded solves bit for bit. This is that check, and the speed measurement
that goes with it: every solve of one or more recordings (:mod:`mcverify.bench.recorded_ipm`) is
replayed with the working tree's library (``kernels.get_runtime_library("ipm")``) and with a
baseline build - the ``ipm.c`` and headers of a git revision (``--baseline-rev``), compiled with the
same flags, or any compatible ``ipm.so`` (``--baseline-library``; the kernel cache keeps one folder
per source) - under each of :data:`ATTEMPTS` (the engine's two warm attempts, the cold one with and
without restoration, the central one, phase 1, the LDL^T path). The two builds alternate in order
from solve to solve, so the CPU ratio is paired.

"The same" means: status, iteration count, and every element of the point and both multiplier
vectors equal, sign of zero included. Both builds must have the binding's ABI
(:func:`mcverify.solver.ipm.check_abi` refuses others).

Run: ``python -m mcverify.bench.ipm_builds --recording FILE [--recording FILE ...]
(--baseline-rev REV | --baseline-library SO) [--every K]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcverify.bench import recorded_ipm
from mcverify.errors import KernelBuildError
from mcverify.solver import kernels
from mcverify.solver.ipm import CENTRAL_WARM, COLD, WARM_ATTEMPTS, Ipm, IpmOptions, IpmResult

#: The engine's tolerance (``Mpc.tol``'s default).
TOL = 1e-6

#: Attempt name -> (options, started from the recorded warm start); cold ones start from the recorded guess.
ATTEMPTS: dict[str, tuple[IpmOptions, bool]] = {
    name: (dataclasses.replace(opts, tol=TOL), warm) for name, (opts, warm) in {
        "warm1": (WARM_ATTEMPTS[0], True),
        "warm2": (WARM_ATTEMPTS[1], True),
        "cold": (COLD, False),
        "cold_restoration": (dataclasses.replace(COLD, restoration=True), False),
        "central": (CENTRAL_WARM, True),
        "phase1_cold": (dataclasses.replace(COLD, phase1=True), False),
    }.items()
}


def build_revision(rev: str, out_dir: Path, repo: Path | None = None) -> Path:
    """``ipm.so`` compiled from ``mcverify/solver/csrc`` of git revision ``rev`` into ``out_dir``, with the
    flags of the working tree's build (:data:`mcverify.solver.kernels.RUNTIME_CFLAGS`)."""
    repo = repo or kernels.CSRC_DIR.parents[2]
    csrc = kernels.CSRC_DIR.relative_to(repo).as_posix()
    names = subprocess.run(["git", "-C", str(repo), "ls-tree", "--name-only", f"{rev}:{csrc}"],
                           capture_output=True, text=True, check=False)
    if names.returncode != 0:
        raise ValueError(f"git revision {rev!r}: {names.stderr.strip() or 'no ' + csrc}")
    for name in names.stdout.split():
        if name.endswith((".c", ".h")):
            text = subprocess.run(["git", "-C", str(repo), "show", f"{rev}:{csrc}/{name}"], capture_output=True,
                                  check=True).stdout
            (out_dir / name).write_bytes(text)
    so = out_dir / "ipm.so"
    kernels.compile_runtime(out_dir / "ipm.c", so, what=f"the ipm library of {rev}")
    return so


def same(a: IpmResult, b: IpmResult) -> bool:
    """Status, iterations and every element of (w, lam_x, lam_g) equal, NaN = NaN, sign of zero included."""
    return a.status == b.status and a.iterations == b.iterations and all(
        np.array_equal(x, y, equal_nan=True) and np.array_equal(np.signbit(x), np.signbit(y))
        for x, y in ((a.w, b.w), (a.lam_x, b.lam_x), (a.lam_g, b.lam_g)))


def compare(paths: Sequence[str], baseline_so: str | Path, every: int = 1, progress=print) -> dict[str, Any]:
    """Replay every ``every``-th solve of each recording under every attempt of :data:`ATTEMPTS` with both
    builds; per attempt: runs, runs that differ, CPU seconds of each build."""
    current_so = kernels.get_runtime_library("ipm").so_path
    rows = {name: {"runs": 0, "differ": 0, "cpu_baseline_s": 0.0, "cpu_current_s": 0.0} for name in ATTEMPTS}
    examples: list[dict[str, Any]] = []
    solves = 0
    for path in paths:
        rec = recorded_ipm.load(path)
        builds = {side: [Ipm(k.kernel_so, k.lbx, k.ubx, k.lbg, k.ubg, so) for k in rec.problems]
                  for side, so in (("baseline", baseline_so), ("current", current_so))}
        for k, s in enumerate(rec.solves[::every]):
            solves += 1
            order = ("baseline", "current") if k % 2 == 0 else ("current", "baseline")
            for name, (opts, warm) in ATTEMPTS.items():
                if warm and s.warm is None:
                    continue
                out = {}
                for side in order:
                    ipm = builds[side][s.problem]
                    cpu0 = time.process_time()
                    out[side] = (ipm.solve(s.p, s.warm.x, s.warm.lam_x, s.warm.lam_g, opts) if warm
                                 else ipm.solve(s.p, s.guess, None, None, opts))
                    rows[name][f"cpu_{side}_s"] += time.process_time() - cpu0
                rows[name]["runs"] += 1
                if not same(out["baseline"], out["current"]):
                    rows[name]["differ"] += 1
                    if len(examples) < 10:
                        examples.append({"recording": path, "solve": k * every, "attempt": name,
                                         "baseline": out["baseline"].status, "current": out["current"].status})
        progress(f"{path}: {solves} solves so far", file=sys.stderr)
    cpu_b = sum(r["cpu_baseline_s"] for r in rows.values())
    cpu_c = sum(r["cpu_current_s"] for r in rows.values())
    return {"solves": solves, "every": every, "recordings": list(paths), "baseline": str(baseline_so),
            "attempts": rows, "runs": sum(r["runs"] for r in rows.values()),
            "differ": sum(r["differ"] for r in rows.values()), "cpu_baseline_s": cpu_b, "cpu_current_s": cpu_c,
            "baseline_over_current": cpu_b / cpu_c if cpu_c else float("nan"), "examples": examples}


def markdown(out: dict[str, Any]) -> str:
    """The comparison as a table (one row per attempt kind and a total)."""
    lines = ["| attempt | runs | differ | CPU-s baseline | CPU-s current | baseline / current |",
             "|---|---:|---:|---:|---:|---:|"]
    for name, r in out["attempts"].items():
        ratio = r["cpu_baseline_s"] / r["cpu_current_s"] if r["cpu_current_s"] else float("nan")
        lines.append(f"| {name} | {r['runs']} | {r['differ']} | {r['cpu_baseline_s']:.2f} | {r['cpu_current_s']:.2f} "
                     f"| {ratio:.3f} |")
    lines.append(f"| all | {out['runs']} | {out['differ']} | {out['cpu_baseline_s']:.2f} | {out['cpu_current_s']:.2f} "
                 f"| **{out['baseline_over_current']:.3f}** |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mcverify.bench.ipm_builds", description=__doc__.split("\n")[0])
    ap.add_argument("--recording", action="append", required=True, help="a recorded_ipm pickle (repeatable)")
    base = ap.add_mutually_exclusive_group(required=True)
    base.add_argument("--baseline-rev", help="a git revision whose csrc is compiled as the baseline")
    base.add_argument("--baseline-library", help="an ipm.so to compare with (e.g. an older rt-ipm-* of the cache)")
    ap.add_argument("--every", type=int, default=1, help="replay every K-th solve only")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="mcverify-ipm-") as tmp:
        try:
            so = args.baseline_library or build_revision(args.baseline_rev, Path(tmp))
        except (ValueError, KernelBuildError) as err:
            print(f"mcverify: error: {err}", file=sys.stderr)
            return 2
        out = compare(args.recording, so, args.every)
    print(markdown(out))
    for e in out["examples"]:
        print(f"differs: {e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
