"""How far random schedules are from T3's counterexamples: a bound on their median cost, from a benchmark folder.

    python studies/t3-ellipse-graze/random_schedule_rate.py OUT [--target adversary_t3_beam]

OUT is the ``--out-dir`` of ``python -m benchmarks.falsify CAMPAIGN --methods beam,random-schedules``. A
random-schedules trial is the beam with branching 1: every restart runs ``width`` schedules, each an independent
draw of per-step signs through the window (its own key), judged by its episode's row. So the schedules of all
trials are n independent Bernoulli draws of one per-schedule violation rate q, and a trial's number of
schedules to its first counterexample is geometric in q. With k violations in n judged schedules (the bound is
exact when k = 0: the trials then ran to their budgets, so n was fixed in advance):

- q_u, the exact one-sided 95 % upper bound on q (Clopper-Pearson);
- m, the median of the geometric number of schedules to the first counterexample at q_u (ceil(ln 2 / -ln(1 -
  q_u))); at any q <= q_u the median is at least m, so m is a 95 % lower confidence bound on random schedules'
  median;
- in control steps: a search that reaches its m-th schedule has run at least floor((m - 1) / width) whole
  restarts, each costing at least the cheapest restart seen, which gives a lower bound in episode-equivalents.

It prints that bound beside the beam's median episode-equivalents to its first counterexample (over its trials,
a failed one counted as beyond the budget), the quantity issue 49's T3 goal compares ("median at most a tenth of
random's").
"""

from __future__ import annotations

import argparse
import math
import statistics
from pathlib import Path

from mcverify.analysis.intervals import one_sided_upper
from mcverify.falsify import beam_folder


def random_schedules(folder: Path) -> tuple[int, int, int, int, int]:
    """(judged schedules, violations, width, the cheapest restart's control steps, trials) over the trials."""
    trials = sorted(folder.glob("trial-[0-9][0-9]"))
    restarts = [r for trial in trials for r in beam_folder.read_summary(trial).restarts]
    n = sum(len(r.frontier) for r in restarts)
    k = sum(node.robustness < 0.0 for r in restarts for node in r.frontier)
    width = max(len(r.frontier) for r in restarts)
    # a restart cut short (by the budget, or at a counterexample) is not a whole restart's cost
    cheapest = min(r.search_steps for r in restarts if len(r.frontier) == width)
    return n, k, width, cheapest, len(trials)


def beam_median(folder: Path) -> tuple[float, int, int]:
    """(median episode-equivalents to the first counterexample, failed trials counted as inf; successes; trials),
    each trial's cost read as benchmarks.falsify reads it (the whole search's, when it found one)."""
    summaries = [beam_folder.read_summary(trial) for trial in sorted(folder.glob("trial-[0-9][0-9]"))]
    costs = [s.episode_equivalents if s.best_robustness < 0.0 else math.inf for s in summaries]
    return statistics.median(costs), sum(math.isfinite(c) for c in costs), len(costs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the benchmark's --out-dir")
    parser.add_argument("--target", default="adversary_t3_beam", help="the campaign's name (a folder of OUT)")
    args = parser.parse_args()
    root = args.out / args.target
    n, k, width, cheapest, trials = random_schedules(root / "random-schedules")
    q_u = one_sided_upper(k, n)
    m = math.ceil(math.log(2.0) / -math.log1p(-q_u))
    steps = beam_folder.read_summary(next((root / "random-schedules").glob("trial-[0-9][0-9]"))).full_episode_steps
    floor_ep_eq = (m - 1) // width * cheapest / steps
    median, found, beam_trials = beam_median(root / "beam")
    print(f"random schedules: {k} violations in {n} judged schedules over {trials} trials ({width} per restart)")
    print(f"  per-schedule violation rate <= {q_u:.3g} (exact one-sided 95 %)")
    print(f"  median schedules to the first counterexample >= {m} (95 % lower confidence bound)")
    print(f"  median cost to it >= {floor_ep_eq:.3g} episode-equivalents ({(m - 1) // width} whole restarts of at "
          f"least {cheapest} control steps, {steps} per episode)")
    print(f"beam: {found} of {beam_trials} trials falsified, median {median:.3g} episode-equivalents to the first")
    if math.isfinite(median):
        print(f"  the beam's median is {median / floor_ep_eq:.3g} of random schedules' lower bound"
              f" ({'at most' if median <= floor_ep_eq / 10 else 'more than'} a tenth)")


if __name__ == "__main__":
    main()
