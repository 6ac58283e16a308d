"""The rare cell reached by continuation: one closed-loop cell at several values of one parameter (the
noise scale by default), crude Monte Carlo where the event is common enough to count and subset
simulation at every value, side by side. Where both ran, the subset simulation interval is checked
against crude Monte Carlo; where only subset simulation ran, the section says what crude Monte Carlo
would need for the same width. Everything is read from the stored folders, never typed in.

    python -m benchmarks.continuation --crude RUN_DIR ... --subset ESTIMATE_DIR ... [--stratified OUT ...]
        [--parameter noise.scale] [--figure PNG] [--no-write]

RUN_DIR: a finished ``mcverify run`` folder of one cell (its events counted from episodes.parquet with the
subset estimate's target, exact Clopper-Pearson interval); folders at the same value with different campaign
seeds (independent episodes) are pooled into one count; ESTIMATE_DIR: a finished ``mcverify estimate
--method subset`` folder of one cell; OUT: a finished ``python -m benchmarks.stratified`` folder (its bound.json),
the exact lower bound drawn beside the estimates. Every folder must hold the same cell but for the parameter."""

from __future__ import annotations

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


@dataclass(frozen=True)
class Subset:
    """One subset simulation estimate at one value (its folder's estimate.json, one cell)."""

    value: float
    estimate: float
    low: float
    high: float
    relative_halfwidth: float
    within_run_cov: float
    runs: tuple[float, ...]
    stages: tuple[int, ...]
    samples: int
    steps: int
    cpu_s: float
    crude_steps: float
    seed: int
    target: str
    folder: Path
    performance: str = PERFORMANCES[0]  # the function the runs climbed (the same event whichever)

    @property
    def factor(self) -> float:
        return self.crude_steps / self.steps if self.steps else math.nan


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


def read_subset(folder: Path, parameter: str) -> tuple[Subset, dict[str, Any]]:
    manifest, cell = _one_cell(folder)
    if (manifest.get("estimate") or {}).get("method") != "subset":
        raise UserError(f"{folder} is not a subset simulation estimate (mcverify estimate --method subset)")
    (c,) = store.read_json(Path(folder) / ESTIMATE)["cells"]
    spec = manifest["estimate"]
    point = Subset(float(_param(cell["params"], parameter)), float(c["estimate"]), float(c["low"]), float(c["high"]),
                   float(c["relative_halfwidth"]), float(c["within_run_cov"]), tuple(c["runs"]), tuple(c["stages"]),
                   int(spec["samples"]), int(c["steps"]), float(c["cpu_s"]), float(c["crude_steps"]),
                   int(manifest["campaign"]["seed"]), spec["target"], Path(folder),
                   spec.get("performance", PERFORMANCES[0]))  # folders from before the choice climbed the robustness
    return point, cell["params"]


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
        raise UserError(f"{folder} bounds {b.get('target')}, not the subset estimates' {target}")
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


def _events(b: Stratified) -> str:
    return f"{b.events} event{'' if b.events == 1 else 's'}"


def _agreement(s: Subset, c: Crude) -> str:
    overlap = s.low <= c.high and c.low <= s.high
    inside = c.low <= s.estimate <= c.high
    return (f"{'overlap' if overlap else 'DISAGREE'}; subset / crude = {_g(s.estimate / c.rate) if c.k else '–'}; "
            f"subset estimate {'inside' if inside else 'outside'} crude's interval")


def table(points: Sequence[Subset], crude: Mapping[float, Crude], parameter: str,
          bounds: Mapping[float, Stratified] | None = None) -> str:
    bounds = bounds or {}
    head = [parameter, "crude Monte Carlo (exact 95 %)", "stratified lower bound", "subset simulation (95 % t on runs)",
            "performance function",
            "runs", "stages",
            "rel. half-width", "within-run CoV", "control steps", "CPU-s", "crude steps, same width", "factor",
            "against crude"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in sorted(points, key=lambda p: (-p.value, PERFORMANCES.index(p.performance))):
        c = crude.get(s.value)
        pooled = f" ({len(c.folders)} runs pooled)" if c and len(c.folders) > 1 else ""
        crude_text = (f"{c.k}/{c.n} = {_g(c.rate)} [{_g(c.low)}, {_g(c.high)}], {c.steps:,} steps{pooled}"
                      if c else "–")
        b = bounds.get(s.value)
        bound_text = f">= {_g(b.lower)} ({_events(b)} in {b.episodes})" if b else "–"
        lines.append("| " + " | ".join([
            f"{s.value:g}", crude_text, bound_text, f"{_g(s.estimate)} [{_g(s.low)}, {_g(s.high)}]", s.performance,
            ", ".join(_g(r) for r in s.runs), ", ".join(map(str, s.stages)), f"{s.relative_halfwidth:.2f}",
            f"{s.within_run_cov:.2f}", f"{s.steps:,}", f"{s.cpu_s:.0f}", f"{s.crude_steps:.3g}", f"{s.factor:.3g}x",
            _agreement(s, c) if c else "no crude reference"]) + " |")
    return "\n".join(lines)


def beyond_crude(s: Subset) -> str:
    """What crude Monte Carlo would cost for the subset estimate's width, in CPU at the estimate's own rate."""
    cpu_h = s.crude_steps * s.cpu_s / s.steps / 3600.0 if s.steps else math.nan
    return (f"at {s.value:g}: no crude reference; for the same relative half-width ({s.relative_halfwidth:.2f}) crude "
            f"Monte Carlo needs {s.crude_steps:.3g} control steps, about {cpu_h:.3g} CPU-hours at this machine's "
            f"rate, against {s.cpu_s / 3600.0:.2g} for subset simulation ({s.factor:.3g}x).")


def figure(points: Sequence[Subset], crude: Mapping[float, Crude], parameter: str, path: Path,
           bounds: Mapping[float, Stratified] | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    labelled = set()
    for s in sorted(points, key=lambda p: p.value):
        k = PERFORMANCES.index(s.performance)
        low = max(s.low, s.estimate / 100.0)  # a t interval can reach below 0: drawn down to the axis' floor
        label = f"subset simulation ({s.performance})" if s.performance not in labelled else None
        labelled.add(s.performance)
        ax.errorbar([s.value + 0.01 * (1 + 2 * k)], [s.estimate], yerr=[[s.estimate - low], [s.high - s.estimate]],
                    fmt="o^sd"[k % 4], color=f"C{(0, 2, 3, 4)[k % 4]}", capsize=3, label=label)
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
    ax.legend()
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


def build(points: Sequence[Subset], crude: Mapping[float, Crude], parameter: str, cmd: str,
          campaign: Mapping[str, Any], figure_path: Path | None,
          bounds: Mapping[float, Stratified] | None = None) -> str:
    bounds = bounds or {}
    alone = [s for s in sorted(points, key=lambda p: -p.value) if s.value not in crude]
    values = {s.value for s in points}
    bound_only = [b for b in sorted(bounds.values(), key=lambda p: -p.value) if b.value not in values]
    folders = [p.folder for p in sorted(points, key=lambda p: -p.value)] + [
        f for c in sorted(crude.values(), key=lambda c: -c.value) for f in c.folders]
    return "\n".join([
        f"## The rare cell by continuation along {parameter} (`python -m benchmarks.continuation`)", "",
        section.provenance_line(cmd), "",
        f"Cell: campaign {campaign['name']} ({campaign['source']}) with {parameter} moved; target "
        f"{points[0].target}. Crude Monte Carlo: `mcverify run` folders (seeds "
        f"{', '.join(str(seed) for c in crude.values() for seed in c.seeds) or '–'}), the exact two-sided 95 % "
        "Clopper-Pearson interval. "
        f"Subset simulation: `mcverify estimate --method subset` folders (seeds "
        f"{', '.join(str(s.seed) for s in points)}), independent runs of N samples per stage "
        f"(N = {', '.join(sorted({str(s.samples) for s in points}))}), the 95 % Student t interval on the runs' "
        "estimates, the within-run coefficient of variation (Au and Beck, the chains' correlation included) beside "
        "it; the performance function whose levels the runs climbed is the target's robustness, the precursor "
        "ladder (the robustness over 1 + the longest run of control steps with neither Q1 nor Q2 solved) or the "
        "margin ladder (the robustness over 1 + 10 x the depth of the lowest Theorem 5 margin below 0), the same "
        "event in every case. Crude steps, same width: z² (1 - p) / (p r²) episodes of stage 0's mean episode. "
        "Agreement: the two intervals overlap. Stratified lower bound: `python -m benchmarks.stratified` folders, "
        "crude Monte Carlo inside boxes of the decisive draws, exact at 95 % (no estimate below it is credible; it "
        "cannot say an estimate reads high).", "",
        table(points, crude, parameter, bounds), "",
        *(f"- {beyond_crude(s)}" for s in alone),
        *(f"- at {b.value:g}: stratified lower bound >= {_g(b.lower)} ({_events(b)} in {b.episodes} episodes; "
          f"the strata's point {_g(b.point)}), no subset estimate yet." for b in bound_only),
        f"- {code_line(folders)}",
        *([f"- Stratified folders: {', '.join(str(b.folder) for b in bounds.values())}."] if bounds else []),
        *([f"- Figure: `{figure_path}`."] if figure_path else []),
    ])


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        p = section.parser(NAME, __doc__.splitlines()[0])
        p.add_argument("--subset", type=Path, nargs="+", required=True, metavar="DIR",
                       help="finished subset simulation estimate folders, one per value and performance function")
        p.add_argument("--crude", type=Path, nargs="*", default=[], metavar="DIR",
                       help="finished `mcverify run` folders of the same cell, one value each")
        p.add_argument("--stratified", type=Path, nargs="*", default=[], metavar="OUT",
                       help="finished `python -m benchmarks.stratified` folders of the same cell, one value each")
        p.add_argument("--parameter", default="noise.scale", help="the parameter moved (default noise.scale)")
        p.add_argument("--figure", type=Path, help="also draw P(target) against the parameter into this PNG")
        section.add_output_options(p)
        args = p.parse_args(argv)
        read = [read_subset(d, args.parameter) for d in args.subset]
        points = [s for s, _ in read]
        if len({s.target for s in points}) != 1:
            raise UserError("the subset folders estimate different targets")
        crude_read = [read_crude(d, args.parameter, points[0].target) for d in args.crude]
        bound_read = [read_stratified(d, args.parameter, points[0].target) for d in args.stratified]
        _check_same_cell([(s.folder, prm) for s, prm in read] + [(c.folders[0], prm) for c, prm in crude_read]
                         + [(b.folder, prm) for b, prm in bound_read], args.parameter)
        if len({b.value for b, _ in bound_read}) != len(bound_read):
            raise UserError(f"two stratified folders at the same {args.parameter}; give one")
        bounds = {b.value: b for b, _ in bound_read}
        values = [(s.value, s.performance) for s in points]
        if len(set(values)) != len(values):
            raise UserError(f"two subset folders at the same {args.parameter} with the same performance function; "
                            "give one")
        crude = pool([c for c, _ in crude_read])
        campaign = store.read_manifest(args.subset[0])["campaign"]
        if args.figure:
            figure(points, crude, args.parameter, args.figure, bounds)
        text = build(points, crude, args.parameter, section.command(NAME, argv), campaign, args.figure, bounds)
        section.publish(NAME, section.wrap(NAME, text), args)
        return 0

    return section.run_main(NAME, body)


if __name__ == "__main__":
    raise SystemExit(main())
