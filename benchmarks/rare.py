"""``python -m benchmarks.rare``: adaptive multilevel splitting against crude Monte Carlo on the calibration
random walk (:mod:`benchmarks.walk`), at a failure probability around 1e-4.

One run measures: a crude Monte Carlo reference (vectorised numpy, ``reference_episodes`` walks);
``repetitions`` independent splitting estimates (each ``replicates`` AMS runs of ``particles``
particles), their coverage of the reference, bias and relative error; and the cost ratio: the
control steps crude Monte Carlo would need for the splitting estimate's relative half-width at the
reference p (normal approximation, every walk run to its horizon) over the steps splitting
simulated. Steps are what the closed loop pays for (5-15 CPU-s per episode); CPU seconds of this
process are reported too, but the walk's crude side is vectorised numpy and its splitting side a
Python loop, so its CPU ratio says nothing about the closed loop.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from benchmarks import section
from benchmarks.walk import Walk
from mcverify import provenance
from mcverify.analysis import intervals
from mcverify.cli.options import positive_int
from mcverify.errors import UserError
from mcverify.estimate import splitting

BEGIN_MARK, END_MARK = section.markers("rare")


def run(*, barrier: float = 6.2, particles: int = 100, replicates: int = 25, repetitions: int = 20,
        reference_episodes: int = 30_000_000, level: float = 0.95) -> dict[str, Any]:
    """The measurements described in the module docstring, as plain data."""
    walk = Walk(drift=-0.05, sigma=0.3, horizon=60)
    t0 = time.process_time()
    hits, total = walk.crude(reference_episodes, barrier, seed=1)
    crude_cpu = time.process_time() - t0
    if hits == 0:
        raise UserError(f"--barrier {barrier:g}: none of the {total} reference walks reached it, so there is no p to "
                        "check the estimates against; lower --barrier or raise --reference-episodes")
    if hits > total / 2:
        raise UserError(f"--barrier {barrier:g}: {hits} of {total} reference walks reached it, so there is no rare "
                        "event to estimate; choose a barrier the walk reaches rarely (default 6.2: p about 1e-4)")
    p = hits / total
    estimates, cpu = [], []
    for r in range(repetitions):
        t0 = time.process_time()
        estimates.append(splitting.estimate(walk, n=particles, failure_level=barrier, replicates=replicates,
                                            level=level, seed=1000 + r))
        cpu.append(time.process_time() - t0)
    values = np.array([e.estimate for e in estimates])
    rel = float(np.mean([e.relative_halfwidth for e in estimates]))
    steps = float(np.mean([e.steps for e in estimates]))
    crude_steps = intervals.crude_steps_for(p, rel, walk.horizon, level)
    return {
        "barrier": barrier, "horizon": walk.horizon, "reference_episodes": total, "reference_hits": hits,
        "p_reference": p, "crude_cpu_s": crude_cpu, "particles": particles, "replicates": replicates,
        "repetitions": repetitions, "coverage": float(np.mean([e.contains(p) for e in estimates])),
        "bias": float(values.mean() / p - 1), "relative_error": float(values.std(ddof=1) / p),
        "mean_relative_halfwidth": rel, "splitting_steps": steps, "splitting_cpu_s": float(np.mean(cpu)),
        "crude_steps_same_width": crude_steps, "steps_ratio": crude_steps / steps,
        "crude_cpu_same_width_s": crude_cpu / (total * walk.horizon) * crude_steps,
        "commit": provenance.environment_info().get("git_commit"), "machine": platform.node(),
    }


def markdown(res: dict[str, Any], command: str) -> str:
    lines = [BEGIN_MARK, "", "## Rare events: splitting against crude Monte Carlo (calibration walk)", "",
             section.provenance_line(command), "",
             f"Gaussian random walk, drift -0.05, sigma 0.3, "
             f"{res['horizon']} steps; event: max x >= {res['barrier']}.", "",
             f"- crude reference: {res['reference_hits']} events in {res['reference_episodes']:,} walks, "
             f"p = {res['p_reference']:.3g} ({res['crude_cpu_s']:.0f} CPU-s)",
             f"- splitting: {res['repetitions']} independent estimates, each {res['replicates']} AMS runs of "
             f"{res['particles']} particles: coverage of the 95 % interval {res['coverage']:.2f}, bias "
             f"{res['bias']:+.1%}, relative error {res['relative_error']:.2f}, mean relative half-width "
             f"{res['mean_relative_halfwidth']:.2f}",
             f"- cost per estimate: {res['splitting_steps']:,.0f} simulated steps "
             f"({res['splitting_cpu_s']:.1f} CPU-s); "
             f"crude Monte Carlo for the same relative half-width at this p: {res['crude_steps_same_width']:,.0f} "
             f"steps, **{res['steps_ratio']:.0f}x more** (vectorised crude walks would take "
             f"{res['crude_cpu_same_width_s']:.0f} CPU-s: the CPU ratio of this toy says nothing about the "
             "closed loop, where a control step costs 0.01-0.03 CPU-s on either side)", "", END_MARK, ""]
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    p = section.parser("rare", "Splitting against crude Monte Carlo on the calibration walk (p about 1e-4).")
    p.add_argument("--barrier", type=float, default=6.2, help="event level of the walk (default 6.2: p ~ 1e-4)")
    p.add_argument("--particles", type=positive_int, default=100, help="particles per AMS run (default 100)")
    p.add_argument("--replicates", type=positive_int, default=25,
                   help="AMS runs per estimate (default 25: about +-30 %% at p ~ 1e-4)")
    p.add_argument("--repetitions", type=positive_int, default=20, help="independent estimates (default 20)")
    p.add_argument("--reference-episodes", type=positive_int, default=30_000_000,
                   help="crude reference walks (default 30000000)")
    section.add_output_options(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        args = _parser().parse_args(argv)
        if args.replicates < 2:
            raise UserError("--replicates must be at least 2 (the interval comes from their spread)")
        if args.particles < 2:
            raise UserError(f"--particles must be at least 2 (got {args.particles}): each AMS iteration kills the "
                            "lowest particle and branches a survivor")
        res = run(barrier=args.barrier, particles=args.particles, replicates=args.replicates,
                  repetitions=args.repetitions, reference_episodes=args.reference_episodes)
        section.publish("rare", markdown(res, section.command("rare", argv)), args)
        return 0

    return section.run_main("rare", body)


if __name__ == "__main__":
    sys.exit(main())
