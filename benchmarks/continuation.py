"""The rare cell reached by continuation: one closed-loop cell at several values of one parameter (the
noise scale by default), crude Monte Carlo where the event is common enough to count and the rare-event
estimators (subset simulation, splitting, importance sampling) beside it, each estimate on its own row. Where
crude Monte Carlo ran, every estimate's interval is checked against it; where it did not, the section says
what crude Monte Carlo would need for the same width. Estimates of one value are set side by side, never
averaged: a disagreement between methods is reported as such. Everything is read from the stored folders,
never typed in.

    python -m benchmarks.continuation --estimate ESTIMATE_DIR ... [--crude RUN_DIR ...] [--stratified OUT ...]
        [--parameter noise.scale] [--figure PNG] [--no-write]

RUN_DIR: a finished ``mcverify run`` folder of one cell (its events counted from episodes.parquet with the
estimates' target, exact Clopper-Pearson interval); folders at the same value with different campaign seeds
(independent episodes) are pooled into one count; ESTIMATE_DIR: a finished ``mcverify estimate --method
subset``, ``splitting`` or ``importance`` folder of one cell; OUT: a finished ``python -m benchmarks.stratified``
folder (its bound.json), the exact lower bound drawn beside the estimates. Every folder must hold the same cell
but for the parameter."""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import section
from mcverify import store
from mcverify.analysis.columns import Columns, floats
from mcverify.analysis.estimates import target_events
from mcverify.analysis.intervals import proportion_interval
from mcverify.errors import UserError
from mcverify.estimate.folder import ESTIMATE
from mcverify.requirements import PERFORMANCES
from mcverify.sim.tilt import TILT_BANDS, TILT_UNITS, NoiseTilt

NAME = "continuation"


@dataclass(frozen=True)
class Crude:
    """Crude Monte Carlo at one value: k events of n episodes, the exact interval, its control steps, and the
    folders (with their campaign seeds) it was counted from."""

    value: float
    k: int
    n: int
    low: float
    high: float
    steps: int
    seeds: tuple[int, ...]
    folders: tuple[Path, ...]

    @property
    def rate(self) -> float:
        return self.k / self.n


#: The estimators whose folders the section reads, in the order their rows of one value are listed.
METHODS = ("subset", "splitting", "importance")


@dataclass(frozen=True)
class Estimate:
    """One rare-event estimate at one value (its folder's estimate.json, one cell): the interval the method
    reports (subset simulation and splitting: Student t on independent runs; importance sampling: the
    weighted CLT interval), its cost and crude Monte Carlo's steps for the same relative half-width."""

    value: float
    method: str
    estimate: float
    low: float
    high: float
    relative_halfwidth: float
    runs: tuple[float, ...]  # the independent runs' estimates (importance sampling: one sample, none)
    samples: int  # subset: episodes per stage; splitting: particles per run; importance: final draws
    steps: int
    cpu_s: float
    crude_steps: float
    seed: int
    target: str
    folder: Path
    steering: str  # what steered the method: subset's performance function, splitting's score, the IS proposal
    stages: tuple[int, ...] = ()  # subset simulation's stages per run
    within_run_cov: float = math.nan  # subset simulation's within-run coefficient of variation of the mean
    warnings: tuple[str, ...] = ()  # what the estimator said against its own interval

    @property
    def factor(self) -> float:
        return self.crude_steps / self.steps if self.steps else math.nan

    @property
    def label(self) -> str:
        return f"{self.method} ({self.steering})"


@dataclass(frozen=True)
class Stratified:
    """The stratified lower bound at one value (``benchmarks.stratified``'s bound.json)."""

    value: float
    lower: float
    point: float
    level: float
    episodes: int
    events: int
    folder: Path


def _param(params: Mapping[str, Any], dotted: str) -> Any:
    node: Any = params
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            raise UserError(f"the cell has no parameter {dotted!r} (e.g. noise.scale, barrier.epsilon)")
        node = node[part]
    return node


def _without(params: Mapping[str, Any], dotted: str) -> dict[str, Any]:
    """``params`` with the parameter ``dotted`` removed (what every folder must share)."""
    head, _, rest = dotted.partition(".")
    out = dict(params)
    if rest:
        out[head] = _without(out[head], rest)
    else:
        out.pop(head, None)
    return out


def _one_cell(folder: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """(manifest, its one cell) of a finished folder."""
    if not (Path(folder) / store.MANIFEST).is_file():
        raise UserError(f"not a run or estimate folder (no {store.MANIFEST}): {folder}")
    manifest = store.read_manifest(folder)
    if not manifest.get("finished_utc"):
        raise UserError(f"{folder} is not finished: resume it first")
    if len(manifest["cells"]) != 1:
        raise UserError(f"{folder} has {len(manifest['cells'])} cells; the continuation reads one cell per folder")
    return manifest, manifest["cells"][0]


def read_estimate(folder: Path, parameter: str) -> tuple[Estimate, dict[str, Any]]:
    manifest, cell = _one_cell(folder)
    spec = manifest.get("estimate") or {}
    method = spec.get("method")
    if method not in METHODS:
        raise UserError(f"{folder} is not a rare-event estimate (mcverify estimate --method "
                        f"{', '.join(METHODS)}){'' if method is None else f'; it holds --method {method}'}")
    (c,) = store.read_json(Path(folder) / ESTIMATE)["cells"]
    common = {"value": float(_param(cell["params"], parameter)), "method": method, "estimate": _num(c["estimate"]),
              "low": _num(c["low"]), "high": _num(c["high"]), "relative_halfwidth": _num(c["relative_halfwidth"]),
              "steps": int(c["steps"]), "cpu_s": float(c["cpu_s"]), "crude_steps": _num(c["crude_steps_same_width"]),
              "seed": int(manifest["campaign"]["seed"]), "target": c["target"], "folder": Path(folder),
              "warnings": tuple(c.get("warnings") or ())}
    if method == "subset":  # folders from before the choice of performance function climbed the robustness
        point = Estimate(**common, runs=tuple(map(_num, c["runs"])), samples=int(spec["samples"]),
                         steering=spec.get("performance", PERFORMANCES[0]), stages=tuple(c["stages"]),
                         within_run_cov=_num(c["within_run_cov"]))
    elif method == "splitting":
        point = Estimate(**common, runs=tuple(map(_num, c["runs"])), samples=int(spec["particles"]),
                         steering=f"score {spec['score']}")
    else:
        point = Estimate(**common, runs=(), samples=int(spec["samples"]),
                         steering=_proposal(spec.get("noise_tilt"), int(spec.get("max_ce_iterations", 0))))
    return point, cell["params"]


def _num(x: Any) -> float:
    """A stored number; NaN where the estimator stored none (a run that estimated nothing, a width of 0)."""
    return math.nan if x is None else float(x)


def _proposal(tilt: Mapping[str, Any] | None, ce_iterations: int) -> str:
    """An importance sampler's proposal in a few words: the noise tilt's non-zero starting tilts (named as
    ``--noise-tilt`` names them), and whether cross-entropy refitted them."""
    if not tilt:
        return "cross-entropy over the scenario"
    theta = NoiseTilt.from_dict(tilt).theta
    named = [f"{unit}_{band} {theta[b * len(TILT_UNITS) + u]:g}" for b, band in enumerate(TILT_BANDS)
             for u, unit in enumerate(TILT_UNITS) if theta[b * len(TILT_UNITS) + u]]
    return f"noise tilt {', '.join(named) or 'none'}" + ("" if ce_iterations == 0 else ", cross-entropy refitted")


def read_crude(folder: Path, parameter: str, target: str) -> tuple[Crude, dict[str, Any]]:
    manifest, cell = _one_cell(folder)
    if manifest.get("estimate"):
        raise UserError(f"{folder} is an estimate folder; --crude reads `mcverify run` folders")
    cols = Columns.from_table(store.read_episodes(folder))
    event, valid = target_events(cols, target)
    k, n = int(event.sum()), int(valid.sum())
    ci = proportion_interval(k, n)
    steps = int(np.nansum(floats(cols, "steps")[valid]))
    return Crude(float(_param(cell["params"], parameter)), k, n, ci.low, ci.high, steps,
                 (int(manifest["campaign"]["seed"]),), (Path(folder),)), cell["params"]


def read_stratified(folder: Path, parameter: str, target: str) -> tuple[Stratified, dict[str, Any]]:
    path = Path(folder) / "bound.json"
    if not path.is_file():
        raise UserError(f"{folder} holds no finished stratified bound (bound.json): run python -m "
                        "benchmarks.stratified")
    b = store.read_json(path)
    if b.get("target") != target:
        raise UserError(f"{folder} bounds {b.get('target')}, not the estimates' {target}")
    return Stratified(float(_param(b["params"], parameter)), float(b["lower"]), float(b["point"]), float(b["level"]),
                      int(b["episodes"]), int(b["events"]), Path(folder)), b["params"]


def pool(points: Sequence[Crude]) -> dict[float, Crude]:
    """One count per value: folders at the same value are pooled (k, n and steps added, the exact interval of
    the sum), which is valid only for independent episodes, so two folders of one seed are refused."""
    out: dict[float, Crude] = {}
    for c in points:
        if c.value not in out:
            out[c.value] = c
            continue
        a = out[c.value]
        same = set(a.seeds) & set(c.seeds)
        if same:
            raise UserError(f"{c.folders[0]} and {a.folders[0]} ran the same seed ({min(same)}) at {c.value:g}: "
                            "the same episodes; give one of them")
        ci = proportion_interval(a.k + c.k, a.n + c.n)
        out[c.value] = Crude(c.value, a.k + c.k, a.n + c.n, ci.low, ci.high, a.steps + c.steps, a.seeds + c.seeds,
                             a.folders + c.folders)
    return out


def _check_same_cell(cells: Sequence[tuple[Path, Mapping[str, Any]]], parameter: str) -> None:
    first_folder, first = cells[0]
    base = _without(first, parameter)
    for folder, params in cells[1:]:
        if _without(params, parameter) != base:
            differing = sorted(k for k in base if base[k] != _without(params, parameter).get(k))
            raise UserError(f"{folder} holds another cell than {first_folder} (they differ in "
                            f"{', '.join(differing) or 'their parameters'}, not only in {parameter})")


def _g(x: float) -> str:
    return f"{x:.3g}" if math.isfinite(x) else "–"


def _f2(x: float) -> str:
    return f"{x:.2f}" if math.isfinite(x) else "–"


def _events(b: Stratified) -> str:
    return f"{b.events} event{'' if b.events == 1 else 's'}"


def _agreement(s: Estimate, c: Crude) -> str:
    overlap = s.low <= c.high and c.low <= s.high
    inside = c.low <= s.estimate <= c.high
    return (f"{'overlap' if overlap else 'DISAGREE'}; estimate / crude = {_g(s.estimate / c.rate) if c.k else '–'}; "
            f"estimate {'inside' if inside else 'outside'} crude's interval")


def order(s: Estimate) -> tuple[float, int, int, str]:
    """Rows by value (largest first), then method, then what steered it (subset: in the order of
    ``--performance``'s choices)."""
    known = s.method == "subset" and s.steering in PERFORMANCES
    return -s.value, METHODS.index(s.method), PERFORMANCES.index(s.steering) if known else 0, s.steering


def table(points: Sequence[Estimate], crude: Mapping[float, Crude], parameter: str,
          bounds: Mapping[float, Stratified] | None = None) -> str:
    bounds = bounds or {}
    head = [parameter, "crude Monte Carlo (exact 95 %)", "stratified lower bound", "estimate (95 %)",
            "method (steered by)", "runs", "subset stages", "rel. half-width", "within-run CoV", "control steps",
            "CPU-s", "crude steps, same width", "factor", "against crude"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in sorted(points, key=order):
        c = crude.get(s.value)
        pooled = f" ({len(c.folders)} runs pooled)" if c and len(c.folders) > 1 else ""
        crude_text = (f"{c.k}/{c.n} = {_g(c.rate)} [{_g(c.low)}, {_g(c.high)}], {c.steps:,} steps{pooled}"
                      if c else "–")
        b = bounds.get(s.value)
        bound_text = f">= {_g(b.lower)} ({_events(b)} in {b.episodes})" if b else "–"
        lines.append("| " + " | ".join([
            f"{s.value:g}", crude_text, bound_text, f"{_g(s.estimate)} [{_g(s.low)}, {_g(s.high)}]", s.label,
            ", ".join(_g(r) for r in s.runs) or "–", ", ".join(map(str, s.stages)) or "–",
            _f2(s.relative_halfwidth), _g(s.within_run_cov), f"{s.steps:,}", f"{s.cpu_s:.0f}",
            _g(s.crude_steps), f"{_g(s.factor)}x" if math.isfinite(s.factor) else "–",
            _agreement(s, c) if c else "no crude reference"]) + " |")
    return "\n".join(lines)


def disagreements(points: Sequence[Estimate]) -> list[str]:
    """Per value, each pair of estimates whose intervals do not overlap (reported, never averaged)."""
    out = []
    for a, b in itertools.combinations(sorted(points, key=order), 2):
        if a.value == b.value and (a.high < b.low or b.high < a.low):
            out.append(f"at {a.value:g}: {a.label} {_g(a.estimate)} [{_g(a.low)}, {_g(a.high)}] and {b.label} "
                       f"{_g(b.estimate)} [{_g(b.low)}, {_g(b.high)}] do not overlap.")
    return out


def below_bound(points: Sequence[Estimate], bounds: Mapping[float, Stratified]) -> list[str]:
    """Estimates whose whole interval lies under the exact stratified lower bound of their value: they read
    low, whatever their own interval says."""
    return [f"at {s.value:g}, {s.label}: its interval [{_g(s.low)}, {_g(s.high)}] lies below the stratified lower "
            f"bound {_g(bounds[s.value].lower)}, so it reads low." for s in sorted(points, key=order)
            if s.value in bounds and s.high < bounds[s.value].lower]


def beyond_crude(s: Estimate) -> str:
    """What crude Monte Carlo would cost for the estimate's width, in CPU at the estimate's own rate."""
    if not math.isfinite(s.crude_steps):
        return (f"at {s.value:g}, {s.label}: no crude reference, and the estimate ({_g(s.estimate)}) has no width to "
                "compare crude Monte Carlo's cost with.")
    cpu_h = s.crude_steps * s.cpu_s / s.steps / 3600.0 if s.steps else math.nan
    return (f"at {s.value:g}, {s.label}: no crude reference; for the same relative half-width "
            f"({s.relative_halfwidth:.2f}) crude Monte Carlo needs {s.crude_steps:.3g} control steps, about "
            f"{cpu_h:.3g} CPU-hours at this machine's rate, against {s.cpu_s / 3600.0:.2g} for the estimate "
            f"({s.factor:.3g}x).")


def figure(points: Sequence[Estimate], crude: Mapping[float, Crude], parameter: str, path: Path,
           bounds: Mapping[float, Stratified] | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    kinds = list(dict.fromkeys(s.label for s in sorted(points, key=order)))
    positive = [v for s in points for v in (s.estimate, s.high) if v > 0] + [
        v for c in crude.values() for v in (c.rate, c.high) if v > 0] + [b.lower for b in (bounds or {}).values()
                                                                         if b.lower > 0]
    floor = min(positive) / 3.0 if positive else 1e-6  # where an estimate of 0 is drawn (a log axis has no 0)
    labelled = set()
    for s in sorted(points, key=lambda p: p.value):
        k = kinds.index(s.label)
        if not s.estimate > 0:
            ax.plot([s.value + 0.01 * (1 + 2 * k)], [floor], marker="v", color=f"C{(0, 2, 3, 4, 6, 7)[k % 6]}",
                    linestyle="none", label=f"{s.label}: estimate 0")
            continue
        low = max(s.low, s.estimate / 100.0)  # an interval can reach below 0: drawn down to the axis' floor
        ax.errorbar([s.value + 0.01 * (1 + 2 * k)], [s.estimate], yerr=[[s.estimate - low], [s.high - s.estimate]],
                    fmt="o^sdPh"[k % 6], color=f"C{(0, 2, 3, 4, 6, 7)[k % 6]}", capsize=3,
                    label=None if s.label in labelled else s.label)
        labelled.add(s.label)
    crude_labels = set()
    for c in sorted(crude.values(), key=lambda p: p.value):
        label = "crude Monte Carlo" if c.k else "crude: upper bound"
        shown = label if label not in crude_labels else None  # one legend entry per kind of crude point
        crude_labels.add(label)
        if c.k:
            ax.errorbar([c.value - 0.01], [c.rate], yerr=[[c.rate - c.low], [c.high - c.rate]], fmt="X", color="C1",
                        capsize=3, label=shown)
        else:
            ax.plot([c.value - 0.01], [c.high], marker="v", color="C1", label=shown)
    for i, b in enumerate(sorted((bounds or {}).values(), key=lambda p: p.value)):
        if b.lower > 0:  # a bound of 0 says nothing and has no place on a log axis
            ax.plot([b.value - 0.02], [b.lower], marker="^", color="C5", linestyle="none",
                    label="stratified lower bound" if i == 0 else None)
    ax.set_yscale("log")
    ax.set_xlabel(parameter)
    ax.set_ylabel(f"P({points[0].target})")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize="small")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def code_line(folders: Sequence[Path]) -> str:
    """Which code made each folder: its git commit and the hash of its simulation source (folders with the
    same source hash simulate identically, whatever their commits)."""
    def one(folder: Path) -> str:
        m = store.read_manifest(folder)
        commit = str(m.get("environment", {}).get("git_commit") or "unknown")[:7]
        return f"{folder.name} {commit} (source {str(m.get('code', {}).get('source_sha256', '?'))[:8]})"

    return "Code, per folder: " + "; ".join(one(f) for f in folders) + "."


def _crude_text(crude: Mapping[float, Crude]) -> str:
    if not crude:
        return "Crude Monte Carlo: no folder given (no estimate here is checked against it)."
    seeds = ", ".join(str(seed) for c in crude.values() for seed in c.seeds)
    return (f"Crude Monte Carlo: `mcverify run` folders (seeds {seeds}), the exact two-sided 95 % Clopper-Pearson "
            "interval.")


def _methods_text(points: Sequence[Estimate]) -> str:
    """What each estimator present did, in one sentence each."""
    def seeds(method: str) -> str:
        return ", ".join(str(s.seed) for s in points if s.method == method)

    def sizes(method: str) -> str:
        return ", ".join(sorted({str(s.samples) for s in points if s.method == method}))

    present = {s.method for s in points}
    texts = {
        "subset": f"Subset simulation: `mcverify estimate --method subset` folders (seeds {seeds('subset')}), "
        f"independent runs of N samples per stage (N = {sizes('subset')}), the 95 % Student t interval on the "
        "runs' estimates, the within-run coefficient of variation (Au and Beck, the chains' correlation included) "
        "beside it; the performance function whose levels the runs climbed is the target's robustness, the "
        "precursor ladder (the robustness over 1 + the longest run of control steps with neither Q1 nor Q2 solved) "
        "or the margin ladder (the robustness over 1 + 10 x the depth of the lowest Theorem 5 margin below 0), the "
        "same event in every case.",
        "splitting": f"Splitting: `mcverify estimate --method splitting` folders (seeds {seeds('splitting')}), "
        f"independent adaptive multilevel splitting runs of {sizes('splitting')} particles on the per-step noise, "
        "steered by the named score, the 95 % Student t interval on the runs' estimates.",
        "importance": "Importance sampling: `mcverify estimate --method importance` folders (seeds "
        f"{seeds('importance')}), {sizes('importance')} episodes from a defensive mixture of the nominal law and "
        "the named proposal, each weighted by its likelihood ratio, the 95 % interval of the weighted mean.",
    }
    return " ".join(texts[m] for m in METHODS if m in present)


def build(points: Sequence[Estimate], crude: Mapping[float, Crude], parameter: str, cmd: str,
          campaign: Mapping[str, Any], figure_path: Path | None,
          bounds: Mapping[float, Stratified] | None = None) -> str:
    bounds = bounds or {}
    alone = [s for s in sorted(points, key=order) if s.value not in crude]
    values = {s.value for s in points}
    bound_only = [b for b in sorted(bounds.values(), key=lambda p: -p.value) if b.value not in values]
    folders = [p.folder for p in sorted(points, key=order)] + [
        f for c in sorted(crude.values(), key=lambda c: -c.value) for f in c.folders]
    return "\n".join([
        f"## The rare cell by continuation along {parameter} (`python -m benchmarks.continuation`)", "",
        section.provenance_line(cmd), "",
        f"Cell: campaign {campaign['name']} ({campaign['source']}) with {parameter} moved; target "
        f"{points[0].target}. {_crude_text(crude)} {_methods_text(points)} Crude steps, same width: z² (1 - p) / "
        "(p r²) episodes "
        "of a nominal episode's mean length. Agreement: the two intervals overlap; estimates of one value are set "
        "side by side, never averaged. Stratified lower bound: `python -m benchmarks.stratified` folders, crude "
        "Monte Carlo inside boxes of the decisive draws, exact at 95 % (no estimate below it is credible; it cannot "
        "say an estimate reads high).", "",
        table(points, crude, parameter, bounds), "",
        *(f"- Methods disagree {d}" for d in disagreements(points)),
        *(f"- at {s.value:g}, {s.label} warns: {w}" for s in sorted(points, key=order) for w in s.warnings),
        *(f"- Not credible {line}" for line in below_bound(points, bounds)),
        *(f"- {beyond_crude(s)}" for s in alone),
        *(f"- at {b.value:g}: stratified lower bound >= {_g(b.lower)} ({_events(b)} in {b.episodes} episodes; "
          f"the strata's point {_g(b.point)}), no estimate yet." for b in bound_only),
        f"- {code_line(folders)}",
        *([f"- Stratified folders: {', '.join(str(b.folder) for b in bounds.values())}."] if bounds else []),
        *([f"- Figure: `{figure_path}`."] if figure_path else []),
    ])


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        p = section.parser(NAME, __doc__.splitlines()[0])
        p.add_argument("--estimate", type=Path, nargs="+", required=True, metavar="DIR",
                       help="finished `mcverify estimate` folders (subset, splitting or importance) of the cell, "
                            "any number per value")
        p.add_argument("--crude", type=Path, nargs="*", default=[], metavar="DIR",
                       help="finished `mcverify run` folders of the same cell, one value each")
        p.add_argument("--stratified", type=Path, nargs="*", default=[], metavar="OUT",
                       help="finished `python -m benchmarks.stratified` folders of the same cell, one value each")
        p.add_argument("--parameter", default="noise.scale", help="the parameter moved (default noise.scale)")
        p.add_argument("--figure", type=Path, help="also draw P(target) against the parameter into this PNG")
        section.add_section_option(p, NAME, "continuation_methods for the methods side by side at one value")
        section.add_output_options(p)
        args = p.parse_args(argv)
        section.check_section_name(NAME, args.section)
        read = [read_estimate(d, args.parameter) for d in args.estimate]
        points = [s for s, _ in read]
        if len({s.target for s in points}) != 1:
            raise UserError("the estimate folders estimate different targets")
        crude_read = [read_crude(d, args.parameter, points[0].target) for d in args.crude]
        bound_read = [read_stratified(d, args.parameter, points[0].target) for d in args.stratified]
        _check_same_cell([(s.folder, prm) for s, prm in read] + [(c.folders[0], prm) for c, prm in crude_read]
                         + [(b.folder, prm) for b, prm in bound_read], args.parameter)
        if len({b.value for b, _ in bound_read}) != len(bound_read):
            raise UserError(f"two stratified folders at the same {args.parameter}; give one")
        bounds = {b.value: b for b, _ in bound_read}
        if len({s.folder.resolve() for s in points}) != len(points):
            raise UserError("the same estimate folder given twice")
        crude = pool([c for c, _ in crude_read])
        campaign = store.read_manifest(args.estimate[0])["campaign"]
        if args.figure:
            figure(points, crude, args.parameter, args.figure, bounds)
        text = build(points, crude, args.parameter, section.command(NAME, argv), campaign, args.figure, bounds)
        section.publish(NAME, section.wrap(NAME, text, args.section), args)
        return 0

    return section.run_main(NAME, body)


if __name__ == "__main__":
    raise SystemExit(main())
