"""``mcverify estimate CAMPAIGN --method splitting``: adaptive multilevel splitting per cell on the
real closed loop, into a folder with ``manifest.json``, ``estimate.json`` and ``report.md``.

Every cell gets ``replicates`` independent AMS runs of ``particles`` particles
(:func:`mcverify.estimate.splitting.ams` on :class:`~mcverify.estimate.closed_loop.ClosedLoopProcess`);
the estimate is their mean with a Student t interval (asymptotic). The cost is counted in control
steps and CPU seconds, and compared with what crude Monte Carlo would need for the same relative
half-width at the estimated p (episodes of the mean length of the fresh particles). Within an AMS
run, one episode at a time (branches are sequential by nature); the independent runs are work units
of the executors (this process by default, ``--executor local`` or ``ray`` to spread them), and a
run's result does not depend on where it ran. Each finished AMS run is written at once to
``runs/cellNNN_runNNN.json`` (atomically: its AMSRun, control steps, CPU seconds and the steps of its
fresh episodes), ``estimate.json`` is rewritten after every cell, and ``manifest.json`` gets
``finished_utc`` once every cell is estimated. ``--resume`` keeps the cells ``estimate.json`` holds and
the finished runs of the others, and runs only the missing ones: a run is a deterministic function of
(campaign, cell, replicate), so the estimate is the one an uninterrupted run gives (only the CPU
seconds, which are measured, can differ). An interrupt loses at most the AMS runs still in progress.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from mcverify.analysis import intervals
from mcverify.campaign import executors
from mcverify.campaign.executors import Executor
from mcverify.campaign.spec import Campaign
from mcverify.cell import Cell
from mcverify.estimate import folder, replicates, splitting
from mcverify.estimate.closed_loop import ClosedLoopProcess
from mcverify.requirements import SCORES

#: Fewer AMS runs than this get a warning: on the closed-loop validation cell (200 runs of 20
#: particles with h_ef_run against 3,848 crude episodes) the 95 % t interval covered p in 43 of 50
#: repetitions of 4 runs, 29 of 33 of 6 and 24 of 25 of 8 (docs/rare_events.md): the runs' estimates
#: are skewed (a tenth of them 0), and a t interval on few skewed values is too narrow.
FEW_RUNS = 8


@dataclass(frozen=True)
class SplittingSpec:
    """score: ``h_ef`` (target ellipse) or ``gap`` (target collision); particles per AMS run, k killed
    per iteration at least, independent replicates, interval level, iteration cap per run."""

    score: str = "gap"
    particles: int = 20
    k: int = 1
    replicates: int = FEW_RUNS
    level: float = 0.95
    max_iterations: int = 2000

    def __post_init__(self) -> None:
        if self.score not in SCORES:
            raise ValueError(f"unknown splitting score {self.score!r}; valid: {', '.join(SCORES)}")
        if self.k < 1:
            raise ValueError(f"k (particles killed per AMS iteration) must be at least 1 (got {self.k})")
        if self.particles <= self.k:
            raise ValueError(f"--particles must be at least {self.k + 1} (got {self.particles}): each AMS iteration "
                             f"kills {self.k} particle{'s' if self.k > 1 else ''} and branches the survivors")
        if self.replicates < 2:
            raise ValueError(f"--replicates must be at least 2 (got {self.replicates}) for an interval")
        if self.max_iterations < 1:
            raise ValueError(f"--max-iterations must be at least 1 (got {self.max_iterations})")

    @property
    def target(self) -> str:
        return SCORES[self.score]


def run(campaign: Campaign, spec: SplittingSpec, out: Path, *, progress=print,
        cells: list[str] | None = None, executor: Executor | None = None) -> Path:
    """Estimate every cell of ``campaign`` (or those named in ``cells``) into the new folder ``out``;
    returns the report path. executor: where the AMS runs go (default: this process, one at a time)."""
    folder.create(out, campaign, {"method": "splitting", **asdict(spec)}, cells)
    return replicates.run_cells(campaign, _replicated(campaign, spec, Path(out)), Path(out), {}, progress, cells,
                                executor)


def resume(out: Path, campaign: Campaign, *, progress=print, executor: Executor | None = None) -> Path:
    """Finish an interrupted splitting estimate: the cells already in ``estimate.json`` are kept."""
    manifest, done = folder.load(out, "splitting")
    spec = SplittingSpec(**{k: v for k, v in manifest["estimate"].items() if k != "method"})
    return replicates.run_cells(campaign, _replicated(campaign, spec, Path(out)), Path(out), done, progress,
                                manifest.get("only_cells"), executor)


def _replicated(campaign: Campaign, spec: SplittingSpec, out: Path) -> replicates.Replicated:
    def done_text(row: dict[str, Any]) -> str:
        run = row["run"]
        return f"{_fate(run)}, {run['iterations']} iterations, {row['steps']} control steps, {row['cpu_s']:.0f} CPU-s"

    return replicates.Replicated(
        label="AMS run", count=spec.replicates, unit=functools.partial(replicate_unit, spec=asdict(spec)),
        announce=lambda cell: f"cell {cell.name}: {spec.replicates} AMS runs of {spec.particles} particles",
        done_text=done_text, cell_result=functools.partial(_cell_from_rows, spec=spec),
        write=lambda results: _write(out, spec, campaign, results))


@dataclass
class _UnitResult:
    """What one AMS run sends back through an executor: one "row" (its AMSRun and cost)."""

    rows: list[dict[str, Any]]
    recordings: dict = field(default_factory=dict)


def replicate_unit(cell: Cell, episode_ids: tuple[int, ...], seed: int, common_random_numbers: bool,
                   record: tuple[int, ...], *, spec: dict[str, Any]) -> _UnitResult:
    """One AMS run (replicate ``episode_ids[0]``) of ``cell`` as an executor work unit (the
    :data:`~mcverify.campaign.executors.EpisodeFn` interface), so replicates spread over local
    worker processes or a Ray cluster with the executors' retries and crash isolation."""
    sp = SplittingSpec(**spec)
    (replicate,) = episode_ids
    process = ClosedLoopProcess(cell, seed, executors.solver_for(cell.params), sp.score)
    # the survivor draws are keyed by the replicate, the campaign seed and the cell (cell 0: the key of
    # the seed alone, as SeedSequence ignores a trailing 0), shared between cells only under common
    # random numbers
    key = (seed,) if common_random_numbers else (seed, cell.index)
    run = splitting.ams(process, n=sp.particles, k=sp.k, failure_level=0.0, seed=replicate,
                        max_iterations=sp.max_iterations, selection_key=key)
    return _UnitResult([{"cell_episode": replicate, "outcome": "ams", "run": asdict(run), "cpu_s": process.cpu_s,
                         "steps": process.steps, "fresh_steps": list(process.fresh_steps)}])


def _fate(run: dict[str, Any]) -> str:
    if run["extinct"]:
        return "extinct"
    if run.get("capped"):
        return "capped by --max-iterations before the failure level (not an estimate)"
    return f"estimate {run['estimate']:.3g}"


def _cell_from_rows(cell: Cell, rows: list[dict[str, Any]], spec: SplittingSpec) -> dict[str, Any]:
    # a kept run's NaN estimate comes back from JSON as None
    runs = [splitting.AMSRun(**{**row["run"], "killed": tuple(row["run"]["killed"]),
                                "estimate": math.nan if row["run"]["estimate"] is None else row["run"]["estimate"]})
            for row in rows]
    cost = _Cost(sum(r["cpu_s"] for r in rows), sum(r["steps"] for r in rows),
                 [s for r in rows for s in r["fresh_steps"]])
    return cell_result(cell.index, cell.name, spec, splitting.from_runs(runs, spec.level), runs, cost)


@dataclass
class _Cost:
    """The cost of a cell's AMS runs: CPU seconds, control steps, steps of each fresh episode."""

    cpu_s: float
    steps: int
    fresh_steps: list[int]


def cell_result(index: int, name: str, spec: SplittingSpec, est: splitting.SplittingEstimate,
                runs: list[splitting.AMSRun], process: _Cost | ClosedLoopProcess) -> dict[str, Any]:
    episode_steps = sum(process.fresh_steps) / max(1, len(process.fresh_steps))
    crude = (intervals.crude_steps_for(est.estimate, est.relative_halfwidth, episode_steps, spec.level)
             if est.estimate > 0 and math.isfinite(est.relative_halfwidth) and est.relative_halfwidth > 0
             else math.nan)  # a zero-width interval (runs that agree exactly) has no crude equivalent
    if len(runs) < FEW_RUNS:
        est = dataclasses.replace(est, warnings=[*est.warnings, (
            f"only {len(runs)} AMS runs: on the closed loop the t interval of fewer than {FEW_RUNS} runs covered "
            f"p in 86 % of repetitions (4 runs), not 95 % (docs/rare_events.md); use --replicates {FEW_RUNS} or more")])
    return {
        "cell_index": index, "cell": name, "method": "splitting", "target": spec.target, **est.as_dict(),
        "iterations": [r.iterations for r in runs], "extinct": [r.extinct for r in runs],
        "capped": [r.capped for r in runs],
        # every particle at the failure level at the end of an uncapped run, in run order: what
        # `mcverify replay DIR K` re-simulates (K its place in this list)
        "failing_particles": [{"run": i, **f} for i, r in enumerate(runs) if not r.capped for f in r.failing],
        "last_level": [r.levels[-1] if r.levels else None for r in runs],  # how close each run got (score)
        "cpu_s": process.cpu_s, "steps": process.steps,
        "mean_episode_steps": episode_steps, "crude_steps_same_width": crude,
        "steps_ratio_vs_crude": crude / process.steps if process.steps and math.isfinite(crude) else math.nan,
    }


def columns(out: Path, cells: int) -> list[folder.Column]:
    """The report's table: one row per cell (``cells``: how many the campaign has, for --cell)."""
    return replicates.columns(out, cells, "failing_particles", "failing particle")


def _write(out: Path, spec: SplittingSpec, campaign: Campaign, results: dict[int, dict]) -> Path:
    intro = (f"Target: {spec.target} (score {spec.score} reaching 0). Adaptive multilevel splitting, "
             f"{spec.replicates} independent runs of {spec.particles} particles (k = {spec.k}); the interval is "
             f"asymptotic ({spec.level:.0%} Student t on the runs' estimates).")
    return folder.write(out, f"mcverify splitting estimate: {campaign.name}", intro,
                        {"method": "splitting", **asdict(spec), "target": spec.target}, results,
                        columns(out, len(campaign.cells)))
