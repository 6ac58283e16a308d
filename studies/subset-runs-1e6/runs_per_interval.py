"""How many subset simulation runs a Student t interval needs at p = 1e-6 on the surrogate (decision clock).

    python studies/subset-runs-1e6/runs_per_interval.py --first-rep 0 --reps 50 --out a.npz   # 42 CPU-min
    python studies/subset-runs-1e6/runs_per_interval.py --first-rep 50 --reps 50 --out b.npz
    python studies/subset-runs-1e6/runs_per_interval.py --coverage a.npz b.npz

Repetition r holds runs 0 .. R-1 under seed r: the same runs that ``benchmarks.surrogate_coverage`` draws (its
repetition r is runs 0 .. K-1 under seed r), so the first K columns of a repetition are the benchmark's interval
of K runs. Each run's estimate is kept (a file is rewritten after every repetition); ``--coverage`` reads the
files and gives the t interval's coverage of the exact p for 10, 20, ... runs per interval.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import stats

from mcverify.analysis.intervals import clopper_pearson_arrays
from mcverify.estimate import subset
from mcverify.estimate.surrogate import Surrogate


def collect(first_rep: int, reps: int, runs: int, n: int, out: str) -> None:
    problem = Surrogate.at(1e-6, clock="decision")
    settings = subset.Settings(n=n)
    est = np.full((reps, runs), np.nan)
    start = time.process_time()
    for i, rep in enumerate(range(first_rep, first_rep + reps)):
        est[i] = [subset.run(problem, settings, seed=rep, run=r).estimate for r in range(runs)]
        np.savez(out, est=est[: i + 1], p=problem.exact_p(), first_rep=first_rep)
        print(f"repetition {rep}: mean {est[i].mean() / problem.exact_p():.3f} p "
              f"({time.process_time() - start:.0f} CPU-s)", flush=True)


def coverage(paths: list[str]) -> None:
    loaded = [np.load(path) for path in paths]
    values = np.vstack([f["est"] / f["p"] for f in loaded])
    print(f"{values.shape[0]} repetitions of {values.shape[1]} runs; run estimates over p: median "
          f"{np.median(values):.2f}, share over 2 p {np.mean(values > 2):.0%}")
    for k in range(10, values.shape[1] + 1, 10):
        x = values[:, :k]
        mean, half = x.mean(1), stats.t.ppf(0.975, k - 1) * x.std(1, ddof=1) / np.sqrt(k)
        hit = int(np.sum((mean - half <= 1) & (1 <= mean + half)))
        m = len(mean)
        low, high = (float(v) for v in clopper_pearson_arrays(hit, m))
        print(f"{k} runs: coverage {hit}/{m} = {hit / m:.0%} ({low:.0%}-{high:.0%}), intervals below p "
              f"{int(np.sum(mean + half < 1))}, mean upper half-width {np.mean(half):.2f} p, "
              f"bias {mean.mean() - 1:+.1%}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--first-rep", type=int, default=0)
    parser.add_argument("--reps", type=int, default=100)
    parser.add_argument("--runs", type=int, default=30)
    parser.add_argument("--n", type=int, default=20000, help="samples per stage (the benchmark's --n-rare)")
    parser.add_argument("--out", default="runs.npz")
    parser.add_argument("--coverage", nargs="+", metavar="FILE", help="only read these files and print coverage")
    args = parser.parse_args()
    if args.coverage:
        coverage(args.coverage)
    else:
        collect(args.first_rep, args.reps, args.runs, args.n, args.out)


if __name__ == "__main__":
    main()
