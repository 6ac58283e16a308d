"""``mcverify estimate CAMPAIGN --method importance``: cross-entropy importance sampling over a
cell's scenario ranges (:mod:`mcverify.estimate.importance`) on the real closed loop.

The parameters are the cell's scenario draws that have a range: alpha_f
(``scenario.front_accel_range_mps2``), veh_o's speed (``opposing.speed_range_mps``), spawn gap
(``opposing.spawn_gap_range_m``) and spawn delay (``opposing.spawn_delay_range_s``); each is uniform
on its range under the campaign, which is the nominal distribution. The perception noise stays
nominal (drawn from the episode key), unless a noise tilt is given (``--noise-tilt``,
:class:`~mcverify.sim.tilt.NoiseTilt`): then veh_f's lateral measurement noise at a few steps near
veh_f is drawn from that fixed proposal, and each episode's weight carries its likelihood ratio
(``noise_log_lr``) besides the scenario's. Every evaluation is one episode with the given values
(``run_episodes(scenarios=...)``), run in batches of 8 lanes, in this process or, with an executor
(``--workers``, Ray), one batch per work unit in parallel (an episode does not depend on its batch,
so the estimate is the same); its score is the final value of one of the splitting scores
(:mod:`mcverify.estimate.closed_loop`): minus min h_ef (``h_ef``, target ellipse), that brought
forward by the steps with neither Q1 nor Q2 solved (``h_ef_held``, target ellipse), by the episode's
longest run of such steps (``h_ef_run``, target ellipse: a row has no per-step runs) or minus the
footprint gap (``gap``, target collision), >= 0 exactly at the event. The score only steers the
cross-entropy stages; the estimate counts the event itself, so any score leaves it unbiased. Episode
ids count the evaluations from 0, so the estimate replays from (campaign seed, cell, the estimator's
seed).

What an interrupt keeps: the finished cells (``estimate.json``, ``samples_cellNNN.parquet``) and,
of the cell in progress, every finished batch of episodes (``evaluated_cellNNN.jsonl``,
:mod:`mcverify.estimate.evaluations`): ``--resume`` replays the cell's cross-entropy iterations from
the kept rows and runs only the batches that were not finished, so it gives the estimate of an
uninterrupted run. ``manifest.json`` gets ``finished_utc`` once every cell is estimated."""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcverify import store
from mcverify.analysis import intervals
from mcverify.campaign import executors
from mcverify.campaign.executors import Executor
from mcverify.campaign.spec import Campaign
from mcverify.cell import Cell
from mcverify.control.planner import Planner
from mcverify.draws import DRAW_REGISTRY, DRAWS
from mcverify.episode.rollout import ChunkResult, run_episodes
from mcverify.errors import RunError
from mcverify.estimate import evaluations, folder, importance
from mcverify.estimate.closed_loop import gap_score, h_ef_score
from mcverify.estimate.evaluations import EvaluationCache
from mcverify.estimate.folder import num
from mcverify.estimate.importance_files import (
    draw_cell,
    figure_file,
    tilt_text,
    write_samples,
)
from mcverify.reporting.run_figures import FigureResult
from mcverify.requirements import H_EF_SCORES, SCORE_REGISTRY, SCORED_TARGETS, SCORES, default_score
from mcverify.sim import tilt as tilt_mod
from mcverify.sim.tilt import NoiseTilt

#: Episodes simulated together (one lane group of the plant).
BATCH = 8


def scenario_bounds(cell: Cell) -> dict[str, tuple[float, float]]:
    """The cell's scenario parameters that are drawn from a range, with the range."""
    out = {}
    for draw in DRAWS:
        rng = draw.range_of(cell.params)
        if rng:
            out[draw.name] = (float(rng[0]), float(rng[1]))
    return out


def crude_comparison(est: importance.ISEstimate, rows: Sequence[dict[str, Any]], weights: np.ndarray,
                     steps: int) -> dict[str, float]:
    """What crude Monte Carlo would need for the estimate's relative half-width, in control steps: its
    episodes (from the estimate, :func:`mcverify.estimate.intervals.crude_steps_for`) times a nominal
    episode's steps, the final draws' steps weighted by their likelihood ratios (self-normalised: the
    nominal mean, whichever proposal drew them); and the ratio to the steps this estimate took."""
    w = np.asarray(weights, dtype=float)
    kept = w.size and len(rows) == w.size  # a score function that keeps no rows (a test's stub) has no steps
    episode_steps = float(np.sum(w * [r.get("steps", math.nan) for r in rows]) / np.sum(w)) if kept else math.nan
    half = (est.high - est.estimate) / est.estimate if est.estimate > 0 else math.nan  # the low end is clipped at 0
    crude = (intervals.crude_steps_for(est.estimate, half, episode_steps, est.level)
             if math.isfinite(half) and half > 0 else math.nan)
    return {"relative_halfwidth": half, "mean_episode_steps": episode_steps, "crude_steps_same_width": crude,
            "steps_ratio_vs_crude": crude / steps if steps and math.isfinite(crude) else math.nan}


def scenario_nominal(cell: Cell) -> importance.Nominal:
    """The nominal distribution of the cell's drawn scenario parameters (:func:`scenario_bounds`), as
    :func:`mcverify.episode.draws.sample_scenario` draws them: uniform on each range, but a truncated normal
    where the draw's standard deviation is > 0 (veh_o's spawn delay with ``opposing.spawn_delay_sd_s`` > 0)."""
    bounds = scenario_bounds(cell)
    p = cell.params
    normals = [(DRAW_REGISTRY[key].fixed(p), DRAW_REGISTRY[key].sd(p)) if DRAW_REGISTRY[key].sd(p) > 0 else None
               for key in bounds]
    return importance.Nominal.of(list(bounds.values()), normals)


def scenario_unit(cell: Cell, episode_ids: tuple[int, ...], seed: int, common_random_numbers: bool,
                  record: tuple[int, ...], *, names: Sequence[str],
                  values: Mapping[int, Sequence[float]], noise_tilt: NoiseTilt | None = None) -> ChunkResult:
    """One batch of evaluations as an executor work unit (the
    :data:`~mcverify.campaign.executors.EpisodeFn` interface): episodes ``episode_ids`` with the
    scenario ``values[e]`` (in the order of ``names``); each row carries its share of the unit's CPU
    seconds (``unit_cpu_s``). The noise is the episode's own (through ``noise_tilt`` if given), as in
    this process."""
    t0 = time.process_time()
    over = {e: dict(zip(names, map(float, values[e]), strict=True)) for e in episode_ids}
    res = run_episodes(cell, list(episode_ids), seed, executors.solver_for(cell.params), scenarios=over,
                       noise_tilt=noise_tilt)
    share = (time.process_time() - t0) / max(1, len(res.rows))
    for row in res.rows:
        row["unit_cpu_s"] = share
    return res


@dataclass
class ClosedLoopScore:
    """score(theta) on the closed loop: theta (m, d) in the order of ``names``; cost counted.
    With ``executor`` (and ``campaign``, whose cell this is) the batches run as parallel work units;
    otherwise one after the other with ``planner`` in this process."""

    cell: Cell
    seed: int
    planner: Planner | None
    names: list[str]
    target: str = "collision"
    score: str | None = None  # None: "gap" for target collision, "h_ef" for ellipse
    episodes: int = 0
    steps: int = 0
    cpu_s: float = 0.0
    executor: Executor | None = None
    campaign: Campaign | None = None
    noise_tilt: NoiseTilt | None = None
    progress: Callable[[str], None] | None = None
    cache: EvaluationCache | None = None  # episodes evaluated before an interrupt, and where new ones go
    _last_rows: list[dict[str, Any]] = field(default_factory=list)

    def __call__(self, theta: np.ndarray) -> np.ndarray | importance.Scored:
        ids = list(range(self.episodes, self.episodes + theta.shape[0]))
        values = {e: tuple(map(float, t)) for e, t in zip(ids, theta, strict=True)}
        rows = self._parallel(ids, values) if self.executor is not None else self._here(ids, values)
        self.episodes += theta.shape[0]
        self.steps += sum(int(r.get("steps") or 0) for r in rows)
        scores = np.array([self._score(r) for r in rows])
        self._last_rows = rows
        if self.noise_tilt is None:
            return scores
        return importance.Scored(scores, np.array([float(r.get("noise_log_lr") or 0.0) for r in rows]))

    def final_rows(self, m: int) -> list[dict[str, Any]]:
        """The rows of the last ``m`` evaluations (the final draws when the estimate just ended)."""
        return self._last_rows[-m:]

    def refit_noise(self, elite: np.ndarray, weights: np.ndarray) -> None:
        """Cross-entropy update of the noise tilt from the last batch's elite episodes (weights: their
        likelihood ratios); nothing without a tilt."""
        if self.noise_tilt is None:
            return
        rows = [r for r, e in zip(self._last_rows, elite, strict=True) if e]
        sums = np.array([r.get("noise_tilt_sums") or [0.0] * 9 for r in rows], dtype=float).reshape(-1, 9)
        counts = np.array([r.get("noise_tilt_counts") or [0.0] * 3 for r in rows], dtype=float).reshape(-1, 3)
        self.noise_tilt = tilt_mod.refit_tilt(self.noise_tilt, sums, counts, weights)
        if self.progress:
            self.progress(f"    noise tilt {tilt_text(self.noise_tilt)}")

    def _tilt_record(self) -> dict[str, Any] | None:
        return None if self.noise_tilt is None else self.noise_tilt._asdict()

    def _kept(self, part: list[int], values: dict[int, tuple[float, ...]]) -> list[dict[str, Any]] | None:
        """The batch's rows from before an interrupt, when all of it was evaluated with these inputs."""
        return None if self.cache is None else self.cache.rows(part, values, self._tilt_record())

    def _keep(self, rows: list[dict[str, Any]], values: dict[int, tuple[float, ...]]) -> None:
        if self.cache is not None:
            self.cache.add(rows, values, self._tilt_record())

    def _here(self, ids: list[int], values: dict[int, tuple[float, ...]]) -> list[dict[str, Any]]:
        rows = []
        for start in range(0, len(ids), BATCH):
            part = ids[start:start + BATCH]
            batch = self._kept(part, values)
            if batch is None:
                over = {e: dict(zip(self.names, values[e], strict=True)) for e in part}
                t0 = time.process_time()
                batch = run_episodes(self.cell, part, self.seed, self.planner, scenarios=over,
                                     noise_tilt=self.noise_tilt).rows
                share = (time.process_time() - t0) / max(1, len(batch))
                for row in batch:
                    row["unit_cpu_s"] = share
                self._keep(batch, values)
            self.cpu_s += sum(float(r.get("unit_cpu_s") or 0.0) for r in batch)
            rows += batch
        return rows

    def _parallel(self, ids: list[int], values: dict[int, tuple[float, ...]]) -> list[dict[str, Any]]:
        if self.campaign is None:
            raise ValueError("a ClosedLoopScore with an executor needs its campaign")
        got: dict[int, dict[str, Any]] = {}

        def on_done(chunk: store.Chunk, output) -> None:
            for row in output.rows:
                got[int(row["cell_episode"])] = row
            self._keep(list(output.rows), values)

        chunks = []
        for i in range(0, len(ids), BATCH):
            part = ids[i:i + BATCH]
            kept = self._kept(part, values)
            if kept is None:
                chunks.append(store.Chunk(self.cell.index, tuple(part)))
            else:
                got.update(zip(part, kept, strict=True))
        unit = functools.partial(scenario_unit, names=tuple(self.names), values=values, noise_tilt=self.noise_tilt)
        if chunks:
            executors.execute(self.campaign, chunks, on_done, executor=self.executor, episode_fn=unit)
        rows = [got[e] for e in ids]  # in episode order, whatever order the units finished in
        self.cpu_s += sum(float(r.get("unit_cpu_s") or 0.0) for r in rows)
        return rows

    def _score(self, row: dict) -> float:
        if row.get("outcome") == "error":
            return -math.inf  # an episode that could not be simulated never counts as the event
        score = self.score or default_score(self.target)
        if score in H_EF_SCORES:  # h_ef_run from the longest run: the row has no per-step runs
            run = SCORE_REGISTRY[score].unsolved == "run"
            unsolved = row.get("both_infeasible_longest_run" if run else "both_infeasible_steps")
            return h_ef_score(score, row["min_h_front"], unsolved or 0)
        gaps = [float(row.get(k, math.nan)) for k in ("min_gap_front_m", "min_gap_opp_any_m")]
        collided = bool(row.get("collision_front")) or bool(row.get("collision_opp"))
        finite = [g for g in gaps if math.isfinite(g)]
        if collided:
            return 0.0
        # gap_run from the longest run, as h_ef_run: the row has no per-step runs
        return gap_score(score, min(finite) if finite else math.inf, row.get("both_infeasible_longest_run") or 0)


@dataclass(frozen=True)
class ImportanceSpec:
    """target: collision or ellipse; samples: final draws from the defensive mixture; ce_samples:
    draws per cross-entropy iteration; rho: elite share; alpha: defensive (nominal) share; level;
    score: what steers the cross-entropy stages (None: ``gap`` for collision, ``h_ef`` for ellipse);
    noise_tilt: the fields of the starting :class:`~mcverify.sim.tilt.NoiseTilt` (None: the nominal
    noise); the cross-entropy iterations refit its tilts."""

    target: str = "collision"
    samples: int = 400
    ce_samples: int = 100
    rho: float = 0.1
    alpha: float = 0.1
    level: float = 0.95
    max_ce_iterations: int = 10
    score: str | None = None
    noise_tilt: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.target not in SCORED_TARGETS:
            raise ValueError(f"importance sampling estimates --target {' or '.join(SCORED_TARGETS)}")
        if self.score is not None and SCORES.get(self.score) != self.target:
            fitting = ", ".join(k for k, v in SCORES.items() if v == self.target)
            raise ValueError(f"--score {self.score} does not steer towards --target {self.target} "
                             f"(scores of {self.target}: {fitting})")
        if not 0.0 < self.alpha < 1.0 or not 0.0 < self.rho < 1.0:
            raise ValueError("alpha and rho must be in (0, 1)")
        if self.samples < 2 or self.ce_samples < 2:
            raise ValueError("need at least 2 samples and 2 cross-entropy samples")
        if self.noise_tilt is not None:
            tilt = self.tilt()
            assert tilt is not None
            if (not 0.0 < tilt.defensive <= 1.0 or tilt.gap_max_m <= 0.0 or tilt.band_steps < 1
                    or tilt.theta_max <= 0 or len(tilt.theta) != 9):
                raise ValueError("--noise-tilt needs defensive in (0, 1], gap_max_m > 0, band_steps >= 1, "
                                 "theta_max > 0 and 9 tilts")

    def tilt(self) -> NoiseTilt | None:
        """The starting noise tilt as the plant takes it, or None."""
        if self.noise_tilt is None:
            return None
        return NoiseTilt.from_dict(self.noise_tilt)

    def max_noise_ratio(self) -> float:
        """The largest likelihood ratio the tilt can give an episode (1 without a tilt)."""
        tilt = self.tilt()
        return 1.0 if tilt is None else tilt.max_ratio()


def check_cells_have_ranges(campaign: Campaign, cells: Sequence[str] | None = None) -> None:
    """Refuse a campaign with a cell to estimate (all, or those named in ``cells``) that draws no
    scenario parameter from a range: importance sampling has nothing to sample there."""
    for cell in campaign.cells:
        if (not cells or cell.name in cells) and not scenario_bounds(cell):
            raise RunError(f"cell {cell.name} draws no scenario parameter from a range: nothing to sample "
                           "(give e.g. scenario.front_accel_range_mps2)")


def run(campaign: Campaign, spec: ImportanceSpec, out: Path, *, progress=print,
        cells: list[str] | None = None, executor: Executor | None = None) -> Path:
    """Estimate every cell of ``campaign`` (or those named in ``cells``) into the new folder ``out``.
    executor: where the batches of episodes go (default: this process, one after the other)."""
    check_cells_have_ranges(campaign, cells)
    folder.create(out, campaign, {"method": "importance", **asdict(spec)}, cells)
    return _cells(campaign, spec, Path(out), {}, progress, cells, executor)


def resume(out: Path, campaign: Campaign, *, progress=print, executor: Executor | None = None) -> Path:
    """Finish an interrupted importance-sampling estimate: finished cells are kept; the cell that was in
    progress continues from its kept batches of episodes (the same episodes and estimate)."""
    manifest, done = folder.load(out, "importance")
    spec = ImportanceSpec(**{k: v for k, v in manifest["estimate"].items() if k != "method"})
    return _cells(campaign, spec, Path(out), done, progress, manifest.get("only_cells"), executor)


def _replay_text(out: Path, result: dict[str, Any], cells: int) -> str:
    """The replay command of a cell's first failing final draw (``mcverify.estimate.replay``), or "-"."""
    failing = result.get("failing_draws") or []
    return folder.replay_text(out, result, failing, failing[0] if failing else 0, cells)


def _cells(campaign: Campaign, spec: ImportanceSpec, out: Path, done: dict[int, dict], progress,
           only: list[str] | None, executor: Executor | None = None) -> Path:
    if executor is None:
        return _cells_on(campaign, spec, out, done, progress, only, None)
    with executor as ex:
        return _cells_on(campaign, spec, out, done, progress, only, ex)


def _cells_on(campaign: Campaign, spec: ImportanceSpec, out: Path, done: dict[int, dict], progress,
              only: list[str] | None, executor: Executor | None) -> Path:
    results = dict(done)
    columns: list[folder.Column] = [
        ("cell", lambda c: c["cell"]),
        ("parameters (nominal)", lambda c: "; ".join(c.get("nominal") or c["parameters"])),
        ("estimate", lambda c: num(c["estimate"])), ("interval", lambda c: f"[{num(c['low'])}, {num(c['high'])}]"),
        ("anytime lower bound", lambda c: num(c["anytime_lower"])),
        ("failing samples", lambda c: str(c["failures"])), ("ESS", lambda c: num(c["ess"], ".0f")),
        ("largest weight share", lambda c: num(c["max_weight_share"], ".2f")),
        ("rel. half-width", lambda c: num(c.get("relative_halfwidth"), ".2f")),
        ("episodes", lambda c: str(c["episodes"])), ("control steps", lambda c: str(c["steps"])),
        ("CPU (s)", lambda c: num(c["cpu_s"], ".0f")),
        ("crude MC steps, same width", lambda c: num(c.get("crude_steps_same_width"))),
        ("ratio", lambda c: num(c.get("steps_ratio_vs_crude"), ".3g")),
        ("warnings", lambda c: "; ".join(c["warnings"]) or "-"),
        ("replay the first failing draw", lambda c: _replay_text(out, c, len(campaign.cells))),
    ]
    steer = spec.score or ("gap" if spec.target == "collision" else "h_ef")
    tilt = spec.tilt()
    noise_text = ("the noise stays nominal" if tilt is None else
                  "veh_f's measurement noise near veh_f is drawn from a noise tilt refitted by the cross-entropy "
                  f"iterations (start: {tilt_text(tilt)}; each episode's weight carries its likelihood ratio)")
    intro = (f"Target: {spec.target}, cross-entropy steered by the score {steer}. Cross-entropy importance "
             "sampling over the cell's scenario ranges "
             f"({spec.ce_samples} episodes per CE iteration, elite share {spec.rho:g}), then {spec.samples} episodes "
             f"from the defensive mixture ({spec.alpha:g} nominal); {noise_text}. The interval is "
             f"asymptotic ({spec.level:.0%} normal); read it with the ESS and the largest weight's share. The "
             "anytime lower bound (one-sided, same level, betting on the bounded weights) holds at any sample count. "
             "Each cell's final draws (episode id, scenario values, weight, failed, outcome) are kept in "
             "samples_cellNNN.parquet; the estimate is mean(weight * failed) over them. The figures show, per "
             "scenario parameter, the nominal density, the proposal the final draws came from, their histogram "
             "and a red tick per failing draw.")

    def write():
        figures = [FigureResult(f"importance-cell{i:03d}", f"Cell {results[i]['cell']}: nominal, proposal and draws",
                                "Per scenario parameter: the nominal density, the proposal the final draws came from, "
                                "their histogram and a red tick per failing draw.", figure_file(i))
                   for i in sorted(results) if (out / figure_file(i)).exists()]
        return folder.write(out, f"mcverify importance-sampling estimate: {campaign.name}", intro,
                            {"method": "importance", **asdict(spec)}, results, columns, figures)

    for cell in campaign.cells:
        if cell.index in results:
            evaluations.cache_file(out, cell.index).unlink(missing_ok=True)  # left by a kill after its result
            continue
        if only and cell.name not in only:
            continue
        bounds = scenario_bounds(cell)
        progress(f"cell {cell.name}: importance sampling over {', '.join(bounds)}")
        planner = executors.solver_for(cell.params) if executor is None else None
        cache = EvaluationCache(evaluations.cache_file(out, cell.index))
        if len(cache):
            progress(f"  {len(cache)} episodes evaluated before the interrupt are kept")
        score = ClosedLoopScore(cell, campaign.seed, planner, list(bounds), spec.target, spec.score,
                                executor=executor, campaign=campaign, noise_tilt=tilt, progress=progress,
                                cache=cache)
        # the draws of the scenario parameters follow the campaign seed and the cell (as the noise
        # does), so that estimates with distinct --seed are independent repetitions and the cells of
        # one campaign are independent estimates (shared draws only under common random numbers)
        final: dict[str, np.ndarray] = {}
        nominal = scenario_nominal(cell)
        est = importance.estimate(score, list(bounds.values()), samples=spec.samples, alpha=spec.alpha,
                                  level=spec.level, seed=campaign.seed, per_iteration=spec.ce_samples, rho=spec.rho,
                                  max_iterations=spec.max_ce_iterations, max_extra_ratio=spec.max_noise_ratio(),
                                  stream=0 if campaign.common_random_numbers else cell.index, progress=progress,
                                  on_samples=lambda t, w, f, kept=final: kept.update(theta=t, weight=w, failed=f),
                                  nominal=nominal)
        drawn = score.final_rows(len(final["weight"]))
        write_samples(out, cell.index, list(bounds), drawn, final)
        failing = [int(r["cell_episode"]) for r, f in zip(drawn, final["failed"], strict=False) if f]
        results[cell.index] = {"cell_index": cell.index, "cell": cell.name, "method": "importance",
                               "target": spec.target, "parameters": list(bounds),
                               "nominal": nominal.describe(list(bounds)), **est.as_dict(),
                               "failing_draws": failing,
                               "episodes": score.episodes, "steps": score.steps, "cpu_s": score.cpu_s,
                               **crude_comparison(est, drawn, final["weight"], score.steps),
                               **({} if score.noise_tilt is None else {"noise_tilt": score.noise_tilt._asdict()})}
        draw_cell(out, results[cell.index], bounds, spec.alpha, final, nominal)
        write()
        cache.remove()
    folder.finish(out)
    return write()  # after finish, so that the report says the estimate is complete
