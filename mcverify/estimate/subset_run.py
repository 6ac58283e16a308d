"""``mcverify estimate CAMPAIGN --method subset``: subset simulation per cell on the real closed loop,
into a folder with ``manifest.json``, ``estimate.json`` and ``report.md`` (:mod:`mcverify.estimate.folder`).

Every cell gets ``runs`` independent subset simulation runs (:func:`mcverify.estimate.subset.run`) over
the whole input vector of its episodes (:class:`~mcverify.estimate.input_vector.ClosedLoopProblem`:
the scenario draws and every per-step perception error as standard normals); the estimate is their
mean with a Student t interval (asymptotic), the mean within-run coefficient of variation of Au and Beck
(chains' correlation included) beside it. The cost is counted in control steps; crude Monte Carlo's
steps for the same relative half-width come from the estimate and the mean length of stage 0's
episodes (prior draws: crude episodes).

Work units: one run of one cell, on the executors (this process by default, local workers or Ray),
each deterministic from (campaign seed, cell, run) (:mod:`mcverify.estimate.subset`'s SeedSequence keys;
under common random numbers the cells share their keys). A run saves its state after every stage in
``runs/cellNNN_runNNN.npz`` and a finished run its record in ``runs/cellNNN_runNNN.json`` and its
failing samples' inputs in ``runs/cellNNN_runNNN-failing.npz``; ``--resume`` keeps finished runs and
continues unfinished ones from their last stage, bit for bit the uninterrupted estimate.
"""

from __future__ import annotations

import functools
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcverify import files
from mcverify.campaign import executors
from mcverify.campaign.executors import Executor
from mcverify.campaign.spec import Campaign
from mcverify.cell import Cell
from mcverify.errors import RunError
from mcverify.estimate import folder, replicates, subset
from mcverify.estimate.folder import num
from mcverify.estimate.input_vector import ClosedLoopProblem, check_law
from mcverify.requirements import PERFORMANCE_TEXT, PERFORMANCES, TARGETS


@dataclass(frozen=True)
class SubsetSpec:
    """target: the event (:data:`mcverify.requirements.TARGETS`); samples: N per stage; p0: the
    conditional level; runs: independent runs for the interval; level; max_stages per run; performance:
    the function whose levels the runs climb (:data:`mcverify.requirements.PERFORMANCES`)."""

    target: str = "collision"
    samples: int = 2000
    p0: float = 0.1
    runs: int = 8
    level: float = 0.95
    max_stages: int = 20
    performance: str = PERFORMANCES[0]

    def __post_init__(self) -> None:
        if self.target not in TARGETS:
            raise ValueError(f"unknown target {self.target!r}; valid: {', '.join(TARGETS)}")
        if self.performance not in PERFORMANCES:
            raise ValueError(f"unknown --performance {self.performance!r}; valid: {', '.join(PERFORMANCES)}")
        if self.runs < 2:
            raise ValueError(f"--replicates must be at least 2 (got {self.runs}) for an interval")
        self.settings()  # N and p0 checked there

    def settings(self) -> subset.Settings:
        try:
            return subset.Settings(n=self.samples, p0=self.p0, max_stages=self.max_stages)
        except ValueError as err:
            raise ValueError(f"--samples and --p0: {err}") from None


def run(campaign: Campaign, spec: SubsetSpec, out: Path, *, progress=print,
        cells: list[str] | None = None, executor: Executor | None = None, stage_lines: bool = False) -> Path:
    """Estimate every cell of ``campaign`` (or those in ``cells``) into the new folder ``out``; with
    ``stage_lines`` each run says on stderr every stage it closes (a closed-loop run takes minutes per
    stage)."""
    for cell in campaign.cells:
        if not cells or cell.name in cells:
            check_law(cell)
    folder.create(out, campaign, {"method": "subset", **asdict(spec)}, cells)
    return replicates.run_cells(campaign, _replicated(campaign, spec, Path(out), stage_lines), Path(out), {},
                                progress, cells, executor)


def resume(out: Path, campaign: Campaign, *, progress=print, executor: Executor | None = None,
           stage_lines: bool = False) -> Path:
    """Finish an interrupted subset estimate: finished cells kept, finished runs kept, runs in progress
    continued from their last stage."""
    manifest, done = folder.load(out, "subset")
    spec = SubsetSpec(**{k: v for k, v in manifest["estimate"].items() if k != "method"})
    return replicates.run_cells(campaign, _replicated(campaign, spec, Path(out), stage_lines), Path(out), done,
                                progress, manifest.get("only_cells"), executor)


def _replicated(campaign: Campaign, spec: SubsetSpec, out: Path, stage_lines: bool) -> replicates.Replicated:
    def done_text(row: dict[str, Any]) -> str:
        r = row["run"]
        return (f"estimate {num(r['estimate'])}, {len(r['stages'])} stages, {r['steps']} control steps, "
                f"{row['cpu_s']:.0f} CPU-s")

    return replicates.Replicated(
        label="subset run", count=spec.runs,
        unit=functools.partial(run_unit, spec=asdict(spec), out=str(out), stage_lines=stage_lines),
        announce=lambda cell: f"cell {cell.name}: {spec.runs} subset simulation runs of {spec.samples} episodes "
                              "per stage",
        done_text=done_text, cell_result=functools.partial(cell_result, spec=spec),
        write=lambda results: _write(out, spec, campaign, results))


def run_stem(out: Path, cell_index: int, run_id: int) -> Path:
    """A run's files without their suffix: ``.json`` (its record), ``.npz`` (its checkpoint)."""
    return replicates.run_path(out, cell_index, run_id).with_suffix("")


@dataclass
class _UnitResult:
    rows: list[dict[str, Any]]
    recordings: dict = field(default_factory=dict)


def problem_for(cell: Cell, seed: int, target: str, performance: str = PERFORMANCES[0]) -> ClosedLoopProblem:
    return ClosedLoopProblem(cell, seed, target, executors.solver_for(cell.params), performance)


def run_key(campaign_seed: int, cell: Cell, common_random_numbers: bool) -> tuple[int, ...]:
    """The SeedSequence entropy of a cell's runs: the campaign seed, and the cell unless its keys are shared."""
    return (campaign_seed,) if common_random_numbers else (campaign_seed, cell.index)


def run_unit(cell: Cell, episode_ids: tuple[int, ...], seed: int, common_random_numbers: bool,
             record: tuple[int, ...], *, spec: dict[str, Any], out: str, stage_lines: bool = False) -> _UnitResult:
    """One subset simulation run (run ``episode_ids[0]``) of ``cell`` as an executor work unit; with
    ``stage_lines`` it says on stderr every stage it closes (from a worker too: workers share stderr)."""
    sp = SubsetSpec(**spec)
    (run_id,) = episode_ids
    stem = run_stem(Path(out), cell.index, run_id)
    stem.parent.mkdir(parents=True, exist_ok=True)
    start = time.process_time()
    problem = problem_for(cell, seed, sp.target, sp.performance)
    setup_s = time.process_time() - start  # the solver loaded in this process; the run counts its own stages
    on_stage = functools.partial(_say_stage, f"cell {cell.name} run {run_id}", setup_s) if stage_lines else None
    result = subset.run(problem, sp.settings(), seed=run_key(seed, cell, common_random_numbers), run=run_id,
                        checkpoint=stem.with_suffix(".npz"), on_stage=on_stage)
    failing = stem.parent / f"{stem.name}-failing.npz"
    files.atomic_write(failing, lambda tmp: _save_failing(tmp, result))
    first = result.stages[0]
    return _UnitResult([{"cell_episode": run_id, "outcome": "subset", "run": _run_record(result),
                         "cpu_s": setup_s + result.cpu_s,  # earlier processes' stages included (resume)
                         "stage0_episode_steps": first.steps / max(1, first.evaluations)}])


def _say_stage(name: str, setup_s: float, stage: subset.Stage, cpu_s: float) -> None:
    what = "the event" if stage.threshold <= 0.0 else f"level {stage.threshold:.4g}"
    print(f"  {name}: {what}, share {stage.share:.3g} (this stage {stage.evaluations} episodes, {stage.steps} "
          f"control steps); {setup_s + cpu_s:.0f} CPU-s so far", file=sys.stderr, flush=True)


def _save_failing(tmp: str, result: subset.Run) -> None:
    with open(tmp, "wb") as f:
        np.savez(f, x=result.failing, g=result.failing_g)


def _run_record(result: subset.Run) -> dict[str, Any]:
    return {"estimate": result.estimate, "cov": result.cov, "stages": [asdict(s) for s in result.stages],
            "evaluations": result.evaluations, "steps": result.steps, "capped": result.capped,
            "failing": int(result.failing.shape[0])}


def as_run(record: dict[str, Any]) -> subset.Run:
    """A :class:`subset.Run` from its record (its failing inputs are kept apart: :func:`failing_inputs`)."""
    stages = tuple(subset.Stage(**s) for s in record["stages"])
    est = math.nan if record["estimate"] is None else float(record["estimate"])
    cov = math.inf if record["cov"] is None else float(record["cov"])
    return subset.Run(est, cov, stages, int(record["evaluations"]), int(record["steps"]), bool(record["capped"]),
                      np.empty((0, 0)), np.empty(0))


def failing_inputs(out: Path, cell_index: int, run_id: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, g) of the failing samples a finished run kept."""
    path = run_stem(out, cell_index, run_id).parent / f"cell{cell_index:03d}_run{run_id:03d}-failing.npz"
    if not path.is_file():
        raise RunError(f"{out}: run {run_id} of cell {cell_index} kept no failing samples ({path.name} is missing)")
    with np.load(path) as data:
        return data["x"].copy(), data["g"].copy()


def cell_result(cell: Cell, rows: list[dict[str, Any]], spec: SubsetSpec) -> dict[str, Any]:
    """A cell's estimate from its runs' records: the t interval, the within-run CoV, the cost, crude
    Monte Carlo's steps for the same width, and where each failing sample is kept (for replay)."""
    runs = [as_run(r["run"]) for r in rows]
    episode_steps = float(np.mean([r["stage0_episode_steps"] for r in rows]))
    est = subset.from_runs(runs, episode_steps, spec.level)
    failing = [{"run": i, "sample": j} for i, r in enumerate(rows) if not r["run"]["capped"]
               for j in range(int(r["run"]["failing"]))]
    return {"cell_index": cell.index, "cell": cell.name, "method": "subset", "target": spec.target,
            **{k: v for k, v in est.as_dict().items() if k != "runs"}, "runs": list(est.runs),
            "stages": [len(r["run"]["stages"]) for r in rows], "failing_samples": failing,
            "cpu_s": sum(r["cpu_s"] for r in rows), "mean_episode_steps": episode_steps,
            "crude_steps_same_width": est.crude_steps,
            "steps_ratio_vs_crude": est.factor if math.isfinite(est.factor) else math.nan}


def columns(out: Path, cells: int) -> list[folder.Column]:
    return replicates.columns(out, cells, "failing_samples", "failing sample",
                              [("within-run CoV of the mean", lambda c: num(c["within_run_cov"], ".2f"))])


def _write(out: Path, spec: SubsetSpec, campaign: Campaign, results: dict[int, dict]) -> Path:
    intro = (f"Target: {spec.target} (its robustness <= 0). Subset simulation over the whole input vector (the "
             f"scenario draws and every per-step perception error as standard normals), {spec.runs} independent "
             f"runs of {spec.samples} episodes per stage at conditional level {spec.p0}"
             + ("" if spec.performance == PERFORMANCES[0] else
                f" climbing the {spec.performance.replace('-', ' ')} (performance function: "
                f"{PERFORMANCE_TEXT[spec.performance]}, the same event)")
             + "; the interval is asymptotic "
             f"({spec.level:.0%} Student t on the runs' estimates), the within-run CoV (Au and Beck, chains' "
             "correlation included) beside it.")
    return folder.write(out, f"mcverify subset estimate: {campaign.name}", intro,
                        {"method": "subset", **asdict(spec)}, results, columns(out, len(campaign.cells)))
