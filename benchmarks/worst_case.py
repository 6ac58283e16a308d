"""``python -m benchmarks.worst_case``: the lowest robustness each search method reaches against the VL-CBF
level ε, the adversarial counterpart of P(collision) against ε (:mod:`benchmarks.eps_curve`).

    python -m benchmarks.worst_case TARGET.toml --eps 0,0.1,0.2,0.3,0.5 --methods cma,random --trials T
        --budget B --seed S --workers W --out-dir DIR [--replay]

Per ε, the trials of :mod:`benchmarks.falsify` on the target with ``barrier.epsilon = ε`` (as ``--set``):
``trials`` searches per method (seeds ``seed``, ``seed + 1``, ...), each with ``budget`` episodes and stopping
at its first counterexample, in ``DIR/eps-<ε>/<campaign>/<method>/trial-NN`` (a killed run resumes there).
The section states per ε and method the falsified trials with their exact interval, the cost to the first
counterexample, and the lowest robustness of every trial; one computed headline sentence, and a figure
(``DIR/worst-case.png`` unless ``--figure``): ε across, each trial's lowest robustness as a point (a
counterexample below the line at 0 marked apart), the median per method as a line.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks import falsify, section
from mcverify import model
from mcverify import requirements as reqs
from mcverify.campaign.spec import Campaign, load_campaign
from mcverify.cli.options import nonneg_int, positive_int
from mcverify.errors import RunError, UserError

NAME = "worst_case"
DEFAULT_EPS = "0,0.1,0.2,0.3,0.5"
#: Figure file under ``--out-dir`` unless ``--figure`` names another.
FIGURE = "worst-case.png"
#: Noise fields that set the half-widths of the measured error: a search over one of them leaves the
#: paper's bounds (the structured disturbances and the adversary stay inside the half-widths).
HALF_WIDTH_FIELDS = ("noise.kind", "noise.scale", "noise.pos_far_m", "noise.pos_near_m", "noise.speed_rel",
                     "noise.near_threshold_m")


@dataclass(frozen=True)
class EpsilonTrials:
    """The trials of every method at one level ε, in method then trial order."""

    epsilon: float
    trials: tuple[falsify.Trial, ...]

    def by_method(self) -> dict[str, list[falsify.Trial]]:
        out: dict[str, list[falsify.Trial]] = {}
        for t in self.trials:
            out.setdefault(t.method, []).append(t)
        return out


@dataclass(frozen=True)
class Setting:
    """What the section says about the target beside the trials."""

    source: str  # the campaign file as given
    requirement: str
    noise: str  # "within the paper's noise bounds", ... (:func:`noise_phrase`)
    budget: int


def parse_eps(text: str) -> tuple[float, ...]:
    """The levels of ``--eps`` (comma-separated, each a number in [0, 1), no repeats); otherwise one
    UserError line."""
    items = [x.strip() for x in text.split(",") if x.strip()]
    if not items:
        raise UserError(f"--eps {text!r}: give at least one level, e.g. --eps {DEFAULT_EPS}")
    out = []
    for item in items:
        try:
            eps = float(item)
        except ValueError:
            raise UserError(f"--eps: {item!r} is not a number (levels in [0, 1), e.g. --eps {DEFAULT_EPS})") from None
        if not 0.0 <= eps < 1.0:  # also refuses nan and inf
            raise UserError(f"--eps: {item} is outside [0, 1) (the VL-CBF level ε of barrier.epsilon)")
        if eps in out:
            raise UserError(f"--eps: {item} is given twice")
        out.append(eps)
    return tuple(out)


def eps_setting(eps: float) -> str:
    """The ``--set`` that puts the target at level ``eps``."""
    return f"barrier.epsilon={float(eps)!r}"


def eps_dir(out_dir: Path, eps: float) -> Path:
    """The trial folders of level ``eps``: ``out_dir/eps-<ε>``."""
    return Path(out_dir) / f"eps-{float(eps)!r}"


def check_target(target: Path) -> Campaign:
    """The target campaign, refused in one line if it is missing, has no ``[falsify]`` table, or its
    controller keeps no level ε (plain MPC-DC: every ε would run the same search)."""
    if not Path(target).is_file():
        raise RunError(f"campaign file not found: {target}")
    campaign = load_campaign(target)
    if campaign.falsify is None:
        raise RunError(f"{target}: no [falsify] table (bounds of the search space); see docs/falsification.md "
                       "or campaigns/falsify_*.toml")
    fixed = sorted({c.params.mpc.controller for c in campaign.cells} & set(model.CONTROLLERS_WITHOUT_LEVEL))
    if fixed:
        raise RunError(f"{target}: controller {', '.join(fixed)} keeps no level ε (barrier.epsilon has no effect); "
                       "give a target of a controller with a level, e.g. vlcbf")
    return campaign


def noise_phrase(campaign: Campaign) -> str:
    """Where the target's perception error lies against the paper's (Sec. VI-A): within its bounds when every
    half-width is at most the paper's and no search varies one, without noise, or beyond."""
    searched = [f for f in campaign.falsify.fields if f in HALF_WIDTH_FIELDS] if campaign.falsify else []
    paper = model.Noise()
    noises = [c.params.noise for c in campaign.cells]
    if searched:
        return f"with the noise half-widths searched ({', '.join(searched)})"
    if all(n.kind == "none" for n in noises):
        return "without perception noise"
    within = all(n.kind == paper.kind and n.near_threshold_m == paper.near_threshold_m
                 and n.scale * n.pos_far_m <= paper.pos_far_m and n.scale * n.pos_near_m <= paper.pos_near_m
                 and n.scale * n.speed_rel <= paper.speed_rel for n in noises)
    if within:
        return "within the paper's noise bounds"
    return f"beyond the paper's noise bounds (noise.scale {', '.join(sorted({f'{n.scale:g}' for n in noises}))})"


def run(target: Path, levels: Sequence[float], methods_: Sequence[str], trials: int, budget: int, seed: int,
        out_dir: Path, progress: Callable[[str], None] | None = None, **search_kw: Any) -> list[EpsilonTrials]:
    """The trials of :func:`benchmarks.falsify.run_trials` at every level, every search of every level
    checked (and every stored trial folder matched) before the first one runs."""
    plans = [(eps, falsify.plan_trials([target], methods_, trials, budget, seed, eps_dir(out_dir, eps),
                                       settings=[eps_setting(eps)])) for eps in levels]
    out = []
    for eps, planned in plans:
        say = None if progress is None else (lambda line, eps=eps: progress(f"ε = {eps:g}: {line}"))
        out.append(EpsilonTrials(eps, tuple(falsify.run_planned(planned, say, **search_kw))))
    return out


def _fastest(trials: Sequence[falsify.Trial]) -> falsify.Trial:
    """The trial with the cheapest first counterexample (the first such in method and trial order)."""
    hits = [t for t in trials if t.counterexamples and t.first_episode_equivalents is not None]
    return min(hits, key=lambda t: t.first_episode_equivalents)


def budget_unit(results: Sequence[EpsilonTrials]) -> str:
    """What ``--budget`` counts for these trials: episodes for the population searches, episode-equivalents
    for the beam methods (:mod:`benchmarks.falsify`)."""
    every = [t for r in results for t in r.trials]
    if all(t.counts_episodes for t in every):
        return "episodes"
    return "episode-equivalents" if not any(t.counts_episodes for t in every) else \
        "episodes (episode-equivalents for beams)"


def headline(results: Sequence[EpsilonTrials], setting: Setting) -> str:
    """One sentence from the trials: the largest ε with a counterexample, the method that found it first
    and how to replay it; else the lowest robustness found, where and at what cost."""
    req = f"`{setting.requirement}`"
    unit = budget_unit(results)
    broken = [r for r in results if any(t.counterexamples for t in r.trials)]
    if broken:
        level = max(broken, key=lambda r: r.epsilon)
        best = _fastest(level.trials)
        group = level.by_method()[best.method]
        hits = sum(t.first_counterexample is not None for t in group)
        cx = best.counterexamples[0]
        text = (f"{setting.noise}, {req} at ε = {level.epsilon:g} is broken by {best.method} after "
                f"{best.first_episode_equivalents:.3g} episode-equivalents (seed {best.seed}; replay: "
                f"`mcverify replay {cx.run_dir} {cx.episode_id}`); {hits} of {len(group)} {best.method} trials broke "
                f"it within {setting.budget} {unit}.")
    else:
        pairs = [(t.min_robustness, r.epsilon, t) for r in results for t in r.trials
                 if not math.isnan(t.min_robustness)]
        if not pairs:
            return f"{setting.noise[0].upper()}{setting.noise[1:]}, no trial evaluated a robustness."
        low, eps, t = min(pairs, key=lambda p: p[0])
        text = (f"{setting.noise}, no trial broke {req} at any ε within {setting.budget} {unit}; the lowest "
                f"robustness found at ε = {eps:g} is {falsify.compact(low)} ({t.method}, seed {t.seed}) after "
                f"{t.episode_equivalents:.3g} episode-equivalents.")
    return text[0].upper() + text[1:]


def table(results: Sequence[EpsilonTrials]) -> list[str]:
    """One row per level and method (:func:`benchmarks.falsify.summarise`)."""
    lines = ["| ε | method | trials | falsified (95% CI) | median ep-eq to 1st, all trials | lowest robustness | "
             "median lowest robustness | lowest robustness per trial |",
             "|---:|---|---:|---|---:|---:|---:|---|"]
    for r in results:
        for method, group in r.by_method().items():
            s = falsify.summarise(group)
            lines.append(f"| {r.epsilon:g} | {method} | {s.trials} | {s.successes}/{s.trials} [{s.low:.2f}, "
                         f"{s.high:.2f}] | {falsify.cost_text(s.median_eq_all)} | {falsify.compact(s.min_robustness)} "
                         f"| {falsify.compact(statistics.median(s.lowest))} | "
                         f"{', '.join(falsify.compact(x) for x in s.lowest)} |")
    return lines


def markdown(results: Sequence[EpsilonTrials], setting: Setting, *, command: str, figure_path: Path | None,
             replays: Sequence[falsify.ReplayCheck] | None = None) -> str:
    """The generated section (between its markers)."""
    req = reqs.requirement(setting.requirement)
    trials = len(next(iter(results[0].by_method().values()))) if results and results[0].trials else 0
    seeds = sorted({t.seed for r in results for t in r.trials})
    seed_text = f"seeds {seeds[0]}..{seeds[-1]}" if len(seeds) > 1 else f"seed {seeds[0] if seeds else '–'}"
    body = [
        "## Worst case against ε (`python -m benchmarks.worst_case`)", "",
        section.provenance_line(command), "",
        f"Target `{setting.source}`, requirement `{req.name}` ({req.statement}; robustness negative iff violated), "
        f"{setting.noise}. Per level ε (`--set barrier.epsilon=ε`) and method, {trials} "
        f"search{'es' if trials != 1 else ''} ({seed_text}, search and noise), each with a budget of "
        f"{setting.budget} {budget_unit(results)} and stopping at its first counterexample. Falsified: trials with a "
        "counterexample within the budget, with the exact 95% Clopper-Pearson interval of the rate. Cost to the "
        "first counterexample in episode-equivalents (control steps simulated up to and including its episode over "
        "a whole episode's), the median over all trials with a failed trial counted as beyond the budget. Lowest "
        "robustness: the lowest over the trials, the median of each trial's lowest, and each trial's lowest in seed "
        "order (two significant digits, sign kept).", "",
        f"**Headline.** {headline(results, setting)}", "",
        *table(results), "",
        (f"Figure: `{figure_path}` (ε across; left, each trial's lowest robustness a point, a counterexample a "
         "cross below the line at 0, the median per method a line; right, each trial's episode-equivalents to its "
         "first counterexample, a trial without one a triangle at the top)." if figure_path else
         "Figure: not drawn."), "",
        falsify.replay_sentence(replays),
    ]
    return section.wrap(NAME, "\n".join(body))


def figure(results: Sequence[EpsilonTrials], setting: Setting, path: Path) -> Path:
    """Two panels against ε: each trial's lowest robustness (points; crosses for counterexamples) with the
    median per method (line) and the line at 0, on a symmetric-log axis so that metres and hundredths both
    show; and each trial's cost to its first counterexample (log axis; a trial without one drawn at the top),
    which separates the methods where the requirement's robustness is a sign (``theorem5_certified``)."""
    from matplotlib.ticker import FormatStrFormatter  # noqa: PLC0415

    from mcverify.falsify.report import label_symlog_axis  # noqa: PLC0415 - matplotlib only when drawing
    from mcverify.reporting.figure_common import save, subplots  # noqa: PLC0415

    methods_ = list(dict.fromkeys(t.method for r in results for t in r.trials))
    levels = [r.epsilon for r in results]
    spread = 0.15 * (min(b - a for a, b in zip(sorted(levels), sorted(levels)[1:], strict=False)) if len(levels) > 1
                     else 0.1)
    fig, (ax, cost_ax) = subplots(1, 2, figsize=(10.0, 4.2))
    for k, method in enumerate(methods_):
        colour, shift = f"C{k}", spread * (k - (len(methods_) - 1) / 2) / max(1, len(methods_))
        _robustness_points(ax, results, method, colour, shift)
        _cost_points(cost_ax, results, method, colour, shift, _top(results, setting))
    ax.plot([], [], "o", mfc="none", color="0.4", label="a trial's lowest robustness")
    ax.plot([], [], "X", color="0.4", mec="k", mew=0.5, label="a counterexample (below 0)")
    ax.axhline(0.0, color="k", lw=0.8, ls="--")
    ax.set_yscale("symlog", linthresh=0.05)
    ax.margins(y=0.08)
    label_symlog_axis(ax)
    ax.set_ylabel(f"lowest robustness ({setting.requirement})")
    cost_ax.set_yscale("log")
    cost_ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    cost_ax.yaxis.set_minor_formatter(FormatStrFormatter("%g"))
    cost_ax.tick_params(axis="y", which="minor", labelsize=7)
    cost_ax.set_ylabel("episode-equivalents to the first counterexample")
    cost_ax.plot([], [], "^", color="0.4", label="none within the budget")
    for a in (ax, cost_ax):
        a.set_xticks(levels)
        a.set_xticklabels([f"{e:g}" for e in levels])
        a.set_xlabel("VL-CBF level ε (barrier.epsilon)")
        a.legend(loc="best", fontsize=7)
        a.grid(alpha=0.3)
    fig.suptitle(f"{Path(setting.source).name}: worst case of `{setting.requirement}` against ε, {setting.noise}; "
                 f"budget {setting.budget} {budget_unit(results)} per trial", fontsize=9)
    fig.tight_layout()
    save(fig, path)
    return Path(path)


def _robustness_points(ax: Any, results: Sequence[EpsilonTrials], method: str, colour: str, shift: float) -> None:
    xs, meds = [], []
    for r in results:
        lows = [t.min_robustness for t in r.by_method().get(method, []) if not math.isnan(t.min_robustness)]
        if not lows:
            continue
        safe = [x for x in lows if x >= 0.0]
        broken = [x for x in lows if x < 0.0]
        ax.plot([r.epsilon + shift] * len(safe), safe, "o", mfc="none", color=colour, ms=5, alpha=0.8)
        ax.plot([r.epsilon + shift] * len(broken), broken, "X", color=colour, mec="k", mew=0.5, ms=7)
        xs.append(r.epsilon + shift)
        meds.append(statistics.median(lows))
    ax.plot(xs, meds, "-", color=colour, lw=1.5, label=f"{method}: median of the trials")


def _top(results: Sequence[EpsilonTrials], setting: Setting) -> float:
    """Where a trial without a counterexample is drawn: at the budget when it is counted in
    episode-equivalents, else above the dearest trial."""
    if budget_unit(results) == "episode-equivalents":
        return float(setting.budget)
    return max((t.episode_equivalents for r in results for t in r.trials), default=1.0) * 1.5


def _cost_points(ax: Any, results: Sequence[EpsilonTrials], method: str, colour: str, shift: float,
                 top: float) -> None:
    xs, meds = [], []
    for r in results:
        group = r.by_method().get(method, [])
        if not group:
            continue
        firsts = [t.first_episode_equivalents for t in group]
        found = [x for x in firsts if x is not None]
        ax.plot([r.epsilon + shift] * len(found), found, "X", color=colour, mec="k", mew=0.5, ms=7)
        ax.plot([r.epsilon + shift] * (len(firsts) - len(found)), [top] * (len(firsts) - len(found)), "^",
                color=colour, ms=6)
        xs.append(r.epsilon + shift)
        meds.append(statistics.median(top if x is None else x for x in firsts))
    ax.plot(xs, meds, "-", color=colour, lw=1.5, label=f"{method}: median (none counted at the top)")


def _parser() -> argparse.ArgumentParser:
    p = section.parser(NAME, "The lowest robustness (or the first counterexample) per search method against the "
                             "VL-CBF level ε.")
    p.add_argument("target", type=Path, help="a campaign file with [falsify] (e.g. "
                   "campaigns/falsify_vlcbf_eps03_paper_noise.toml); its barrier.epsilon is set per level")
    p.add_argument("--eps", default=DEFAULT_EPS, help=f"comma-separated levels in [0, 1) (default {DEFAULT_EPS})")
    p.add_argument("--methods", default="cma,random", help="comma-separated methods (default cma,random)")
    p.add_argument("--trials", type=positive_int, default=5, help="independent trials per method and level")
    p.add_argument("--budget", type=positive_int, default=40, help="episodes per trial")
    p.add_argument("--seed", type=nonneg_int, default=0, help="seed of the first trial (then seed+1, ...)")
    p.add_argument("--out-dir", type=Path, default=Path("results/bench-worst-case"),
                   help="trial folders (DIR/eps-<ε>/...) and the figure")
    p.add_argument("--workers", type=positive_int, default=None, help="worker processes")
    p.add_argument("--figure", type=Path, default=None, metavar="PNG", help=f"the figure (default DIR/{FIGURE})")
    p.add_argument("--replay", action="store_true",
                   help="re-simulate every counterexample found and check it bit for bit (as mcverify replay)")
    section.add_output_options(p)
    return p


def say(line: str) -> None:
    """A progress line on stderr (stdout carries the section)."""
    print(line, file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the trials at every level, draw the figure and write (or print) the generated section."""
    def body() -> int:
        from mcverify.campaign import executors  # noqa: PLC0415 - keep --help fast

        args = _parser().parse_args(argv)
        levels = parse_eps(args.eps)
        chosen = falsify.chosen_methods(args.methods)
        campaign = check_target(args.target)
        setting = Setting(str(args.target), campaign.falsify.requirement, noise_phrase(campaign), args.budget)
        results = run(args.target, levels, chosen, args.trials, args.budget, args.seed, args.out_dir, progress=say,
                      make_executor=lambda: executors.make_executor("local", workers=args.workers))
        path = figure(results, setting, args.figure or args.out_dir / FIGURE)
        say(f"figure: {path}")
        replays = (falsify.replay_counterexamples([t for r in results for t in r.trials], progress=say)
                   if args.replay else None)
        section.publish(NAME, markdown(results, setting, command=section.command(NAME, argv), figure_path=path,
                                       replays=replays), args)
        return 0

    return section.run_main(NAME, body)


if __name__ == "__main__":
    sys.exit(main())
