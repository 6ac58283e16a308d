"""``mcverify estimate CAMPAIGN --method splitting``: adaptive multilevel splitting per cell on the
real closed loop, into a folder with ``manifest.json``, ``estimate.json`` and ``report.md``.

Every cell gets ``replicates`` independent AMS runs of ``particles`` particles
(:func:`mcverify.estimate.splitting.ams` on :class:`~mcverify.estimate.closed_loop.ClosedLoopProcess`);
the estimate is their mean with a Student t interval (asymptotic). The cost is counted in control
steps and CPU seconds, and compared with what crude Monte Carlo would need for the same relative
half-width at the estimated p (episodes of the mean length of the fresh particles). Runs in this
process, one episode at a time (branches are sequential by nature; replicates could be spread over
workers, which is not done yet). ``estimate.json`` is rewritten after every cell, and ``--resume``
keeps the cells it holds (each cell's result is deterministic, so nothing is lost).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from mcverify.campaign import executors
from mcverify.campaign.spec import Campaign
from mcverify.estimate import folder, splitting
from mcverify.estimate.closed_loop import SCORES, ClosedLoopProcess
from mcverify.estimate.folder import num


@dataclass(frozen=True)
class SplittingSpec:
    """score: ``h_ef`` (target ellipse) or ``gap`` (target collision); particles per AMS run, k killed
    per iteration at least, independent replicates, interval level, iteration cap per run."""

    score: str = "gap"
    particles: int = 20
    k: int = 1
    replicates: int = 5
    level: float = 0.95
    max_iterations: int = 2000

    def __post_init__(self) -> None:
        if self.score not in SCORES:
            raise ValueError(f"unknown splitting score {self.score!r}; valid: {', '.join(SCORES)}")
        if not 1 <= self.k < self.particles:
            raise ValueError(f"need 1 <= k < particles, got k={self.k}, particles={self.particles}")
        if self.replicates < 2:
            raise ValueError(f"an interval needs at least 2 replicates, got {self.replicates}")

    @property
    def target(self) -> str:
        return SCORES[self.score]


def run(campaign: Campaign, spec: SplittingSpec, out: Path, *, progress=print,
        cells: list[str] | None = None) -> Path:
    """Estimate every cell of ``campaign`` (or those named in ``cells``) into the new folder ``out``;
    returns the report path."""
    folder.create(out, campaign, {"method": "splitting", **asdict(spec)}, cells)
    return _cells(campaign, spec, Path(out), {}, progress, cells)


def resume(out: Path, campaign: Campaign, *, progress=print) -> Path:
    """Finish an interrupted splitting estimate: the cells already in ``estimate.json`` are kept."""
    manifest, done = folder.load(out, "splitting")
    spec = SplittingSpec(**{k: v for k, v in manifest["estimate"].items() if k != "method"})
    return _cells(campaign, spec, Path(out), done, progress, manifest.get("only_cells"))


def _cells(campaign: Campaign, spec: SplittingSpec, out: Path, done: dict[int, dict], progress,
           only: list[str] | None = None) -> Path:
    results = dict(done)
    for cell in campaign.cells:
        if cell.index in results or (only and cell.name not in only):
            continue
        progress(f"cell {cell.name}: {spec.replicates} AMS runs of {spec.particles} particles")
        process = ClosedLoopProcess(cell, campaign.seed, executors.solver_for(cell.params), spec.score)
        runs = [splitting.ams(process, n=spec.particles, k=spec.k, failure_level=0.0, seed=r,
                              max_iterations=spec.max_iterations) for r in range(spec.replicates)]
        results[cell.index] = cell_result(cell.index, cell.name, spec, splitting.from_runs(runs, spec.level), runs,
                                          process)
        _write(out, spec, campaign, results)
    return _write(out, spec, campaign, results)


def cell_result(index: int, name: str, spec: SplittingSpec, est: splitting.SplittingEstimate,
                runs: list[splitting.AMSRun], process: ClosedLoopProcess) -> dict[str, Any]:
    episode_steps = sum(process.fresh_steps) / max(1, len(process.fresh_steps))
    crude = (splitting.crude_steps_for(est.estimate, est.relative_halfwidth, episode_steps, spec.level)
             if est.estimate > 0 and math.isfinite(est.relative_halfwidth) else math.nan)
    return {
        "cell_index": index, "cell": name, "method": "splitting", "target": spec.target, **est.as_dict(),
        "iterations": [r.iterations for r in runs], "cpu_s": process.cpu_s, "steps": process.steps,
        "mean_episode_steps": episode_steps, "crude_steps_same_width": crude,
        "steps_ratio_vs_crude": crude / process.steps if process.steps and math.isfinite(crude) else math.nan,
    }


COLUMNS: list[folder.Column] = [
    ("cell", lambda c: c["cell"]), ("estimate", lambda c: num(c["estimate"])),
    ("interval", lambda c: f"[{num(c['low'])}, {num(c['high'])}]"),
    ("rel. half-width", lambda c: num(c["relative_halfwidth"], ".2f")), ("control steps", lambda c: str(c["steps"])),
    ("CPU (s)", lambda c: num(c["cpu_s"], ".0f")),
    ("crude MC steps, same width", lambda c: num(c["crude_steps_same_width"])),
    ("ratio", lambda c: num(c["steps_ratio_vs_crude"], ".2f")), ("warnings", lambda c: "; ".join(c["warnings"]) or "-"),
]


def _write(out: Path, spec: SplittingSpec, campaign: Campaign, results: dict[int, dict]) -> Path:
    intro = (f"Target: {spec.target} (score {spec.score} reaching 0). Adaptive multilevel splitting, "
             f"{spec.replicates} independent runs of {spec.particles} particles (k = {spec.k}); the interval is "
             f"asymptotic ({spec.level:.0%} Student t on the runs' estimates).")
    return folder.write(out, f"mcverify splitting estimate: {campaign.name}", intro,
                        {"method": "splitting", **asdict(spec)}, results, COLUMNS)
