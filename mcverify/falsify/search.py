"""A falsification search: generations of candidates, each run as an ordinary run folder.

Layout of a search folder ``OUT``::

    OUT/falsify.json              what defines the search (campaign content, method, budget, seeds)
    OUT/generations/g000/ ...     generation 0: an ordinary run folder (manifest, chunks, episodes)
    OUT/search.parquet            one row per evaluated candidate, in evaluation order
    OUT/counterexamples.parquet   every violating episode, worst first, with its replay command
    OUT/report.md                 robustness against episodes, the counterexamples, the worst drawn

Generation ``g`` is a campaign with one axis ``candidate`` whose labels ``c00``, ``c01``, ... are
one-episode cells with the candidate's model values as overrides, run through the campaign layer
(executors, chunk store, ledger); its episode seed is :func:`generation_seed`. So every evaluated
episode is a row ``mcverify replay OUT/generations/gNNN EPISODE_ID`` re-simulates bit for bit, and a
killed search resumes (``resume``): the searcher is rebuilt from its seed and told the stored
robustness of every finished generation, which gives exactly the points the uninterrupted search
asked, then the unfinished generation is resumed chunk by chunk and the search goes on.

This module holds what defines a search (:class:`SearchConfig`, checked by :func:`check`), its loop
(:func:`start`, :func:`resume`) and its outputs; one generation's run folder is
:mod:`~mcverify.falsify.generation_folder`, the method's side (the cube, ask and tell)
:mod:`~mcverify.falsify.ask_tell`, and what a candidate scored :mod:`~mcverify.falsify.candidate_scores`.
"""

from __future__ import annotations

import copy
import hashlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mcverify import files, provenance, store
from mcverify import requirements as reqs
from mcverify.analysis import counterexamples as cx
from mcverify.analysis import failure_regions
from mcverify.campaign import executors, runner
from mcverify.campaign.executors import EpisodeFn, Executor
from mcverify.campaign.overrides import apply_overrides
from mcverify.campaign.search_space import SearchSpace, check_single_target, split_element
from mcverify.campaign.spec import Campaign, campaign_from_dict
from mcverify.errors import CampaignError, RunError
from mcverify.falsify import ask_tell, candidate_scores, generation_folder, methods
from mcverify.falsify.generation_folder import GENERATIONS
from mcverify.falsify.parametrisations import theta_of_unit
from mcverify.sim.schedule import control_steps

CONFIG = "falsify.json"
SEARCH = "search.parquet"
COUNTEREXAMPLES = "counterexamples.parquet"
FORMAT = 1


@dataclass(frozen=True)
class SearchConfig:
    """What defines a search: the campaign file's content (``raw``, with ``--set`` applied), the
    method, the episode budget, the search seed, and the requirement it minimises."""

    raw: dict[str, Any]
    source: str
    method: str
    budget: int
    seed: int
    requirement: str

    def to_json(self) -> dict[str, Any]:
        return {"format": FORMAT, "raw": self.raw, "source": self.source, "method": self.method,
                "budget": self.budget, "seed": self.seed, "requirement": self.requirement}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> SearchConfig:
        if data.get("format") != FORMAT:
            raise RunError(f"falsify folder format {data.get('format')!r}, this mcverify reads {FORMAT}")
        return cls(data["raw"], data["source"], data["method"], int(data["budget"]), int(data["seed"]),
                   data["requirement"])


@dataclass(frozen=True)
class Evaluation:
    """One evaluated candidate: its generation and index, unit-cube point, model values, row."""

    generation: int
    candidate: int
    point: tuple[float, ...]
    values: dict[str, float]
    row: dict[str, Any]
    robustness: float
    parent: int = 0  # splitting: the 1-based evaluation number of the particle it branched from (0: none)
    branch_after_step: int = -1  # splitting: the control step after which its own noise starts (-1: fresh)
    move: str = "fresh"  # splitting: how it came from its parent ("fresh", "noise" or "scenario")
    guide: float = math.nan  # the value the method was told ([falsify] guide; NaN: none, it was told the robustness)
    control_steps: int = 0  # control steps its episode simulated (settling included): its cost


@dataclass(frozen=True)
class SearchResult:
    out_dir: Path
    config: SearchConfig
    space: SearchSpace
    evaluations: tuple[Evaluation, ...]
    full_episode_steps: int = 0  # control steps of a whole episode of the target (the unit of the cost)

    @property
    def episodes(self) -> int:
        return len(self.evaluations)

    @property
    def control_steps(self) -> int:
        """Control steps simulated by the whole search (episodes that stopped early cost less)."""
        return sum(e.control_steps for e in self.evaluations)

    def episode_equivalents(self, upto: int | None = None) -> float:
        """Control steps simulated by the first ``upto`` evaluations (all: None) over those of a whole episode."""
        steps = sum(e.control_steps for e in self.evaluations[:upto])
        return steps / self.full_episode_steps if self.full_episode_steps else math.nan

    @property
    def min_robustness(self) -> float:
        finite = [e.robustness for e in self.evaluations if not math.isnan(e.robustness)]
        return min(finite) if finite else math.nan

    @property
    def first_counterexample(self) -> int | None:
        """1-based count of episodes evaluated up to and including the first violating one (a count,
        not an episode id: :meth:`first_counterexample_text` names the episode)."""
        return next((i + 1 for i, e in enumerate(self.evaluations) if e.robustness < 0.0), None)

    def first_counterexample_text(self) -> str | None:
        """``after N episodes: generation G, episode E (mcverify replay DIR E)``, None if none was found;
        E is the episode id the replay command takes (0-based within its generation's folder)."""
        count = self.first_counterexample
        if count is None:
            return None
        e = self.evaluations[count - 1]
        gen_dir = self.out_dir / GENERATIONS / f"g{e.generation:03d}"
        episode = int(e.row["episode_id"])
        return (f"after {count} episode{'s' if count != 1 else ''}: generation {e.generation}, episode {episode} "
                f"(`mcverify replay {gen_dir} {episode}`)")


def target(config: SearchConfig) -> tuple[Campaign, SearchSpace]:
    """The campaign (one target cell) and its validated ``[falsify]`` table."""
    campaign = campaign_from_dict(config.raw, source=config.source)
    if campaign.falsify is None:
        raise CampaignError(f"{config.source}: no [falsify] table; `mcverify falsify` needs one "
                            "(see mcverify.campaign.search_space)")
    check_single_target(config.raw, config.source)
    return campaign, campaign.falsify


def generation_seed(campaign_seed: int, search_seed: int, generation: int) -> int:
    """The episode seed of generation ``generation``: distinct per generation and search seed, so
    candidates of different generations (and independent trials) see independent per-step noise."""
    digest = hashlib.sha256(f"{campaign_seed}:{search_seed}:{generation}".encode()).digest()
    return int.from_bytes(digest[:8], "big") % 2**31  # the summary reads seeds as float64: stay exact


def generation_campaign(config: SearchConfig, values: list[dict[str, Any]], generation: int,
                        stop_episodes: bool = False) -> Campaign:
    """Generation ``generation`` as a campaign: one one-episode cell per candidate (``values``: its
    cell overrides, :meth:`SearchSpace.overrides`); with
    ``stop_episodes`` each episode ends at its first violation of the requirement (``sim.stop_at``)."""
    raw = copy.deepcopy(config.raw)
    raw.pop("falsify", None)
    head = raw["campaign"]
    head["name"] = f"{head['name']}-g{generation:03d}"
    head["seed"] = generation_seed(int(head.get("seed", 0)), config.seed, generation)
    head["episodes"] = 1
    head["common_random_numbers"] = False
    raw["axes"] = {"candidate": {f"c{k:02d}": dict(v) for k, v in enumerate(values)}}
    if stop_episodes:  # end each episode at its first violation of the searched requirement
        model = raw.setdefault("model", {})
        model["sim"] = {**model.get("sim", {}), "stop_at": config.requirement}
    return campaign_from_dict(raw, source=f"{config.source} (generation {generation})")


def check(config: SearchConfig) -> SearchSpace:
    """Everything about a new search that can be wrong before it runs, each as one CampaignError or
    RunError line: the campaign and its ``[falsify]`` table, every bound against its field's limits,
    the method and the method's demands on the table."""
    campaign, space = target(config)
    if not space.bounds and space.adversary is None:
        raise RunError(f"{config.source}: its [falsify] table searches with [falsify.beam] only (--method beam); "
                       f"--method {config.method} needs [falsify.bounds] or [falsify.adversary]")
    check_bounds(config, campaign, space)
    methods.searcher(config.method, 1, 2, 0)  # a bad method name (or a missing optional package) fails here
    if space.adversary is not None:
        check_adversary(config, campaign, space)
    if config.method == "splitting" and space.common_noise:
        raise RunError("--method splitting draws fresh noise for its branches; [falsify] common_noise = true "
                       "is for the other methods")
    if config.method == "splitting" and space.guide and not space.guide.endswith(reqs.RUN_SUFFIX):
        raise RunError(f"--method splitting branches on a running robustness: [falsify] guide {space.guide!r} has "
                       f"none (splitting takes the requirement itself or a guide ending in {reqs.RUN_SUFFIX!r})")
    if space.stop_episodes and reqs.is_stl(config.requirement):
        raise RunError(f"[falsify] stop_episodes = true ends each episode at its first violation, which the rollout "
                       f"cannot see for an STL requirement ({config.requirement!r}: evaluated on the stored "
                       "trajectory afterwards); set it false")
    if config.method == "splitting" and config.requirement not in reqs.STEPWISE:
        raise RunError(f"--method splitting branches on a per-step robustness; requirement {config.requirement!r} "
                       f"has none (choose one of {', '.join(reqs.STEPWISE)})")
    return space


def check_adversary(config: SearchConfig, campaign: Campaign, space: SearchSpace) -> None:
    """A searched perception error needs noise bounds to search in and a method that searches the cube."""
    if config.method == "splitting":
        raise RunError("--method splitting branches the drawn noise; with [falsify.adversary] the error is searched "
                       "(choose cma, cross-entropy, random or bo)")
    if campaign.cells[0].params.noise.kind == "none":
        raise RunError(f"{config.source}: noise.kind = \"none\" gives the adversary no bounds to search in "
                       "([falsify.adversary] scales its units by the noise bounds)")
    try:
        adversary = ask_tell.adversary_of(campaign, space)
        adversary.schedule(np.zeros(adversary.dimension))
    except ValueError as exc:
        raise RunError(f"{config.source} [falsify.adversary]: {exc}") from None


def check_bounds(config: SearchConfig, campaign: Campaign, space: SearchSpace) -> None:
    """Each searched field at its lower and at its upper bound, on the campaign's own model, must be
    valid, so that a bound beyond a field's limit fails before the search starts, not in the generation
    whose candidate first lands there. (The other elements of a searched list field sit at their
    middle; the other fields keep the file's values, so a limit that two searched fields share is still
    checked per candidate.)"""
    base = campaign.cells[0].params
    for i, (name, lo, hi) in enumerate(space.bounds):
        field = split_element(name)[0]
        for end, u in (("lower", 0.0), ("upper", 1.0)):
            point = [0.5] * space.dimension
            point[i] = u
            values = {k: v for k, v in space.values(point).items() if split_element(k)[0] == field}
            where = f"{config.source} [falsify.bounds] {name} = [{lo:g}, {hi:g}], at its {end} bound {values[name]:g}"
            apply_overrides(base, space.overrides(values), where)


def check_new_folder(out_dir: Path) -> None:
    """A new search's folder must not exist yet or be empty."""
    if out_dir.exists() and any(out_dir.iterdir()):
        raise RunError(f"{out_dir} exists and is not empty; choose another folder or use --resume {out_dir}")


def start(config: SearchConfig, out_dir: Path, **kw: Any) -> SearchResult:
    """A new search into the new folder ``out_dir`` (see :func:`_search` for the keywords)."""
    out_dir = Path(out_dir)
    check(config)  # validates before anything is written
    check_new_folder(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files.write_json_atomic(out_dir / CONFIG, config.to_json())
    return _search(config, out_dir, **kw)


def stored_generations(out_dir: Path) -> int:
    """How many generations of the search in ``out_dir`` are finished on disk (what a resume re-reads)."""
    return sum(generation_folder.is_finished(g) for g in sorted((Path(out_dir) / GENERATIONS).glob("g[0-9][0-9][0-9]")))


def resume(out_dir: Path, **kw: Any) -> SearchResult:
    """Finish (or re-read) the search in ``out_dir``."""
    out_dir = Path(out_dir)
    if not (out_dir / CONFIG).is_file():
        raise RunError(f"{out_dir} is not a falsification folder (no {CONFIG})")
    config = SearchConfig.from_json(store.read_json(out_dir / CONFIG))
    first = out_dir / GENERATIONS / "g000" / store.MANIFEST
    if first.is_file():  # the search's recorded parameters must still be this code's (a one-line error if not)
        runner.campaign_from_manifest(store.read_json(first))
    return _search(config, out_dir, **kw)


def _search(
    config: SearchConfig,
    out_dir: Path,
    *,
    make_executor: Callable[[], Executor] = executors.LocalExecutor,
    episode_fn: EpisodeFn = executors.simulate,
    progress: Callable[[str], None] | None = None,
    stop_after_generations: int | None = None,
    bar: bool = False,
) -> SearchResult:
    """The search loop. make_executor: the executor, made once and kept alive across the generations
    (:class:`~mcverify.campaign.executors.KeptAlive`: its workers start once); episode_fn: the episode
    simulation (tests inject cheap ones); progress: called with one line per generation;
    stop_after_generations: stop (as if killed) after running that many generations in this call;
    bar: a per-episode progress bar on stderr inside each generation."""
    shared = executors.KeptAlive(make_executor)
    try:
        return _generations(config, out_dir, lambda: shared, episode_fn, progress, stop_after_generations, bar)
    finally:
        shared.release()


def _generations(config: SearchConfig, out_dir: Path, make_executor: Callable[[], Executor], episode_fn: EpisodeFn,
                 progress: Callable[[str], None] | None, stop_after_generations: int | None,
                 bar: bool = False) -> SearchResult:
    campaign, space = target(config)
    adversary = ask_tell.adversary_of(campaign, space)
    search = methods.searcher(config.method, ask_tell.search_dimension(campaign, space), space.population, config.seed,
                              campaign.seed)
    evaluations: list[Evaluation] = []
    ran = 0
    generation = 0
    common_seed = ask_tell.noise_seed(campaign.seed, config.seed) if space.common_noise else -1
    while len(evaluations) < config.budget:
        candidates = ask_tell.ask(search, common_seed)
        n = min(len(candidates), config.budget - len(evaluations))
        values = [space.values(list(c.point[:space.dimension])) for c in candidates[:n]]
        gen_campaign = generation_campaign(
            config, [space.overrides(v) | c.noise_overrides() for v, c in zip(values, candidates, strict=False)],
            generation, space.stop_episodes)
        schedules = ask_tell.schedules(adversary, space, gen_campaign, candidates[:n])
        gen_dir = out_dir / GENERATIONS / f"g{generation:03d}"
        finished = generation_folder.is_finished(gen_dir)
        if not finished:
            if stop_after_generations is not None and ran >= stop_after_generations:
                raise RunError(f"search stopped after {ran} generation(s) (test hook); resume {out_dir}")
            generation_folder.run(gen_campaign, gen_dir, make_executor, episode_fn, bar, schedules)
            ran += 1
        else:
            generation_folder.check_same(gen_dir, gen_campaign, schedules)
        rows = {int(r["cell_index"]): r for r in store.read_episodes(gen_dir).to_pylist()}
        robs = np.array([candidate_scores.robustness(gen_dir, rows[k], config.requirement) for k in range(n)])
        periods_s = [cell.params.sim.control_period_s for cell in gen_campaign.cells]
        guides = (np.array([candidate_scores.guide_value(gen_dir, rows[k], space.guide, periods_s[k])
                            for k in range(n)]) if space.guide else None)
        evaluations += [Evaluation(generation, k, candidates[k].point, values[k], rows[k], float(robs[k]),
                                   candidates[k].parent, candidates[k].branch_after_step, candidates[k].move,
                                   math.nan if guides is None else float(guides[k]),
                                   candidate_scores.simulated_steps(rows[k], periods_s[k]))
                        for k in range(n)]
        if progress is not None:
            best = np.nanmin(robs) if np.isfinite(robs).any() else math.nan
            told = "" if guides is None else f", best {space.guide} {candidate_scores.lowest(guides):.4g}"
            progress(f"generation {generation}: {n} episodes, best robustness {best:.4g}{told}, "
                     f"{len(evaluations)}/{config.budget} episodes")
        if n == len(candidates):
            ask_tell.tell(search, candidates, robs if guides is None else guides, gen_dir,
                          [rows[k] for k in range(n)], space.guide or config.requirement, periods_s)
        generation += 1
        if space.stop_at_first and (robs < 0.0).any():
            break
    if ran == 0 and progress is not None:
        progress("nothing left to run: every generation of this search is stored; its report is rebuilt from them")
    result = SearchResult(out_dir, config, space, tuple(evaluations), control_steps(campaign.cells[0].params.sim))
    write_outputs(result)
    mark_finished(out_dir)
    return result


def mark_finished(out_dir: Path) -> None:
    """Record in ``falsify.json`` that the search is complete (``finished_utc``, as a run's manifest
    does), once its outputs are written; kept as it is when a finished search is read again."""
    data = store.read_json(Path(out_dir) / CONFIG)
    if not data.get("finished_utc"):
        files.write_json_atomic(Path(out_dir) / CONFIG, {**data, "finished_utc": provenance.now_utc()})


def is_finished(out_dir: Path) -> bool:
    """Whether the search in ``out_dir`` is complete (a search from before the record reads as not)."""
    path = Path(out_dir) / CONFIG
    return path.is_file() and bool(store.read_json(path).get("finished_utc"))


# -------------------------------------------------------------------------------------- outputs


def search_table(result: SearchResult) -> pa.Table:
    """``search.parquet``: one row per evaluated candidate, in evaluation order."""
    ev = result.evaluations
    cols: dict[str, Any] = {
        "evaluation": list(range(1, len(ev) + 1)),
        "generation": [e.generation for e in ev],
        "candidate": [e.candidate for e in ev],
        "run_dir": [f"{GENERATIONS}/g{e.generation:03d}" for e in ev],
        "episode_id": [int(e.row["episode_id"]) for e in ev],
    }
    for i, name in enumerate(result.space.fields):
        cols[f"u:{name}"] = [e.point[i] for e in ev]
        cols[name] = [e.values[name] for e in ev]
    cols["parent"] = [e.parent for e in ev]  # splitting: the evaluation it branched from (0: none)
    # ... and that parent's replay id, as the report names it (-1: none)
    cols["parent_generation"] = [ev[e.parent - 1].generation if e.parent else -1 for e in ev]
    cols["parent_episode_id"] = [int(ev[e.parent - 1].row["episode_id"]) if e.parent else -1 for e in ev]
    cols["branch_after_step"] = [e.branch_after_step for e in ev]  # splitting: where its last noise branch starts
    cols["move"] = [e.move for e in ev]  # splitting: fresh, noise (branch) or scenario (step)
    if result.space.adversary is not None:  # the error's theta in [-1, 1] (the schedule is in the generation folder)
        cols["adversary_theta"] = [[float(x) for x in theta_of_unit(e.point[result.space.dimension:])] for e in ev]
    cols["control_steps"] = [e.control_steps for e in ev]
    cols["episode_equivalents"] = (list(np.cumsum([e.control_steps for e in ev]) / result.full_episode_steps)
                                   if result.full_episode_steps else [math.nan] * len(ev))
    cols["robustness"] = [e.robustness for e in ev]
    if result.space.guide:  # what the method was told instead of the robustness
        cols["guide"] = [e.guide for e in ev]
    cols["violated"] = [bool(e.robustness < 0.0) for e in ev]
    cols["best_so_far"] = list(np.fmin.accumulate([e.robustness for e in ev])) if ev else []
    return pa.table(cols)


def counterexample_records(result: SearchResult) -> list[dict[str, Any]]:
    """Every violating episode of the search, worst first, with its generation's replay command,
    its searched values (``param:<bound name>``, list elements included) and its failure region
    over the whole search (scaled by the search space's bounds)."""
    values = {(e.generation, int(e.row["episode_id"])): e.values for e in result.evaluations}
    records: list[dict[str, Any]] = []
    for generation in sorted({e.generation for e in result.evaluations}):
        gen_dir = result.out_dir / GENERATIONS / f"g{generation:03d}"
        manifest = store.read_json(gen_dir / store.MANIFEST)
        for rec in cx.counterexamples(store.read_episodes(gen_dir), manifest, str(gen_dir),
                                      result.config.requirement,
                                      trajectory=lambda eid, d=gen_dir: store.read_trajectory(d, eid)):
            searched = values.get((generation, int(rec["episode_id"])), {})
            rec.update({f"param:{name}": float(searched[name]) for name in result.space.fields if name in searched})
            records.append({"generation": generation, **rec})
    records.sort(key=lambda r: (r["robustness"], r["generation"], r["episode_id"]))
    failure_regions.assign(records, {f"param:{name}": (lo, hi) for name, lo, hi in result.space.bounds})
    return records


def write_outputs(result: SearchResult) -> None:
    from mcverify.falsify import report  # noqa: PLC0415 - matplotlib only when writing

    files.atomic_write(result.out_dir / SEARCH, lambda tmp: pq.write_table(search_table(result), tmp))
    records = counterexample_records(result)
    files.atomic_write(result.out_dir / COUNTEREXAMPLES, lambda tmp: pq.write_table(cx.to_arrow(records), tmp))
    report.write(result, records)
