"""Subset simulation [AB01] over a whole input vector of independent standard normals.

The problem is a batched performance function g over x in R^d (the event is g(x) <= ``failure_level``,
0 by default: the requirement's robustness), with every random input of an episode in x: the
scenario units and every per-step noise unit (:class:`Problem`). One run:

1. stage 0: N independent draws from the prior N(0, I_d);
2. at stage j, y_j = the midpoint between the (N p0)-th and (N p0 + 1)-th smallest g; if
   y_j <= failure_level stop with P_j = share of the stage with g <= failure_level; else the
   N p0 samples below y_j seed N p0 Markov chains of length 1 / p0 (the seed included) whose
   stationary law is the prior conditioned on g <= y_j, giving stage j + 1;
3. the estimate is p0^j' * P_L: the product of the conditional shares (each p0 but for ties).

Moves: the adaptive conditional sampler of [PBS15], preconditioned Crank-Nicolson per component:
candidate v = rho * x + sigma * xi with sigma_i = min(1, lambda * sd_i) (sd_i: the seeds' spread of
component i) and rho_i = sqrt(1 - sigma_i^2), which keeps the prior invariant, so the candidate is
accepted iff g(v) <= y_j. (Au and Beck's component-wise modified Metropolis was measured against it
on the surrogate and lost: see docs/decisions.md.) The scale lambda is adapted between groups of
chains towards an acceptance rate of ``target_acceptance`` (log lambda += (rate - target) /
sqrt(group)), carried from level to level; chains within a group share one scale, so each is a
Markov chain of its own.

Error: the within-run coefficient of variation of [AB01], delta^2 = sum_j (1 - P_j) / (N P_j)
(1 + gamma_j), gamma_j from the indicator's correlation along the chains; the interval is the
Student t interval of independent runs (:func:`estimate`), with the within-run value reported beside.

Determinism: stage 0's draws come from SeedSequence(seed, spawn_key=(run, 0, 0)), seed an int or ints
such as (campaign seed, cell index); chain c of stage j from (run, j, 1, c), step s being the s-th
block of its stream; the seeds' order from (run, j, 0).
A run with a ``checkpoint`` path saves its state after each stage and resumes from it: the resumed
run is bit for bit the uninterrupted one. Every failing sample of the last stage is returned with its
full input vector, so a deterministic episode function replays it.

[AB01] S.-K. Au, J. L. Beck, Estimation of small failure probabilities in high dimensions by subset
simulation, Probab. Eng. Mech. 16 (2001). [PBS15] I. Papaioannou, W. Betz, K. Zwirglmaier, D. Straub,
MCMC algorithms for subset simulation, Probab. Eng. Mech. 41 (2015).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from scipy import stats as sps

from mcverify import files
from mcverify.analysis import intervals


class Problem(Protocol):
    """What subset simulation needs of an episode function: the input length, and for (n, dimension)
    standard-normal inputs the (n,) robustness g (the event is g <= failure level) and the (n,) control
    steps each evaluation simulated, from one call (a closed-loop episode gives both at once). It must
    be a pure function of the rows: a failing row then replays. An optional ``key`` string names the
    problem in checkpoints (else its repr)."""

    @property
    def dimension(self) -> int: ...

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class Settings:
    """N samples per stage, conditional level p0, and the pCN moves' scale adaptation.

    N must let every route to the event keep samples at every level: the chains do not cross between
    routes, and a route that is rare at the intermediate levels but not in the event is lost by most
    runs and kept, far over its share, by a few, which no interval over runs repairs (the surrogate's
    study in docs/decisions.md)."""

    n: int = 1000
    p0: float = 0.1
    target_acceptance: float = 0.44
    initial_scale: float = 0.6
    chains_per_group: int = 10  # [PBS15] adapt after every 100 p0 chains
    max_stages: int = 40
    failure_level: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 < self.p0 < 0.5:
            raise ValueError(f"p0 must be in (0, 0.5), got {self.p0}")
        chains = self.n * self.p0
        if abs(chains - round(chains)) > 1e-9 or round(chains) < 2 or self.n % round(chains):
            raise ValueError(f"n * p0 must be an integer >= 2 that divides n, got n={self.n}, p0={self.p0}")
        if not 0.0 < self.target_acceptance < 1.0 or self.initial_scale <= 0 or self.chains_per_group < 1:
            raise ValueError("need 0 < target_acceptance < 1, initial_scale > 0 and chains_per_group >= 1")

    @property
    def chains(self) -> int:
        return int(round(self.n * self.p0))


@dataclass(frozen=True)
class Stage:
    """One stage's population: its threshold y_j (failure_level at the last), the share P_j of it at or
    below, Au and Beck's gamma_j, and how it was made: the moves' acceptance rate and the scale lambda
    they started from (None at stage 0, drawn from the prior), its evaluations and control steps."""

    threshold: float
    share: float
    gamma: float
    acceptance: float | None
    scale: float | None
    evaluations: int
    steps: int


@dataclass(frozen=True)
class Run:
    """One subset simulation run. ``failing``: (m, d) inputs of the last stage with g <= the failure
    level, ``failing_g`` their robustness; ``capped``: max_stages reached first (estimate NaN)."""

    estimate: float
    cov: float  # within-run coefficient of variation [AB01], chains' correlation included
    stages: tuple[Stage, ...]
    evaluations: int
    steps: int
    capped: bool
    failing: np.ndarray = field(repr=False, compare=False)  # == leaves the arrays out; same_as compares them
    failing_g: np.ndarray = field(repr=False, compare=False)
    #: CPU seconds of the stages kept, across resumes (NaN: a checkpoint from before it was kept); a measure of
    #: the machine, not of the run, so neither == nor same_as compares it
    cpu_s: float = field(default=math.nan, compare=False)

    def same_as(self, other: Run) -> bool:
        """Bit-for-bit equality, arrays included."""
        return (self.stages == other.stages and self.estimate == other.estimate and self.steps == other.steps
                and np.array_equal(self.failing, other.failing) and np.array_equal(self.failing_g, other.failing_g))


#: A run's seed: an int, or ints such as (campaign seed, cell index) so that the cells of one campaign
#: share no stream (SeedSequence entropy; a trailing 0 adds nothing, so (seed, 0) is seed's stream).
Seed = int | tuple[int, ...]


def _rng(seed: Seed, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def gamma_factor(hits: np.ndarray, share: float) -> float:
    """Au and Beck's gamma for indicators ``hits`` (chains, length): 2 sum_k (1 - k/length) rho(k),
    rho(k) the indicator's autocorrelation at lag k along the chains [AB01, eq. (29)]."""
    chains, length = hits.shape
    n = chains * length
    var = share * (1.0 - share)
    if length < 2 or var <= 0.0:
        return 0.0
    h = hits.astype(float)
    gamma = 0.0
    for k in range(1, length):
        r = float(np.sum(h[:, :-k] * h[:, k:])) / (n - k * chains) - share * share
        gamma += 2.0 * (1.0 - k * chains / n) * r / var
    return gamma


def _propose(x: np.ndarray, sigma: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """pCN candidates for states ``x`` (m, d): they keep the prior invariant by themselves."""
    return np.sqrt(1.0 - sigma**2) * x + sigma * normals


def _chains(problem: Problem, seeds: np.ndarray, seed_g: np.ndarray, threshold: float, scale: float,
            settings: Settings, key: tuple[Seed, int, int]) -> tuple[np.ndarray, np.ndarray, float, float, int]:
    """Run the chains of stage ``key`` = (seed, run, stage) from ``seeds``: returns states (chains,
    length, d), their g, the acceptance rate, the adapted scale and the control steps spent."""
    seed, run, stage = key
    chains, d = seeds.shape
    length = settings.n // chains
    spread = np.maximum(seeds.std(axis=0), 1e-3) if chains > 1 else np.ones(d)
    x = np.empty((chains, length, d))
    g = np.empty((chains, length))
    x[:, 0], g[:, 0] = seeds, seed_g
    accepted, steps, log_scale = 0, 0, math.log(scale)
    group_size = settings.chains_per_group
    for group, start in enumerate(range(0, chains, group_size)):
        idx = np.arange(start, min(chains, start + group_size))
        sigma = np.minimum(1.0, math.exp(log_scale) * spread)
        draws = [_rng(seed, run, stage, 1, int(c)) for c in idx]
        normals = np.stack([r.standard_normal((length - 1, d)) for r in draws], axis=1)
        group_accepted = 0
        for s in range(1, length):
            cand = _propose(x[idx, s - 1], sigma, normals[s - 1])
            g_cand, spent = _evaluate(problem, cand)
            steps += spent
            ok = g_cand <= threshold
            x[idx, s] = np.where(ok[:, None], cand, x[idx, s - 1])
            g[idx, s] = np.where(ok, g_cand, g[idx, s - 1])
            group_accepted += int(ok.sum())
        rate = group_accepted / (idx.size * (length - 1))
        accepted += group_accepted
        log_scale += (rate - settings.target_acceptance) / math.sqrt(group + 1)
    return x, g, accepted / (chains * (length - 1)), math.exp(log_scale), steps


# -- checkpoints -------------------------------------------------------------------------------------


def _fingerprint(problem: Problem, settings: Settings, seed: Seed, run: int) -> str:
    """What a checkpoint must match: a problem names itself by a ``key`` attribute, else by its repr."""
    name = getattr(problem, "key", None) or repr(problem)
    return json.dumps({"settings": asdict(settings), "seed": seed, "run": run, "dimension": int(problem.dimension),
                       "problem": name}, sort_keys=True)


@dataclass
class _State:
    """A run between stages: population ``stage`` (x, g), how it was made, the scale, stages done."""

    stage: int
    x: np.ndarray
    g: np.ndarray
    made: tuple[float | None, float | None, int, int]  # acceptance, scale, evaluations, steps of this population
    scale: float
    stages: list[Stage]
    cpu_s: float = 0.0  # CPU seconds spent on the stages and population kept here, earlier processes included


def _save(path: Path, fingerprint: str, state: _State) -> None:
    meta = json.dumps({"fingerprint": fingerprint, "stage": state.stage, "made": list(state.made),
                       "stages": [asdict(s) for s in state.stages], "cpu_s": state.cpu_s})

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, x=state.x, g=state.g, scale=np.array([state.scale]), meta=np.array(meta))

    files.atomic_write(path, write)


def _load(path: Path, fingerprint: str) -> _State:
    with np.load(path) as data:
        meta = json.loads(str(data["meta"]))
        if meta["fingerprint"] != fingerprint:
            raise ValueError(f"{path} is the checkpoint of another run (problem, settings, seed or run differ)")
        acc, sc, ev, st = meta["made"]
        return _State(meta["stage"], data["x"].copy(), data["g"].copy(), (acc, sc, int(ev), int(st)),
                      float(data["scale"][0]), [Stage(**s) for s in meta["stages"]], float(meta.get("cpu_s", math.nan)))


# -- one run -----------------------------------------------------------------------------------------


def _evaluate(problem: Problem, x: np.ndarray) -> tuple[np.ndarray, int]:
    g, steps = problem.evaluate(x)
    return np.asarray(g, dtype=float), int(np.sum(steps))


def _start(problem: Problem, settings: Settings, seed: Seed, run: int) -> _State:
    x = _rng(seed, run, 0, 0).standard_normal((settings.n, problem.dimension))
    g, steps = _evaluate(problem, x)
    return _State(0, x, g, (None, None, settings.n, steps), settings.initial_scale, [])


def run(problem: Problem, settings: Settings = Settings(), *, seed: Seed = 0, run: int = 0,
        checkpoint: Path | None = None, on_stage: Callable[[Stage, float], None] | None = None) -> Run:
    """One subset simulation run (see the module docstring). With ``checkpoint``, the state after
    each stage is saved there, and a run that finds its own checkpoint continues from it. ``on_stage``
    is told each stage this process closes, with the run's CPU seconds so far (a resumed run's earlier
    processes included)."""
    fingerprint = _fingerprint(problem, settings, seed, run)
    path = None if checkpoint is None else Path(checkpoint)
    clock = time.process_time()
    state = _load(path, fingerprint) if path is not None and path.is_file() else _start(problem, settings, seed, run)
    chains = settings.chains
    while True:
        state.cpu_s += time.process_time() - clock  # the work this process did since the state it came from
        clock = time.process_time()
        if path is not None:
            _save(path, fingerprint, state)
        g = state.g
        order = np.argsort(g, kind="stable")
        threshold = 0.5 * float(g[order[chains - 1]] + g[order[chains]])
        last = threshold <= settings.failure_level
        level = settings.failure_level if last else threshold
        hits = g <= level
        share = float(hits.mean())
        gamma = gamma_factor(hits.reshape(chains, -1), share) if state.stage else 0.0
        state.stages.append(Stage(level, share, gamma, *state.made))
        if on_stage is not None:
            on_stage(state.stages[-1], state.cpu_s)
        if last or state.stage >= settings.max_stages:
            break
        stage = state.stage + 1
        perm = _rng(seed, run, stage, 0).permutation(chains)  # [PBS15]: the groups get seeds in random order
        seeds = order[:chains][perm]
        xs, gs, rate, scale, spent = _chains(problem, state.x[seeds], g[seeds], level, state.scale, settings,
                                             (seed, run, stage))
        state = _State(stage, xs.reshape(settings.n, -1), gs.reshape(settings.n),
                       (rate, state.scale, settings.n - chains, spent), scale, state.stages, state.cpu_s)
    return _finish(state, settings, capped=not last)


def _finish(state: _State, settings: Settings, capped: bool) -> Run:
    stages = state.stages
    shares = np.array([s.share for s in stages])
    estimate = math.nan if capped else float(np.prod(shares))
    terms = [(1 - s.share) / (settings.n * s.share) * (1 + s.gamma) for s in stages if s.share > 0]
    cov = math.sqrt(sum(terms)) if shares[-1] > 0 else math.inf
    fail = state.g <= settings.failure_level
    return Run(estimate, cov, tuple(stages), sum(s.evaluations for s in stages), sum(s.steps for s in stages),
               capped, state.x[fail], state.g[fail], state.cpu_s)


# -- independent runs and their interval -------------------------------------------------------------


@dataclass(frozen=True)
class Estimate:
    """The mean of independent runs with its Student t interval (asymptotic), the mean within-run
    coefficient of variation beside it, the cost, and crude Monte Carlo's steps for the same width."""

    estimate: float
    low: float
    high: float
    level: float
    relative_halfwidth: float
    runs: tuple[float, ...]
    within_run_cov: float  # the mean run's [AB01] CoV, divided by sqrt(runs): the mean's CoV by that estimate
    evaluations: int
    steps: int
    crude_steps: float  # crude Monte Carlo's control steps for the same relative half-width at this estimate
    interval: str = "asymptotic: Student t on independent subset simulation runs"
    warnings: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def contains(self, p: float) -> bool:
        return bool(self.low <= p <= self.high)

    @property
    def factor(self) -> float:
        """Crude Monte Carlo's control steps over this estimate's, for the same relative half-width."""
        return self.crude_steps / self.steps if self.steps else math.nan


#: Below this estimate a t interval wants at least RARE_RUNS runs: at p = 1e-6 on the surrogate a run that keeps a
#: route the intermediate levels nearly lose reads several times p and most runs read under it, so 10 runs per
#: interval covered 82 %, 20 runs 88 % and 30 runs 92 % (docs/decisions.md, "Subset simulation on the surrogate").
RARE_ESTIMATE = 1e-5
RARE_RUNS = 30


def from_runs(runs: list[Run], crude_episode_steps: float, level: float = 0.95) -> Estimate:
    """The t interval of independent runs (capped runs left out, with a warning; a warning too where the
    estimate is below RARE_ESTIMATE from fewer than RARE_RUNS runs)."""
    values = np.array([r.estimate for r in runs], dtype=float)
    kept = values[~np.isnan(values)]
    warnings = []
    if kept.size < values.size:
        warnings.append(f"{values.size - kept.size} of {values.size} runs reached max_stages and are left out")
    evaluations, steps = sum(r.evaluations for r in runs), sum(r.steps for r in runs)
    if kept.size < 2:
        return Estimate(math.nan, math.nan, math.nan, level, math.nan, tuple(values.tolist()), math.nan, evaluations,
                        steps, math.nan, warnings=(*warnings, "an interval needs at least 2 finished runs"))
    mean = float(kept.mean())
    half = float(sps.t.ppf(0.5 + level / 2, kept.size - 1)) * float(kept.std(ddof=1)) / math.sqrt(kept.size)
    rel = half / mean if mean > 0 else math.inf
    if np.sum(kept == 0) > 0:
        warnings.append(f"{int(np.sum(kept == 0))} runs found no failing sample: the interval is unreliable")
    if mean < RARE_ESTIMATE and kept.size < RARE_RUNS:
        warnings.append(f"an estimate below {RARE_ESTIMATE:g} from {kept.size} runs: the t interval may read low "
                        "(the runs' estimates are skewed there: on the surrogate at 1e-6, 10 runs covered 82 %, 30 "
                        f"runs 92 %), use --replicates {RARE_RUNS} or more")
    within = float(np.mean([r.cov for r in runs if not r.capped])) / math.sqrt(kept.size)
    crude = intervals.crude_steps_for(mean, rel, crude_episode_steps, level)
    return Estimate(mean, max(0.0, mean - half), mean + half, level, rel, tuple(values.tolist()), within,
                    evaluations, steps, crude, warnings=tuple(warnings))


def estimate(problem: Problem, settings: Settings = Settings(), *, runs: int = 10, seed: Seed = 0,
             crude_episode_steps: float | None = None, level: float = 0.95,
             checkpoint_dir: Path | None = None) -> Estimate:
    """``runs`` independent runs (run ids 0 .. runs - 1 under ``seed``) and their t interval.
    crude_episode_steps: the control steps of one crude Monte Carlo episode, for the comparison (default:
    the problem's ``mean_steps()`` where it has one, else NaN). checkpoint_dir: run r keeps its
    checkpoint in run-r.npz there (four digits), so a killed estimate resumes by the same call."""
    if runs < 2:
        raise ValueError(f"an interval needs at least 2 runs, got {runs}")
    done = [run(problem, settings, seed=seed, run=r,
                checkpoint=None if checkpoint_dir is None else Path(checkpoint_dir) / f"run-{r:04d}.npz")
            for r in range(runs)]
    if crude_episode_steps is None:
        mean_steps = getattr(problem, "mean_steps", None)
        crude_episode_steps = float(mean_steps()) if mean_steps else math.nan
    return from_runs(done, crude_episode_steps, level)
