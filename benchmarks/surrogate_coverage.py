"""Coverage of subset simulation on the structure-matched surrogate with exact p (issue 50):
``python -m benchmarks.surrogate_coverage [--reps R] [--runs K] [--rare-runs K] [--n N] [--n-rare N] [--quick]``.

For each clock of the surrogate (:mod:`mcverify.estimate.surrogate`: "time", the noise keyed to control
steps as the closed loop draws it today, and "decision", keyed to the decision instant) and each p,
``reps`` independent repetitions, each the Student t interval of ``runs`` independent subset simulation
runs of N samples per stage (``--n`` and ``--runs`` at p = 1e-3 and 1e-4, ``--n-rare`` and ``--rare-runs``
at 1e-6: the rarest cell needs more samples per stage to carry the routes that are rare at the intermediate
levels, and more runs because a run that keeps such a route reads several times p while most read under it,
see docs/decisions.md): coverage of the exact p (with its Clopper-Pearson interval), the mean's relative
bias, the mean relative error, the mean relative half-width, control steps per repetition, crude Monte
Carlo's steps for the same relative half-width at the exact p, and their ratio. Beside it: openturns'
SubsetSampling at the same N and p0 (fewer repetitions: it is slower), and the routes of the failing
samples against the exact route shares (where subset simulation loses a route, this says which). Writes
only its own section of results/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

from benchmarks import section
from mcverify.analysis import intervals
from mcverify.errors import UserError
from mcverify.estimate import splitting, subset
from mcverify.estimate.surrogate import SplittingProcess, Surrogate

NAME = "surrogate_coverage"
ROUTES = ("jump", "sustained", "away_then_towards")


@dataclass(frozen=True)
class Row:
    """One (method, clock, p) cell of the coverage table."""

    method: str
    clock: str
    p: float
    reps: int
    runs: int
    n: int
    coverage: float
    coverage_low: float  # 95 % Clopper-Pearson interval of the coverage over the repetitions
    coverage_high: float
    bias: float  # mean of the repetitions' estimates over p, minus 1
    mean_relative_error: float  # mean |estimate - p| / p
    relative_halfwidth: float  # mean over repetitions of the upper half-width (high - estimate) over the exact p
    steps: float  # control steps per repetition
    crude_steps: float  # crude Monte Carlo's steps for the same relative half-width at the exact p
    seconds: float

    @property
    def factor(self) -> float:
        return self.crude_steps / self.steps


def _row(method: str, clock: str, problem: Surrogate, estimates: list[subset.Estimate], runs: int, n: int,
         seconds: float) -> Row:
    p = problem.exact_p()
    values = np.array([e.estimate for e in estimates])
    covered = int(sum(e.contains(p) for e in estimates))
    low, high = _clopper_pearson(covered, len(estimates))
    # relative to the exact p, not to each estimate: a repetition that estimates 0 (extinct splitting runs)
    # would otherwise make the mean infinite; the upper half, since the low end is clipped at 0
    rel = float(np.nanmean([(e.high - e.estimate) / p for e in estimates]))
    steps = float(np.mean([e.steps for e in estimates]))
    return Row(method, clock, p, len(estimates), runs, n, covered / len(estimates), low, high,
               float(np.nanmean(values) / p - 1.0), float(np.nanmean(np.abs(values - p)) / p), rel, steps,
               intervals.crude_steps_for(p, rel, problem.mean_steps()), seconds)


def _clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact binomial interval of k successes in n trials."""
    alpha = 1.0 - level
    low = float(sps.beta.ppf(alpha / 2, k, n - k + 1)) if k > 0 else 0.0
    high = float(sps.beta.ppf(1 - alpha / 2, k + 1, n - k)) if k < n else 1.0
    return low, high


def subset_row(clock: str, p: float, settings: subset.Settings, reps: int, runs: int) -> tuple[Row, np.ndarray]:
    """Coverage of our subset simulation, and the failing samples' route counts (summed over runs)."""
    problem = Surrogate.at(p, clock=clock)
    start = time.process_time()
    estimates, counts = [], np.zeros(len(ROUTES))
    for rep in range(reps):
        done = [subset.run(problem, settings, seed=rep, run=r) for r in range(runs)]
        estimates.append(subset.from_runs(done, problem.mean_steps()))
        for r in done:
            if r.failing.size:
                counts += problem.routes(r.failing).sum(axis=0)
    return _row("subset (pCN)", clock, problem, estimates, runs, settings.n, time.process_time() - start), counts


def openturns_row(clock: str, p: float, n: int, p0: float, reps: int, runs: int) -> Row | None:
    """The same coverage study with openturns' SubsetSampling (None where openturns is not installed)."""
    try:
        import openturns as ot
    except ImportError:
        return None
    problem = Surrogate.at(p, clock=clock)
    spent = {"steps": 0}

    def g(sample):
        values, steps = problem.evaluate(np.asarray(sample))
        spent["steps"] += int(np.sum(steps))
        return values[:, None]

    model = ot.PythonFunction(problem.dimension, 1, func_sample=g)
    vector = ot.CompositeRandomVector(model, ot.RandomVector(ot.Normal(problem.dimension)))
    event = ot.ThresholdEvent(vector, ot.LessOrEqual(), 0.0)
    start = time.process_time()
    estimates, raised = [], 0
    for rep in range(reps):
        values, before = [], spent["steps"]
        for r in range(runs):
            ot.RandomGenerator.SetSeed(rep * runs + r)
            algo = ot.SubsetSampling(event)
            algo.setMaximumOuterSampling(1)
            algo.setBlockSize(n)  # one batch of n per stage: n samples per stage, as ours
            algo.setConditionalProbability(p0)
            try:
                algo.run()
                values.append(algo.getResult().getProbabilityEstimate())
            except (TypeError, RuntimeError):  # openturns raises on some runs (a negative variance estimate)
                raised += 1
        estimates.append(_t_estimate(np.array(values), spent["steps"] - before))
    note = f"; {raised} of {reps * runs} runs raised and are left out" if raised else ""
    return _row(f"openturns {ot.__version__} SubsetSampling{note}", clock, problem, estimates, runs, n,
                time.process_time() - start)


def splitting_row(clock: str, p: float, n: int, replicates: int, reps: int) -> Row:
    """The same study with adaptive multilevel splitting (:mod:`mcverify.estimate.splitting`, k = 1) on
    the surrogate as a time-restart branching process: ``replicates`` AMS runs of ``n`` particles per
    interval, as the closed loop runs it."""
    problem = Surrogate.at(p, clock=clock)
    start = time.process_time()
    estimates = []
    for rep in range(reps):
        est = splitting.estimate(SplittingProcess(problem, seed=rep), n=n, failure_level=0.0, replicates=replicates,
                                 seed=rep)
        estimates.append(subset.Estimate(est.estimate, est.low, est.high, est.level, est.relative_halfwidth,
                                         tuple(est.runs), math.nan, 0, est.steps, math.nan))
    return _row(f"AMS splitting (k = 1, {n} particles)", clock, problem, estimates, replicates, n,
                time.process_time() - start)


def _t_estimate(values: np.ndarray, steps: int, level: float = 0.95) -> subset.Estimate:
    mean = float(values.mean())
    half = float(sps.t.ppf(0.5 + level / 2, values.size - 1)) * float(values.std(ddof=1)) / math.sqrt(values.size)
    return subset.Estimate(mean, max(0.0, mean - half), mean + half, level, half / mean if mean > 0 else math.inf,
                           tuple(values.tolist()), math.nan, 0, steps, math.nan)


def render(rows: list[Row], routes: dict[tuple[str, float], np.ndarray], command: str, settings: subset.Settings,
           seconds: float) -> str:
    lines = ["## Rare-event estimators on the structure-matched surrogate (exact p)", "",
             f"{section.provenance_line(command)[:-1]} ({seconds:.0f} CPU-s). Surrogate: "
             f"{Surrogate().dimension} standard-normal inputs (2 scenario units, "
             f"{Surrogate().horizon_steps} per-step noise units), event decided at the decision instant by 1-3 draws "
             "over three routes (jump, sustained offset, away then towards: 40/35/25 % of p), robustness graded in "
             f"units of the noise bound. Subset simulation: N per stage as in the table, p0 = {settings.p0}, "
             f"pCN moves adapted towards acceptance {settings.target_acceptance}; each repetition is the "
             "95 % Student t interval of independent runs; rel. half-width r: the mean of (high - estimate) / p. "
             "Crude steps: z^2 (1 - p) / (p r^2) episodes of the surrogate's mean episode (the steps to the decision, "
             "its draws and the depth). Bias of mean: the mean of the repetitions' estimates over p, minus 1.", "",
             "| method | clock | p | reps x runs | N | coverage (95 % CI) | bias of mean | mean rel. error "
             "| rel. half-width | control steps / rep | crude steps, same width | factor | CPU-s |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r.method} | {r.clock} | {r.p:.0e} | {r.reps} x {r.runs} | {r.n} | {r.coverage:.0%} "
                     f"({r.coverage_low:.0%}-{r.coverage_high:.0%}) | "
                     f"{r.bias:+.0%} | {r.mean_relative_error:.0%} | {r.relative_halfwidth:.0%} | {r.steps:.3g} | "
                     f"{r.crude_steps:.3g} | {r.factor:.3g}x | {r.seconds:.0f} |")
    lines += ["", "Routes of the failing samples of the last stage (all runs pooled) against each route's exact share "
              "of p (routes overlap a little):", "", "| clock | p | jump | sustained | away then towards |",
              "| --- | --- | --- | --- | --- |"]
    for (clock, p), counts in routes.items():
        exact = Surrogate.at(p, clock=clock).route_probabilities()
        share = counts / max(1.0, counts.sum())
        cells = " | ".join(f"{s:.0%} (exact {exact[name] / sum(exact.values()):.0%})"
                           for s, name in zip(share, ROUTES, strict=True))
        lines.append(f"| {clock} | {p:.0e} | {cells} |")
    return section.wrap(NAME, "\n".join(lines))


def _parse(argv: list[str] | None) -> argparse.Namespace:
    parser = section.parser(NAME, __doc__.split("\n")[0])
    parser.add_argument("--reps", type=int, default=100, help="independent repetitions per cell (default 100)")
    parser.add_argument("--time-reps", type=int, default=None,
                        help="repetitions under the time clock (default: --reps)")
    parser.add_argument("--split-reps", type=int, default=30,
                        help="AMS splitting repetitions at p = 1e-4, time clock (default 30; 0: none)")
    parser.add_argument("--runs", type=int, default=10,
                        help="subset simulation runs per interval at p = 1e-3 and 1e-4 (default 10)")
    parser.add_argument("--rare-runs", type=int, default=subset.RARE_RUNS,
                        help=f"subset simulation runs per interval at p = 1e-6 (default {subset.RARE_RUNS})")
    parser.add_argument("--n", type=int, default=2000, help="samples per stage at p = 1e-3 and 1e-4 (default 2000)")
    parser.add_argument("--n-rare", type=int, default=20000, help="samples per stage at p = 1e-6 (default 20000)")
    parser.add_argument("--rare-reps", type=int, default=None,
                        help="repetitions at p = 1e-6 under the decision clock (default: --reps)")
    parser.add_argument("--ot-reps", type=int, default=10, help="openturns repetitions at p = 1e-4 (default 10)")
    parser.add_argument("--quick", action="store_true", help="3 repetitions of 3 runs, no openturns (a smoke run)")
    section.add_output_options(parser)
    args = parser.parse_args(argv)
    if args.quick:
        args.reps, args.runs, args.rare_runs, args.ot_reps, args.split_reps = 3, 3, 3, 0, 0
        args.n, args.n_rare = 500, 500
    args.time_reps = args.reps if args.time_reps is None else args.time_reps
    args.rare_reps = args.reps if args.rare_reps is None or args.quick else args.rare_reps
    if (min(args.reps, args.time_reps, args.rare_reps) < 1 or min(args.runs, args.rare_runs) < 2
            or min(args.n, args.n_rare) < 20
            or min(args.ot_reps, args.split_reps) < 0):
        raise UserError("need --reps, --time-reps and --rare-reps >= 1, --runs and --rare-runs >= 2, "
                        "--n and --n-rare >= 20, --ot-reps and --split-reps >= 0")
    return args


def main(argv: list[str] | None = None) -> int:
    return section.run_main(NAME, lambda: _main(argv))


def _main(argv: list[str] | None) -> int:
    args = _parse(argv)
    try:
        settings = subset.Settings(n=args.n)
        rare = subset.Settings(n=args.n_rare)
    except ValueError as err:
        raise UserError(str(err)) from None
    start = time.process_time()
    rows, routes = [], {}
    for clock in ("time", "decision"):
        for p in (1e-3, 1e-4, 1e-6):
            rare_cell = p < subset.RARE_ESTIMATE
            reps = args.time_reps if clock == "time" else args.rare_reps if rare_cell else args.reps
            row, counts = subset_row(clock, p, rare if rare_cell else settings, reps,
                                     args.rare_runs if rare_cell else args.runs)
            rows.append(row)
            routes[(clock, p)] = counts
            print(f"{row.method} {clock} p={p:.0e}: coverage {row.coverage:.0%}, bias {row.bias:+.0%}, "
                  f"rel. half-width {row.relative_halfwidth:.0%}, factor {row.factor:.3g}x ({row.seconds:.0f} s)",
                  flush=True)
        if args.ot_reps:
            ot_row = openturns_row(clock, 1e-4, args.n, settings.p0, args.ot_reps, args.runs)
            if ot_row is not None:
                rows.append(ot_row)
                print(f"{ot_row.method} {clock}: coverage {ot_row.coverage:.0%}, bias {ot_row.bias:+.0%}", flush=True)
        if args.split_reps and clock == "time":
            split_row = splitting_row(clock, 1e-4, 100, args.runs, args.split_reps)
            rows.append(split_row)
            print(f"{split_row.method} {clock}: coverage {split_row.coverage:.0%}, bias {split_row.bias:+.0%}",
                  flush=True)
    text = render(rows, routes, section.command(NAME, argv), settings, time.process_time() - start)
    section.publish(NAME, text, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
