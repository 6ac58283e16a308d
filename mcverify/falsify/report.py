"""The report of a falsification search: ``OUT/report.md``, ``OUT/report.html`` and ``OUT/figures/``.

Facts (method, requirement, budget and effort, the minimum robustness reached, when the first
counterexample came), robustness against episodes (each episode and the running minimum), the
counterexample table (:mod:`mcverify.reporting.counterexample_report`) and road snapshots of the
worst counterexamples (every candidate's trajectory is stored in its generation folder).
report.html is the same content as one self-contained page (:mod:`mcverify.reporting.html`, the
renderer of run reports: tables that fit, figures embedded, unsafe rows marked).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from matplotlib.ticker import MaxNLocator

from mcverify import files, store
from mcverify import requirements as reqs
from mcverify.falsify import audit
from mcverify.reporting import counterexample_report
from mcverify.reporting import html as report_html
from mcverify.reporting.figure_common import subplots
from mcverify.reporting.run_figures import FigureResult
from mcverify.reporting.tables import fmt_num, to_markdown


class SearchResult(Protocol):
    """What the report reads of a finished search (:class:`mcverify.falsify.search.SearchResult`),
    declared here so that the report does not import the search that writes it (no import cycle)."""

    @property
    def out_dir(self) -> Path: ...
    @property
    def config(self) -> Any: ...  # SearchConfig: method, budget, seed, requirement, source
    @property
    def space(self) -> Any: ...  # SearchSpace: population, stop_at_first, guide, common_noise, describe()
    @property
    def evaluations(self) -> Sequence[Any]: ...
    @property
    def episodes(self) -> int: ...
    @property
    def min_robustness(self) -> float: ...
    @property
    def first_counterexample(self) -> int | None: ...
    def first_counterexample_text(self) -> str | None: ...
    @property
    def control_steps(self) -> int: ...
    @property
    def full_episode_steps(self) -> int: ...
    def episode_equivalents(self, upto: int | None = None) -> float: ...

REPORT = "report.md"
HTML = "report.html"
FIGURES = "figures"
ROBUSTNESS_CAPTION = ("Each episode's robustness (dots) and the smallest so far (line); below the dashed line the "
                      "requirement is violated. Episodes are named by their replay ids, gG/E: episode E of generation "
                      "G (`mcverify replay OUT/generations/gGGG E`); the axis runs through the generations in "
                      "evaluation order, each tick at a generation's episode 0, and the worst episode is labelled. Per "
                      "episode in `search.parquet`.")

#: Most generation ticks on the robustness axis (more are thinned to every k-th generation).
MAX_GENERATION_TICKS = 12


def robustness_curves(curves: Mapping[str, Sequence[float]], path: Path, requirement: str,
                      episodes: Sequence[tuple[int, int]] | None = None) -> None:
    """Robustness against episodes: one marker per episode and the running minimum, per method.
    The vertical axis is symmetric-log so that margins of metres and of hundredths both show.

    ``episodes``: with one curve, each episode's replay id (generation, episode id); the axis then
    names episodes as ``mcverify replay`` does (a tick ``gG/0`` at each generation's first episode, the
    worst episode labelled). Without it (curves of several searches) the axis counts episodes evaluated."""
    fig, ax = subplots(figsize=(7.0, 3.6), dpi=150)
    for k, (label, values) in enumerate(curves.items()):
        y = np.asarray(values, dtype=float)
        x = np.arange(y.size) if episodes is not None else np.arange(1, y.size + 1)
        colour = f"C{k}"
        ax.plot(x, y, ".", color=colour, alpha=0.5, ms=5)
        ax.step(x, np.fmin.accumulate(np.where(np.isnan(y), np.inf, y)), where="post", color=colour, label=label)
    ax.axhline(0.0, color="k", lw=0.8, ls="--")
    ax.set_yscale("symlog", linthresh=0.05)
    label_symlog_axis(ax)
    if episodes is not None:
        _replay_id_axis(ax, list(next(iter(curves.values()), [])), list(episodes))
    else:
        ax.set_xlabel("episodes evaluated")
    ax.set_ylabel(f"robustness ({requirement})")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})


def replay_id(generation: int, episode_id: int) -> str:
    """How the report names a search's episode: ``gG/E``, episode E (from 0) of generation G's folder."""
    return f"g{generation:03d}/{episode_id}"


def _replay_id_axis(ax: Any, values: Sequence[float], episodes: Sequence[tuple[int, int]]) -> None:
    """Ticks at each generation's first episode (``gG/0``), thinned to :data:`MAX_GENERATION_TICKS`,
    and the worst episode labelled with its replay id."""
    starts = [i for i, (g, _) in enumerate(episodes) if i == 0 or episodes[i - 1][0] != g]
    step = max(1, math.ceil(len(starts) / MAX_GENERATION_TICKS))
    ticks = starts[::step]
    ax.set_xticks(ticks)
    ax.set_xticklabels([replay_id(*episodes[i]) for i in ticks], fontsize=7,
                       rotation=30 if len(ticks) > 6 else 0)
    ax.set_xlabel("episode (replay id gG/E: generation G, episode E)" if len(starts) > 1 else
                  f"episode id (generation g{episodes[0][0]:03d})" if episodes else "episode")
    if len(starts) == 1 and episodes:  # one generation: the position is the episode id itself
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    y = np.asarray(values, dtype=float)
    if y.size and np.isfinite(y).any():
        worst = int(np.nanargmin(y))
        ax.annotate(replay_id(*episodes[worst]), (worst, y[worst]), textcoords="offset points", xytext=(6, -10),
                    fontsize=7, color="C3")


def label_symlog_axis(ax: Any, most: int = 9) -> None:
    """Plain-number ticks at 0 and +-1, 2, 5 x 10^k inside the axis's range (matplotlib's symlog labels
    only whole decades, so a search whose robustness stays within -0.06..0.5 showed a single label).
    Thinned to 1 and 5 x 10^k, then to 10^k, while there are more than ``most``."""
    low, high = ax.get_ylim()
    for mantissas in ((1.0, 2.0, 5.0), (1.0, 5.0), (1.0,)):
        steps = [m * 10.0**k for k in range(-2, 5) for m in mantissas]  # below 0.01: crowded at 0
        ticks = sorted({0.0, *(v for v in steps if v <= high), *(-v for v in steps if -v >= low)})
        if len(ticks) <= most:
            break
    ax.set_yticks(ticks)
    ax.set_yticklabels([f"{v:g}" for v in ticks])
    ax.set_ylim(low, high)


def facts(result: SearchResult, records: Sequence[Mapping[str, Any]]) -> list[tuple[str, str]]:
    req = reqs.requirement(result.config.requirement)
    first = result.first_counterexample_text()
    space = result.space.describe() or "(no scenario field: the target's scenario fixed)"
    if getattr(result.space, "adversary", None) is not None:
        space += f"; {result.space.adversary.describe()}"
    generations = len({e.generation for e in result.evaluations})
    return [
        ("campaign", f"`{result.config.source}`"),
        ("requirement", f"`{req.name}`: {req.statement} (robustness in {req.unit or 'its own unit'}, "
                        "negative iff violated)"),
        ("method", f"{result.config.method}, seed {result.config.seed}, population {result.space.population}"),
        ("search space", space),
        ("effort", f"{result.episodes} of {result.config.budget} episodes in {generations} generation(s)"
                   + _why_stopped(result)),
        ("cost", _cost(result)),
        ("minimum robustness reached", fmt_num(result.min_robustness, 4, signed=True)),
        ("first counterexample", first if first else
         f"none found within {result.episodes} episodes"),
        ("counterexamples", f"{len(records)} (see `counterexamples.parquet`)"),
    ] + _guide_facts(result) + _noise_facts(result)


def _cost(result: SearchResult) -> str:
    """Control steps simulated, as episode-equivalents (whole episodes of the target), to the end and to the
    first counterexample."""
    first = result.first_counterexample
    to_first = "" if first is None else f"; {result.episode_equivalents(first):.3g} to the first counterexample"
    return (f"{result.control_steps} control steps = {result.episode_equivalents():.3g} episode-equivalents "
            f"({result.full_episode_steps} control steps each){to_first}")


def _why_stopped(result: SearchResult) -> str:
    """Why a finished search spent less than its budget: it stops after the generation of its first
    counterexample unless ``[falsify] stop_at_first = false``."""
    if result.episodes >= result.config.budget or result.first_counterexample is None or not result.space.stop_at_first:
        return ""
    return ("; it stopped after the generation that found its first counterexample (`[falsify] stop_at_first`, "
            "default true; set it false to spend the whole budget)")


def _guide_facts(result: SearchResult) -> list[tuple[str, str]]:
    """What the method minimised when it was not the requirement ([falsify] guide)."""
    guide = result.space.guide
    if not guide:
        return []
    values = [e.guide for e in result.evaluations if not math.isnan(e.guide)]
    finite = [v for v in values if math.isfinite(v)]
    lowest = fmt_num(min(finite), 4, signed=True) if finite else "none finite"
    return [("guide", f"the method minimised `{guide}` instead of the requirement (lowest {lowest}; finite for "
                      f"{len(finite)} of {len(result.evaluations)} episodes, column `guide` of `search.parquet`)")]


def _noise_facts(result: SearchResult) -> list[tuple[str, str]]:
    """How the search treated the per-step noise: common to all candidates, or split (the best's lineage)."""
    if result.space.common_noise:
        return [("noise", "one realisation for every candidate (`[falsify] common_noise`)")]
    if result.config.method != "splitting" or not result.evaluations:
        return []
    ev = result.evaluations
    best = min(range(len(ev)), key=lambda i: (math.isnan(ev[i].robustness), ev[i].robustness))
    return [("lineage of the best", lineage(ev, best + 1))]


def lineage(evaluations: Sequence[Any], number: int) -> str:
    """``episode gG/E (how it came) <- its parent (...) <- ...`` back to a fresh draw, each named by its
    replay id (:func:`replay_id`); ``number`` and each ``parent`` are 1-based evaluation numbers."""
    how = {"fresh": "fresh", "scenario": "scenario step"}
    steps = []
    while number > 0:
        e = evaluations[number - 1]
        name = replay_id(e.generation, int(e.row["episode_id"]))
        steps.append(f"{name} ({how.get(e.move, f'noise branch after step {e.branch_after_step}')})")
        number = e.parent
    return "episode " + " ← ".join(steps)


def write(result: SearchResult, records: Sequence[Mapping[str, Any]]) -> Path:
    """Write report.md and report.html of the search; returns report.md's path."""
    out = result.out_dir
    (out / FIGURES).mkdir(exist_ok=True)
    robustness_curves({result.config.method: [e.robustness for e in result.evaluations]},
                      out / FIGURES / "robustness.png", result.config.requirement,
                      [(e.generation, int(e.row["episode_id"])) for e in result.evaluations])
    fact_list = facts(result, records)
    tables = [counterexample_report.table(records, result.config.requirement, result.episodes,
                                          audits=audit.kept(out, records), run_dir=str(out), audit_key=audit.key)]
    if records:
        tables.append(counterexample_report.regions_table(records))
    drawn = _draw_worst(out, records)
    title = f"Falsification: {Path(result.config.source).name}"
    lines = [f"# {title}", ""]
    lines += [f"- **{k}**: {v}" for k, v in fact_list]
    lines += ["", "## Robustness against episodes", "", f"![robustness]({FIGURES}/robustness.png)", "",
              ROBUSTNESS_CAPTION, ""]
    lines += ["## Counterexamples", "", to_markdown(tables[0]), ""]
    lines += [line for t in tables[1:] for line in (to_markdown(t, heading="##"), "")]
    if drawn:
        lines += ["## Worst counterexamples", ""]
        for path, caption in drawn:
            lines += [f"![worst counterexample]({path})", "", caption, ""]
    elif records:
        lines += ["No counterexample could be drawn (no stored trajectory).", ""]
    text = "\n".join(lines)
    files.atomic_write(out / REPORT, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
    page = report_html.render(out, fact_list, tables, _html_figures(result, drawn),
                              _definitions(result.config.requirement), title=title)
    files.atomic_write(out / HTML, lambda tmp: Path(tmp).write_text(page, encoding="utf-8"))
    return out / REPORT


def _html_figures(result: SearchResult, drawn: Sequence[tuple[str, str]]) -> list[FigureResult]:
    figs = [FigureResult("robustness", "Robustness against episodes", ROBUSTNESS_CAPTION,
                         f"{FIGURES}/robustness.png")]
    figs += [FigureResult(f"worst-{k}", f"Worst counterexample {k + 1}", caption, path)
             for k, (path, caption) in enumerate(drawn)]
    return figs


def _definitions(chosen: str) -> list[tuple[str, str]]:
    """The chosen requirement first, then every other one (the counterexample file has them all)."""
    names = [chosen, *[n for n in reqs.REQUIREMENTS if n != chosen]]
    return [(n, f"{reqs.requirement(n).statement}; robustness in {reqs.requirement(n).unit or 'its own unit'}, "
                f"negative iff violated") for n in names]


def _draw_worst(out: Path, records: Sequence[Mapping[str, Any]]) -> list[tuple[str, str]]:
    drawn = []
    for rec in records[: counterexample_report.MAX_DRAWN]:
        gen_dir = out / "generations" / f"g{int(rec['generation']):03d}"
        manifest = store.read_json(gen_dir / store.MANIFEST)
        for fig in counterexample_report.figures(gen_dir, [rec], manifest):
            if fig.file:
                drawn.append((str((gen_dir / fig.file).relative_to(out)), fig.caption))
    return drawn

