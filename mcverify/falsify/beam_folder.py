"""A beam search (:mod:`mcverify.falsify.beam`) as a falsification folder: what ``mcverify falsify --method
beam`` checks, writes, resumes and reports.

Layout of a beam folder ``OUT``::

    OUT/falsify.json        what defines the search (campaign content, method "beam", budget, seed,
                            requirement); ``finished_utc`` once complete
    OUT/beam/restart-RR/    restart RR: beam.json (its specification), depth-NNN.npz (the frontier after each
                            depth), restart.json (its depth log, final frontier and cost, once finished) and
                            best.npz (its best node's schedule)
    OUT/beam/result.json    the finished search (every restart): what report.md is written from
    OUT/best/               the chosen schedule re-simulated from step 0, a one-episode run folder
                            (``mcverify replay OUT/best 0``)
    OUT/report.md

The campaign is one scenario (``[campaign] episodes = 1``, no grid, no axes) whose ``[falsify]`` table holds
only ``requirement`` and ``[falsify.beam]`` (:mod:`mcverify.campaign.beam_table`): the beam searches the
per-step error of that scenario, so searched scenario fields (``[falsify.bounds]``) and the other methods'
settings are refused rather than ignored.

The budget: ``--budget N`` is in episode-equivalents (control steps over a whole episode's, the unit every
method's cost is stated in) and is a ceiling. The beam's cost is bounded before it runs
(:meth:`BeamSpec.cost_bound`), so a spec whose one beam could exceed the budget is refused up front rather than
cut short inside a depth (which would leave no frontier to judge); the bound counts one final node run to the
time limit, and the others run while the budget left covers another such run (the allowance of
:func:`mcverify.falsify.beam.search`). Restarts: while no counterexample is found and the budget left covers
another beam's bound, the beam restarts under the same seed with a new draw of every child (``BeamSpec.restart``;
restart r's children are keyed by (seed, r, ...)). A beam's success is a draw of its children, so restarts turn a
beam that succeeds at rate q into a search that fails only at (1 - q)^restarts. The chosen restart is the first
with a counterexample, else the one with the lowest robustness. The control steps a resume spends rebuilding
snapshots are stated apart and do not count against the budget.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mcverify import files, store
from mcverify.analysis import robustness as rb
from mcverify.campaign.spec import Campaign
from mcverify.errors import RunError
from mcverify.falsify import beam, search
from mcverify.falsify.beam import BeamResult, BeamSpec
from mcverify.falsify.search import SearchConfig
from mcverify.sim.schedule import control_steps

BEST = "best"
RESULT = "result.json"
RESTART = "restart.json"
#: The keys of ``[falsify]`` a beam campaign may have.
BEAM_KEYS = ("requirement", "beam")


def target(config: SearchConfig) -> tuple[Campaign, BeamSpec]:
    """The one-episode campaign and the beam's spec; every mistake one RunError or CampaignError line."""
    campaign, space = search.target(config)
    where = config.source
    if space.beam is None:
        raise RunError(f"{where}: --method beam needs a [falsify.beam] table (window_s, segment_s, branching, width; "
                       "docs/falsification.md)")
    other = [k for k in config.raw["falsify"] if k not in BEAM_KEYS]
    if other:
        raise RunError(f"{where} [falsify]: --method beam searches the per-step error of the file's one scenario and "
                       f"takes only requirement and [falsify.beam]; remove {', '.join(other)}")
    episodes = sum(c.episodes for c in campaign.cells)
    if episodes != 1:
        raise RunError(f"{where}: [campaign] episodes = {episodes}; the beam searches one episode (set episodes = 1)")
    params = campaign.cells[0].params
    if params.noise.kind == "none":
        raise RunError(f"{where}: noise.kind = \"none\" gives the beam no bounds to act in (its units scale the "
                       "noise bounds)")
    if rb.needs_trajectory(config.requirement):
        raise RunError(f"requirement {config.requirement!r}: the beam ranks its final frontier by the episodes' rows; "
                       "an STL requirement is evaluated on stored trajectories (choose a named requirement)")
    try:
        spec = beam.spec_of(space.beam, config.requirement, config.seed, params.sim)
    except ValueError as exc:
        raise RunError(f"{where} {exc}") from None
    return campaign, spec


def check(config: SearchConfig) -> tuple[Campaign, BeamSpec]:
    """:func:`target`, and the budget (episode-equivalents) against the spec's cost bound."""
    campaign, spec = target(config)
    steps = control_steps(campaign.cells[0].params.sim)
    bound = spec.cost_bound(steps)
    if bound > config.budget * steps:
        raise RunError(f"--budget {config.budget}: this beam may spend up to {bound / steps:.3g} episode-equivalents "
                       f"({bound} control steps of {steps} per episode); give --budget {math.ceil(bound / steps)} or "
                       "narrow the beam (see --dry-run)")
    return campaign, spec


def describe(config: SearchConfig) -> str:
    """``falsify --method beam --dry-run``: the beam's depths, children per depth and cost bound."""
    from mcverify.campaign import cost  # noqa: PLC0415 - the kernel count only for a dry run

    campaign, spec = check(config)
    sim = campaign.cells[0].params.sim
    steps = control_steps(sim)
    bound = spec.cost_bound(steps)
    return "\n".join([
        f"falsify {config.source}: beam, budget {config.budget} episode-equivalents, requirement "
        f"{config.requirement}, seed {config.seed}",
        *_spec_lines(spec, sim.control_period_s, steps),
        f"cost bound: {bound} control steps = {bound / steps:.3g} episode-equivalents per beam (the prefix to the "
        "window, every child's segment, the best final node run to the time limit; the other final nodes run "
        "while the budget left covers another such run; episodes that end sooner cost less); the nodes run one "
        "after another in this process",
        f"restarts: at least {config.budget * steps // bound} beam(s) fit the budget; without a counterexample the "
        "beam restarts with new draws while the budget left covers another beam's bound",
        cost.kernels_to_build(campaign.cells).text(),
    ])


def _spec_lines(spec: BeamSpec, period_s: float, steps: int) -> list[str]:
    children, shape = spec.children_per_depth(), spec.shape
    return [
        f"window: control steps [{spec.first_step}, {spec.last_step}) = [{spec.first_step * period_s:g}, "
        f"{spec.last_step * period_s:g}) s of {steps} ({period_s:g} s each), segments of {spec.segment_steps} steps: "
        f"{spec.depths} depth(s)",
        f"children per depth (at most): {', '.join(map(str, children))} ({sum(children)} in all); branching "
        f"{shape.branching}, width {shape.width}; snapshots alive at most {2 * shape.width + 1}",
        f"units: {shape.units} on {', '.join(shape.channels)}, shares front {shape.front_share:g}, opposing "
        f"{shape.opp_share:g}; nodes ranked by the running {shape.score}",
    ]


# ------------------------------------------------------------------------------------------- running


def start(config: SearchConfig, out_dir: Path, *, progress: Callable[[str], None] | None = None,
          stop_after_depths: int | None = None) -> BeamSummary:
    """A new beam search into the new (or empty) folder ``out_dir``; ``stop_after_depths``: a test's interruption."""
    out_dir = Path(out_dir)
    campaign, spec = check(config)
    search.check_new_folder(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files.write_json_atomic(out_dir / search.CONFIG, config.to_json())
    return _run(config, campaign, spec, out_dir, progress, stop_after_depths)


def is_beam_folder(out_dir: Path) -> bool:
    """Whether ``out_dir`` holds a beam search (its ``falsify.json`` names the method)."""
    path = Path(out_dir) / search.CONFIG
    return path.is_file() and store.read_json(path).get("method") == beam.BEAM


def stored_depths(out_dir: Path) -> int:
    """Depth files stored over every restart."""
    return len(list((Path(out_dir) / beam.BEAM).glob("restart-[0-9][0-9]/depth-[0-9][0-9][0-9].npz")))


def resume(out_dir: Path, *, progress: Callable[[str], None] | None = None,
           stop_after_depths: int | None = None) -> BeamSummary:
    """Finish the beam search in ``out_dir`` from its last depth file (to where an uninterrupted one ends)."""
    out_dir = Path(out_dir)
    config = SearchConfig.from_json(store.read_json(out_dir / search.CONFIG))
    campaign, spec = check(config)
    return _run(config, campaign, spec, out_dir, progress, stop_after_depths)


def _run(config: SearchConfig, campaign: Campaign, spec: BeamSpec, out_dir: Path,
         progress: Callable[[str], None] | None, stop_after_depths: int | None) -> BeamSummary:
    steps = control_steps(campaign.cells[0].params.sim)
    budget, bound = config.budget * steps, spec.cost_bound(steps)
    restarts: list[RestartSummary] = []
    while not restarts or (restarts[-1].best_robustness >= 0.0 and _spent(restarts) + bound <= budget):
        restarts.append(_restart(campaign, dataclasses.replace(spec, restart=len(restarts)), out_dir,
                                 budget - _spent(restarts), progress, stop_after_depths))
    summary = BeamSummary.of(config, campaign, spec, tuple(restarts))
    best_dir = out_dir / BEST
    if best_dir.exists():  # a write cut short before the search was marked finished: re-simulate it whole
        shutil.rmtree(best_dir)
    if progress is not None:
        progress(f"best schedule (restart {summary.chosen}) re-simulated from step 0 into {best_dir}")
    with np.load(_restart_dir(out_dir, summary.chosen) / "best.npz", allow_pickle=False) as data:
        beam.write_best(campaign, data["units"], spec, best_dir)
    row = store.read_episodes(best_dir).to_pylist()[0]
    replayed = rb.robustness(row, spec.requirement)
    if not _same(replayed, summary.best_robustness):
        raise RunError(f"{best_dir}: the best schedule re-simulated from step 0 has robustness {replayed!r}, the "
                       f"beam's node {summary.best_robustness!r}; the snapshots did not continue the episode exactly")
    files.write_json_atomic(out_dir / beam.BEAM / RESULT, summary.to_json())
    write_report(out_dir, summary)
    search.mark_finished(out_dir)
    return summary


def _restart_dir(out_dir: Path, restart: int) -> Path:
    return Path(out_dir) / beam.BEAM / f"restart-{restart:02d}"


def _spent(restarts: list[RestartSummary]) -> int:
    return sum(r.search_steps for r in restarts)


def _restart(campaign: Campaign, spec: BeamSpec, out_dir: Path, allowance_steps: int,
             progress: Callable[[str], None] | None, stop_after_depths: int | None) -> RestartSummary:
    """Restart ``spec.restart`` with the budget left, ``allowance_steps``: re-read when finished, else run (or
    resumed from its depth files) and kept."""
    folder = _restart_dir(out_dir, spec.restart)
    if (folder / RESTART).is_file():
        return RestartSummary.from_json(store.read_json(folder / RESTART))
    if progress is not None and spec.restart:
        progress(f"beam restart {spec.restart}: no counterexample yet, new draws of every child")
    result = beam.search(campaign, spec, folder, allowance_steps=allowance_steps,
                         stop_after_depths=stop_after_depths, progress=progress)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, units=result.frontier[result.best].units)

    files.atomic_write(folder / "best.npz", write)
    summary = RestartSummary.of(result)
    files.write_json_atomic(folder / RESTART, summary.to_json())
    return summary


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


# ------------------------------------------------------------------------------------------- outputs


@dataclass(frozen=True)
class FrontierNode:
    """A node of the final frontier: its requirement's robustness, running score and episode outcome."""

    robustness: float
    score: float
    outcome: str
    steps: int


@dataclass(frozen=True)
class RestartSummary:
    """One finished beam (one restart): its depth log, final frontier, best node and costs."""

    restart: int
    depth_log: tuple[tuple[int, float, int], ...]  # (depth, best score, control steps so far)
    frontier: tuple[FrontierNode, ...]
    best: int
    search_steps: int
    rebuild_steps: int
    peak_snapshots: int
    stopped_at_depth: int | None = None  # a child of this depth violated the requirement: the search ended there

    @classmethod
    def of(cls, result: BeamResult) -> RestartSummary:
        nodes = tuple(FrontierNode(float(r), float(n.score), str(n.row["outcome"]), int(n.row["steps"]))
                      for n, r in zip(result.frontier, result.robustness, strict=True))
        log = tuple((int(d["depth"]), float(d["best_score"]), int(d["control_steps"])) for d in result.depth_log)
        return cls(result.spec.restart, log, nodes, result.best, result.search_steps, result.rebuild_steps,
                   result.peak_snapshots, result.stopped_at_depth)

    @property
    def best_robustness(self) -> float:
        return self.frontier[self.best].robustness

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RestartSummary:
        return cls(**{**data, "depth_log": tuple(tuple(d) for d in data["depth_log"]),
                      "frontier": tuple(FrontierNode(**n) for n in data["frontier"])})


@dataclass(frozen=True)
class BeamSummary:
    """A finished beam search as ``OUT/beam/result.json`` keeps it (what the report is written from)."""

    source: str
    requirement: str
    seed: int
    budget: int
    spec: BeamSpec  # restart 0's; restart r differs only in ``restart``
    control_period_s: float
    full_episode_steps: int
    restarts: tuple[RestartSummary, ...]

    @classmethod
    def of(cls, config: SearchConfig, campaign: Campaign, spec: BeamSpec,
           restarts: tuple[RestartSummary, ...]) -> BeamSummary:
        return cls(config.source, config.requirement, config.seed, config.budget, spec,
                   campaign.cells[0].params.sim.control_period_s, control_steps(campaign.cells[0].params.sim),
                   restarts)

    @property
    def chosen(self) -> int:
        """The first restart with a counterexample, else the one with the lowest robustness."""
        robs = [r.best_robustness for r in self.restarts]
        hits = [i for i, x in enumerate(robs) if x < 0.0]
        if hits:
            return hits[0]
        return 0 if all(math.isnan(x) for x in robs) else int(np.nanargmin(robs))

    @property
    def best_robustness(self) -> float:
        return self.restarts[self.chosen].best_robustness

    @property
    def frontier(self) -> tuple[FrontierNode, ...]:
        """The chosen restart's final frontier."""
        return self.restarts[self.chosen].frontier

    @property
    def search_steps(self) -> int:
        return sum(r.search_steps for r in self.restarts)

    @property
    def rebuild_steps(self) -> int:
        return sum(r.rebuild_steps for r in self.restarts)

    @property
    def peak_snapshots(self) -> int:
        return max(r.peak_snapshots for r in self.restarts)

    @property
    def episode_equivalents(self) -> float:
        return self.search_steps / self.full_episode_steps

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "spec": self.spec.to_json()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> BeamSummary:
        return cls(**{**data, "spec": BeamSpec.from_json(data["spec"]),
                      "restarts": tuple(RestartSummary.from_json(r) for r in data["restarts"])})


def read_summary(out_dir: Path) -> BeamSummary:
    return BeamSummary.from_json(store.read_json(Path(out_dir) / beam.BEAM / RESULT))


def verdict(summary: BeamSummary, out_dir: Path) -> str:
    """One line: counterexample or not, the cost, and the replay command."""
    r = summary.best_robustness
    found = (f"counterexample: robustness {r:.4g} of {summary.requirement}" if r < 0.0 else
             f"no counterexample: lowest robustness {r:.4g} of {summary.requirement}")
    return (f"{found}; cost {summary.search_steps} control steps = {summary.episode_equivalents:.3g} "
            f"episode-equivalents; `mcverify replay {Path(out_dir) / BEST} 0`")


def write_report(out_dir: Path, summary: BeamSummary) -> Path:
    """``OUT/report.md`` from the summary (``mcverify report OUT`` rewrites it from result.json)."""
    s, out_dir = summary, Path(out_dir)
    steps, found, chosen = s.full_episode_steps, verdict(s, out_dir), s.restarts[s.chosen]
    lines = [f"# Beam search: {s.source}", "",
             f"Requirement `{s.requirement}`, seed {s.seed}, budget {s.budget} episode-equivalents "
             f"(cost bound {s.spec.cost_bound(steps)} control steps per beam). {found[0].upper()}{found[1:]}.", "",
             "## Specification", "", *[f"- {line}" for line in _spec_lines(s.spec, s.control_period_s, steps)], "",
             "## Restarts", "",
             "Without a counterexample the beam restarts with new draws of every child while the budget left covers "
             "another beam's bound; the chosen restart is the first with a counterexample, else the lowest.", "",
             f"| restart | lowest robustness ({s.requirement}) | control steps |", "|---:|---:|---:|",
             *[f"| {r.restart}{' (chosen)' if r.restart == s.chosen else ''} | {r.best_robustness:.4g} | "
               f"{r.search_steps} |" for r in s.restarts], "",
             f"## Depths of restart {s.chosen}", "",
             f"| depth | best running {s.spec.shape.score} | control steps so far |",
             "|---:|---:|---:|", *[f"| {d} | {score:.4g} | {cost} |" for d, score, cost in chosen.depth_log], "",
             *([f"Stopped at depth {chosen.stopped_at_depth}: a child violated `{s.requirement}` in its segment (a "
                "running minimum, violated for good), so it ran to its episode's end as the counterexample and the "
                "search ended; its frontier below is that node.", ""] if chosen.stopped_at_depth is not None else []),
             f"## Final frontier of restart {s.chosen}", "", f"| rank | robustness ({s.requirement}) | running "
             f"{s.spec.shape.score} at the window's end | outcome | control steps |", "|---:|---:|---:|---|---:|",
             *[f"| {i}{' (best)' if i == chosen.best else ''} | {n.robustness:.4g} | {n.score:.4g} | {n.outcome} | "
               f"{n.steps} |" for i, n in enumerate(chosen.frontier)], "",
             "## Cost", "",
             f"- search: {s.search_steps} control steps = {s.episode_equivalents:.3g} episode-equivalents "
             f"({steps} control steps per episode) over {len(s.restarts)} restart(s)",
             f"- rebuilding snapshots after a resume: {s.rebuild_steps} control steps (not counted above)",
             f"- snapshots alive at most: {s.peak_snapshots} (in the search's last process; bound "
             f"{2 * s.spec.shape.width + 1})", "",
             "## Replay", "",
             f"The chosen node's whole schedule (zeros outside the window) re-simulated from step 0 is "
             f"`{out_dir / BEST}`, one episode; `mcverify replay {out_dir / BEST} 0` re-simulates it bit for bit. "
             f"`mcverify replay {out_dir / BEST} 0 --backend ipopt` re-simulates the same error with IPOPT at every "
             "step and says whether the verdict is the controller's or the fast path's (a held plan that grazes the "
             "ellipse under the fast path may not under IPOPT).", ""]
    path = out_dir / "report.md"
    files.atomic_write(path, lambda tmp: Path(tmp).write_text("\n".join(lines), encoding="utf-8"))
    return path
