"""``python -m benchmarks.validation``: the rare-event estimators checked against a crude Monte Carlo
reference on the closed loop, where crude Monte Carlo can answer (p about 0.01-0.05).

Inputs, all of one cell and one target event:

- the **reference** (:mod:`benchmarks.validation_reference`): crude Monte Carlo folders of one cell, finished
  or stopped: estimate folders (``mcverify estimate --method mc``, whose target it is) or run folders
  (``mcverify run``, with ``--target``). Each folder's gap-free prefix of episodes, in their pre-assigned order,
  and the folders one after another (distinct seeds: independent episodes) give k events in n episodes; n was
  set by the clock or the budget, not by the outcomes, so its interval is the fixed-n Clopper-Pearson one;
- **splitting** folders (``mcverify estimate --method splitting``, distinct seeds, one setting of
  particles and score per pool; several pools give several rows): a pool's AMS runs are pooled
  (folders in the order given, runs in replicate order) and cut into consecutive repetitions of
  ``group`` runs. Each repetition is exactly the estimate ``--replicates group`` would return (the
  mean of independent unbiased runs with its Student t interval), so the pool gives many independent
  repetitions of that estimator;
- **subset** folders (``mcverify estimate --method subset``, distinct seeds, one setting of samples per
  stage and performance function per pool): pooled and cut into repetitions of ``group`` runs as splitting's
  are, each exactly the estimate ``--replicates group`` would return (the t interval on the runs); with
  ``--group 1`` each run alone is a repetition, with the interval of its within-run coefficient of variation
  (the value the estimate reports beside its t interval), so R runs check that interval R times;
- **importance** folders (``mcverify estimate --method importance``, distinct seeds): one estimate each;
- **crude Monte Carlo with sequential stopping** (``--sequential H``): the reference's own episodes,
  in their pre-assigned order, cut into consecutive runs of ``mcverify estimate --method mc
  --until-halfwidth H``: each run walks the next episodes until its anytime-valid interval is H wide
  (half-width) and stops; the next run starts at the following episode; an unfinished last run is
  dropped. The runs use disjoint sets of i.i.d. episodes, so they are independent repetitions, and
  each is checked against the reference *without its own episodes* (leave-out), which is independent
  of it.

Reported per estimator: repetitions, coverage of the reference's p by the intervals, bias and relative
error (standard deviation over p) of the estimates, mean relative half-width, cost in control steps and
CPU per repetition, and the control steps crude Monte Carlo would need for the same relative half-width.
The reference has its own error: coverage is also given as if p were at either end of the reference's
interval, so a reader sees how much of a shortfall the reference alone could explain.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.stats as sps

from benchmarks import section
from benchmarks.validation_reference import Reference, as_dirs, manifest_of, reference_of, reference_sequence
from benchmarks.validation_report import figure, markdown
from mcverify import files, provenance, store
from mcverify.analysis import intervals
from mcverify.analysis.estimates import TARGETS
from mcverify.analysis.intervals import proportion_interval
from mcverify.analysis.sequential import StopRule, sequential_estimate
from mcverify.cli import options
from mcverify.errors import RunError
from mcverify.estimate import splitting, subset_run
from mcverify.estimate.folder import ESTIMATE
from mcverify.reporting.compare import flat_params
from mcverify.requirements import PERFORMANCES


@dataclass
class Repetition:
    """One estimate: value, interval, and its cost (control steps, CPU seconds)."""

    estimate: float
    low: float
    high: float
    steps: float
    cpu_s: float
    warnings: list[str] = field(default_factory=list)
    #: the reference p this repetition is checked against, when not the whole reference's (leave-out)
    reference_p: float | None = None
    #: importance sampling: its anytime-valid lower bound, failing samples and their effective sample size
    anytime_lower: float = math.nan
    failures: int = -1
    ess: float = math.nan


def sequential_repetitions(events: np.ndarray, steps: np.ndarray, halfwidth: float, relative: bool = False,
                           level: float = 0.95) -> list[Repetition]:
    """Consecutive runs of ``mcverify estimate --method mc --until-halfwidth`` over the ordered
    reference ``events`` (see the module docstring), each stopped when its anytime-valid interval's
    half-width is <= ``halfwidth`` (of the estimate when ``relative``). Each repetition carries the
    leave-out reference p: the reference without the run's own episodes."""
    events = np.asarray(events, dtype=bool)
    total_k, total_n = int(events.sum()), int(events.size)
    stop = StopRule(halfwidth, relative)
    reps, start = [], 0
    while start < total_n:
        found = _first_stop(events[start:], stop, level)
        if found is None:
            break  # the last run did not finish: dropped
        n, est, low, high = found
        used = slice(start, start + n)
        k_out, n_out = total_k - int(events[used].sum()), total_n - n
        reps.append(Repetition(est, low, high, float(steps[used].sum()), math.nan,
                               reference_p=k_out / n_out if n_out else math.nan))
        start += n
    return reps


def _first_stop(rest: np.ndarray, stop: StopRule, level: float) -> tuple[int, float, float, float] | None:
    """(n, estimate, low, high) where a sequential run over ``rest`` stops, or None if it does not.
    Looks at growing windows (256, 512, ...) so that cutting a long sequence costs what the runs use."""
    window = 256
    while True:
        res = sequential_estimate(rest[:window], stop, level)
        if res.status == "halfwidth":
            return res.n, res.estimate, res.low, res.high
        if window >= rest.size:
            return None
        window *= 2


def _estimate_folder(run_dir: Path, method: str, ref: Reference) -> tuple[dict[str, Any], dict[str, Any]]:
    """(manifest, the one cell's result) of an estimate folder, checked against the reference."""
    manifest = manifest_of(run_dir)
    spec = manifest.get("estimate") or {}
    if spec.get("method") != method:
        raise RunError(f"{run_dir} is not a {method} estimate")
    path = Path(run_dir) / ESTIMATE
    cells = store.read_json(path)["cells"] if path.exists() else []
    mine = [c for c in cells if c["cell"] == ref.cell]
    if not mine:
        raise RunError(f"{run_dir} has no finished result for cell {ref.cell!r} (resume it first)")
    target = mine[0].get("target", spec.get("target"))
    if manifest["campaign"]["name"] != ref.campaign or target != ref.target:
        raise RunError(f"{run_dir} estimates {target!r} of {manifest['campaign']['name']!r}; the "
                       f"reference is {ref.target!r} of {ref.campaign!r}")
    return manifest, mine[0]


def _check_seeds(manifests: Sequence[dict[str, Any]], dirs: Sequence[Path], ref: Reference) -> None:
    """The estimator folders must be independent of each other and of the reference (distinct campaign
    seeds: an estimator run with the reference's seed re-simulates its episodes), and estimate the
    reference's cell: every model field both manifests have must agree (a field only one has was
    added later, and new fields default to the earlier behaviour)."""
    seen: dict[int, Path] = {}
    for manifest, d in zip(manifests, dirs, strict=True):
        seed = int(manifest["campaign"]["seed"])
        if seed in ref.seeds:
            raise RunError(f"{d} has the reference's seed {seed}: its episodes replay the reference's, so it is "
                           "not an independent check; run the estimator with another --seed")
        if seed in seen:
            raise RunError(f"{d} and {seen[seed]} have the same seed {seed}: their runs are not independent")
        seen[seed] = d
        cells = [c for c in manifest["cells"] if c["name"] == ref.cell]
        mine = flat_params(cells[0].get("params", {})) if cells else {}
        differ = sorted(k for k in set(mine) & set(ref.params) if mine[k] != ref.params[k])
        if differ:
            shown = ", ".join(f"{k} = {mine[k]!r} (reference {ref.params[k]!r})" for k in differ[:3])
            raise RunError(f"{d} estimates another model than the reference: {shown}")


#: The replicated estimators whose runs are pooled, and the settings every folder of one pool must share.
POOLED_SETTINGS = {"splitting": ("particles", "score"), "subset": ("samples", "performance")}


def _pool_settings(method: str, spec: dict[str, Any]) -> tuple[Any, ...]:
    if method == "splitting":
        return int(spec["particles"]), str(spec.get("score"))
    return int(spec["samples"]), str(spec.get("performance") or PERFORMANCES[0])  # older folders: the robustness


def pooled_runs(dirs: Sequence[Path], ref: Reference, method: str = "splitting"
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """(estimate, control steps, CPU seconds) of every run of the ``method`` folders ``dirs`` (splitting's AMS
    runs or subset simulation's runs; folders in the order given, runs in replicate order; a folder's cost is
    split evenly over its runs) and the runs' settings (:data:`POOLED_SETTINGS`), the same in every folder."""
    values, steps, cpu, manifests, settings = [], [], [], [], set()
    for d in dirs:
        manifest, cell = _estimate_folder(d, method, ref)
        manifests.append(manifest)
        runs = [math.nan if v is None else v for v in cell["runs"]]
        values.extend(runs)
        steps.extend([cell["steps"] / len(runs)] * len(runs))
        cpu.extend([cell["cpu_s"] / len(runs)] * len(runs))
        settings.add(_pool_settings(method, store.read_json(Path(d) / ESTIMATE)["spec"]))
    _check_seeds(manifests, dirs, ref)
    names = POOLED_SETTINGS[method]
    if len(settings) != 1:
        raise RunError(f"the {method} folders differ in ({', '.join(names)}): {sorted(settings)}; pool one at a time")
    return (np.asarray(values, float), np.asarray(steps, float), np.asarray(cpu, float),
            dict(zip(names, settings.pop(), strict=True)))


def pooled_repetitions(dirs: Sequence[Path], ref: Reference, group: int, level: float = 0.95,
                       method: str = "splitting") -> list[Repetition]:
    """The pooled runs of ``dirs`` cut into consecutive repetitions of ``group`` runs (a short remainder is
    dropped), each with the Student t interval on its runs (:func:`splitting.t_interval`, the interval
    ``mcverify estimate --replicates group`` reports for splitting and subset simulation alike); ``group`` 1:
    :func:`within_run_repetitions`."""
    if group == 1:
        return within_run_repetitions(dirs, ref, level, method)
    values, steps, cpu, _ = pooled_runs(dirs, ref, method)
    if values.size < group:
        raise RunError(f"--group {group} (runs per repetition; 4 unless given) is more than the {values.size} runs "
                       f"the {method} folders hold: give more folders or a smaller --group")
    reps = []
    for start in range(0, values.size - group + 1, group):
        part = slice(start, start + group)
        mean, low, high, _, warnings = splitting.t_interval(values[part], level)
        reps.append(Repetition(mean, low, high, float(steps[part].sum()), float(cpu[part].sum()),
                               warnings if method == "splitting" else []))
    return reps


def within_run_repetitions(dirs: Sequence[Path], ref: Reference, level: float = 0.95,
                           method: str = "subset") -> list[Repetition]:
    """Every subset simulation run alone, with the interval of its own within-run coefficient of variation
    delta ([AB01], the chains' correlation included: the value ``mcverify estimate`` reports beside the t
    interval): estimate x (1 -+ z delta), the low end clipped at 0 (``--group 1``). One run per repetition, so
    a pool of R runs gives R repetitions of it."""
    if method != "subset":
        raise RunError(f"--group 1 (each run with its within-run interval) is subset simulation's; {method} runs "
                       "have no within-run error: give --group 2 or more")
    values, steps, cpu, _ = pooled_runs(dirs, ref, method)
    covs = np.array([cov for d in dirs for cov in _run_covs(d, ref)], float)
    z = float(sps.norm.ppf(0.5 + level / 2))
    return [Repetition(float(v), max(0.0, float(v) * (1 - z * c)), float(v) * (1 + z * c), float(s), float(t),
                       [] if math.isfinite(v) else ["a run that reached max_stages: no estimate"])
            for v, c, s, t in zip(values, covs, steps, cpu, strict=True)]


def _run_covs(run_dir: Path, ref: Reference) -> list[float]:
    """The within-run coefficient of variation of each run of a subset folder's reference cell, in run order
    (inf for a run with none: its interval is the whole half-line)."""
    manifest, cell = _estimate_folder(run_dir, "subset", ref)
    index = next(c["index"] for c in manifest["cells"] if c["name"] == ref.cell)
    stems = (subset_run.run_stem(Path(run_dir), index, run_id) for run_id in range(len(cell["runs"])))
    return [subset_run.as_run(store.read_json(stem.with_suffix(".json"))["run"]).cov for stem in stems]


def pooled_summary(dirs: Sequence[Path], ref: Reference, method: str = "splitting") -> dict[str, Any]:
    """The runs taken one by one: each is unbiased (splitting) or nearly so (subset simulation, a bias of
    order 1/N), so their mean, with its standard error, checks the estimator's bias on this cell without any
    interval; and how many runs estimate 0."""
    values, steps, cpu, settings = pooled_runs(dirs, ref, method)
    ok = np.isfinite(values)  # a run stopped by --max-iterations is no estimate (stored as null)
    capped = int((~ok).sum())
    values, steps, cpu = values[ok], steps[ok], cpu[ok]
    sd = float(values.std(ddof=1)) if values.size > 1 else math.nan
    se = sd / math.sqrt(values.size)
    # Work-normalised relative variance (control steps x relative variance, the cost of a relative
    # variance of 1): one run's against one crude episode's, (1 - p) / p; their ratio is the steps
    # crude Monte Carlo needs per step of splitting for the same width (> 1: splitting is cheaper).
    splitting_work = (sd / ref.p) ** 2 * float(steps.mean())
    crude_work = (1 - ref.p) / ref.p * ref.mean_episode_steps
    return {"method": method, "runs": int(values.size), "capped_runs": capped, **settings, "mean": float(values.mean()),
            "standard_error": se,
            "bias": float(values.mean() / ref.p - 1), "bias_standard_error": se / ref.p,
            "zero_runs": int(np.sum(values == 0)), "steps_per_run": float(steps.mean()),
            "cpu_s_per_run": float(cpu.mean()), "run_relative_sd": sd / ref.p,
            "steps_ratio_vs_crude": crude_work / splitting_work if splitting_work > 0 else math.nan}


def importance_repetitions(dirs: Sequence[Path], ref: Reference) -> list[Repetition]:
    """One repetition per importance folder: its estimate, asymptotic interval and cost."""
    reps, manifests = [], []
    for d in dirs:
        manifest, cell = _estimate_folder(d, "importance", ref)
        manifests.append(manifest)
        reps.append(Repetition(float(cell["estimate"]), float(cell["low"]), float(cell["high"]),
                               float(cell.get("steps", math.nan)), float(cell.get("cpu_s", math.nan)),
                               list(cell.get("warnings", [])), anytime_lower=float(cell.get("anytime_lower", math.nan)),
                               failures=int(cell.get("failures", -1)), ess=float(cell.get("ess", math.nan))))
    _check_seeds(manifests, dirs, ref)
    return reps


def importance_summary(reps: Sequence[Repetition], ref: Reference) -> dict[str, Any]:
    """What importance sampling's own diagnostics said over its repetitions: failing samples and their
    ESS per estimate, and how often the one-sided anytime-valid lower bound held (was at or below p)."""
    lower = np.array([r.anytime_lower for r in reps])
    has_lower = np.isfinite(lower)
    failures = np.array([r.failures for r in reps if r.failures >= 0])
    ess = np.array([r.ess for r in reps if math.isfinite(r.ess)])

    def spread(x: np.ndarray) -> list[float]:
        return [float(np.median(x)), float(x.min()), float(x.max())] if x.size else [math.nan] * 3

    return {"repetitions": len(reps), "failures_median_min_max": spread(failures),
            "ess_median_min_max": spread(ess), "with_anytime_lower": int(has_lower.sum()),
            "anytime_lower_held": int(np.sum(lower[has_lower] <= ref.p)),
            "anytime_lower_median": float(np.median(lower[has_lower])) if has_lower.any() else math.nan}


def summarise(reps: Sequence[Repetition], ref: Reference, level: float = 0.95) -> dict[str, Any]:
    """Coverage (of p, and of either end of the reference's interval), bias, relative error, width and
    cost of the repetitions of one estimator."""
    if not reps:
        raise ValueError("no repetition to summarise")
    est = np.array([r.estimate for r in reps])
    low, high = np.array([r.low for r in reps]), np.array([r.high for r in reps])

    def coverage(p: float) -> float:
        return float(np.mean((low <= p) & (p <= high)))

    rel = (high - low) / 2 / np.where(est > 0, est, np.nan)
    mean_rel = float(np.nanmean(rel)) if np.any(est > 0) else math.inf
    steps = float(np.mean([r.steps for r in reps]))
    crude = intervals.crude_steps_for(ref.p, mean_rel, ref.mean_episode_steps, level) if ref.p > 0 else math.nan
    target_p = np.array([ref.p if r.reference_p is None else r.reference_p for r in reps])
    covered = int(np.sum((low <= target_p) & (target_p <= high)))
    return {
        "repetitions": len(reps), "covered": covered,
        "coverage": covered / len(reps), "coverage_interval": _interval(covered, len(reps), level),
        "coverage_at_reference_low": coverage(ref.low), "coverage_at_reference_high": coverage(ref.high),
        "mean_estimate": float(est.mean()), "bias": float(est.mean() / ref.p - 1),
        "bias_standard_error": float(est.std(ddof=1) / math.sqrt(est.size) / ref.p) if est.size > 1 else math.nan,
        "relative_error": float(est.std(ddof=1) / ref.p) if est.size > 1 else math.nan,
        "zero_estimates": int(np.sum(est == 0)), "mean_relative_halfwidth": mean_rel,
        "steps_per_repetition": steps, "cpu_s_per_repetition": float(np.mean([r.cpu_s for r in reps])),
        "crude_steps_same_width": crude, "steps_ratio_vs_crude": crude / steps if steps else math.nan,
        "with_warnings": int(sum(bool(r.warnings) for r in reps)),
        "leave_out_reference": any(r.reference_p is not None for r in reps),
        "intervals": [[r.estimate, r.low, r.high] for r in reps],
        "reference_ps": target_p.tolist(),
    }


def _interval(k: int, n: int, level: float) -> list[float]:
    ci = proportion_interval(k, n, level)
    return [ci.low, ci.high]


def run(reference_dirs: Path | Sequence[Path], *, splitting_pools: Sequence[Sequence[Path]] = (),
        importance_dirs: Sequence[Path] = (), groups: Sequence[int] = (4,), level: float = 0.95,
        sequential: Sequence[tuple[float, bool]] = (), subset_pools: Sequence[Sequence[Path]] = (),
        target: str | None = None) -> dict[str, Any]:
    """The measurements described in the module docstring, as plain data: ``estimators`` holds one
    row per (estimator, runs per repetition); each splitting or subset pool (folders of one setting) gives its
    rows, and its runs one by one go to ``pooled_runs``."""
    dirs = as_dirs(reference_dirs)
    sequence = reference_sequence(dirs, target)
    ref = reference_of(dirs, sequence, level)
    reference = {k: v for k, v in asdict(ref).items() if k != "params"}  # the model is the manifest's
    out: dict[str, Any] = {"reference": reference, "level": level, "estimators": [], "pooled_runs": [],
                           "commit": provenance.environment_info().get("git_commit")}
    pools = [("splitting", dirs) for dirs in splitting_pools] + [("subset", dirs) for dirs in subset_pools]
    for method, dirs in pools:
        pooled = pooled_summary(dirs, ref, method)
        out["pooled_runs"].append(pooled)
        for group in groups:
            reps = pooled_repetitions(dirs, ref, group, level, method)
            out["estimators"].append({"estimator": _pool_name(pooled, group), "method": method,
                                      "runs_per_repetition": group, **summarise(reps, ref, level)})
    if importance_dirs:
        reps = importance_repetitions(importance_dirs, ref)
        out["estimators"].append({"estimator": "importance", "method": "importance", **summarise(reps, ref, level)})
        out["importance"] = importance_summary(reps, ref)
    events, steps = sequence.events, sequence.steps
    for halfwidth, relative in sequential:
        reps = sequential_repetitions(events, steps, halfwidth, relative, level)
        if not reps:
            raise RunError(f"--sequential {halfwidth:g}: the reference's {ref.n} episodes are too few for one run "
                           f"to reach that half-width")
        width = f"{halfwidth:.0%} of the estimate" if relative else f"{halfwidth:g}"
        out["estimators"].append({"estimator": f"mc, stopped at half-width {width}", "method": "mc",
                                  "halfwidth": halfwidth, "relative": relative, **summarise(reps, ref, level)})
    if not out["estimators"]:
        raise RunError("give at least one --splitting, --subset, --importance or --sequential to check against the "
                       "reference")
    return out


def _pool_name(pooled: dict[str, Any], group: int) -> str:
    if pooled["method"] == "splitting":
        return f"splitting ({pooled['score']}), {group} runs of {pooled['particles']} particles"
    if group == 1:
        return f"subset ({pooled['performance']}), 1 run of {pooled['samples']} per stage, within-run interval"
    return f"subset ({pooled['performance']}), {group} runs of {pooled['samples']} per stage"


def _parser() -> argparse.ArgumentParser:
    p = section.parser("validation", "The rare-event estimators against a crude Monte Carlo reference on one "
                                     "closed-loop cell: coverage, bias, relative error, cost.")
    p.add_argument("reference", type=Path, nargs="+", help="crude Monte Carlo folders of one cell, distinct seeds, "
                   "pooled: estimate folders (mcverify estimate --method mc) or run folders (mcverify run, with "
                   "--target)")
    p.add_argument("--target", choices=TARGETS, default=None,
                   help="the event a run-folder reference counts (an estimate folder's is its own)")
    p.add_argument("--splitting", type=Path, nargs="+", action="append", default=[], metavar="DIR",
                   help="splitting estimate folders of the same cell, target, particles and score, distinct seeds "
                   "(repeat the option for another pool, e.g. another score)")
    p.add_argument("--subset", type=Path, nargs="+", action="append", default=[], metavar="DIR",
                   help="subset simulation estimate folders of the same cell, target, samples per stage and "
                   "performance function, distinct seeds (repeat the option for another pool)")
    p.add_argument("--importance", type=Path, nargs="+", default=[], metavar="DIR",
                   help="importance estimate folders of the same cell and target, distinct seeds")
    p.add_argument("--group", type=options.positive_int, nargs="+", default=[4], metavar="R",
                   help="splitting, subset: runs per repetition (the estimator's --replicates), one row per value "
                   "(default 4); 1 (subset only): each run alone with its within-run interval")
    p.add_argument("--sequential", type=options.halfwidth, nargs="+", default=[], metavar="H",
                   help="crude Monte Carlo with sequential stopping: the reference's episodes cut into consecutive "
                   "runs of --until-halfwidth H (absolute, e.g. 0.08, or relative, e.g. 50%%), each checked against "
                   "the reference without its episodes; one row per H, and the invalid fixed-n Clopper-Pearson "
                   "stopping beside it")
    section.add_output_options(p)
    section.add_section_option(p, "validation", "validation_rare for a cell of another p")
    p.add_argument("--json", type=Path, default=None, help="also write every figure as JSON to this file")
    p.add_argument("--figure", type=Path, default=None, metavar="PNG",
                   help="also draw every repetition's interval against the reference into this PNG")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        args = _parser().parse_args(argv)
        section.check_section_name("validation", args.section)
        res = run(args.reference, splitting_pools=args.splitting, importance_dirs=args.importance,
                  groups=args.group, sequential=args.sequential, subset_pools=args.subset,
                  target=args.target)
        if args.json:
            files.write_json_atomic(args.json, res)
        if args.figure:
            print(f"figure: {figure(res, args.figure)}", file=sys.stderr)
        text = section.wrap("validation", markdown(res, section.command("validation", argv)), args.section)
        section.publish("validation", text, args)
        return 0

    return section.run_main("validation", body)


if __name__ == "__main__":
    sys.exit(main())
