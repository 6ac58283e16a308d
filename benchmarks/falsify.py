"""``python -m benchmarks.falsify``: ARCH-COMP-style comparison of the search methods.

For every target campaign and method, ``trials`` independent searches (search seeds ``seed``,
``seed + 1``, ...; each seed also sets the episodes' noise) with the same episode budget, each
stopping at its first counterexample. Reported per target and method (:func:`summarise`): the success
rate with its exact (Clopper-Pearson) interval; the cost to the first counterexample in episodes and in
episode-equivalents (control steps simulated up to and including the counterexample's episode over a
whole episode's, the search's own cost column: episodes that stop early cost less); each trial's lowest
robustness (and lowest guide value, for a guided target); per target, issue 16's verdict
(:func:`goal_verdict`): is the target rare for random search, and does a method meet the goal there.
With ``--replay`` every counterexample found is re-simulated and checked bit for bit
(:func:`replay_counterexamples`). Written as a generated section of ``results/BENCHMARKS.md``, named by
``--section`` (so the adversary targets keep a section apart from the default targets'); the search
folders stay under ``out_dir``.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import re
import statistics
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import tomllib

from benchmarks import section
from mcverify import files, store
from mcverify.analysis import stats
from mcverify.campaign.spec import apply_settings, load_campaign
from mcverify.cli.options import nonneg_int, positive_int
from mcverify.errors import RunError, UserError
from mcverify.falsify import methods, search

NAME = "falsify"
BEGIN_MARK, END_MARK = section.markers(NAME)
#: What ``--section`` accepts: the name goes into the section's markers.
SECTION_NAME = re.compile(r"[a-z_]+")


class Counterexample(NamedTuple):
    """A violating episode, as ``mcverify replay RUN_DIR EPISODE_ID`` takes it (a generation folder)."""

    run_dir: Path
    episode_id: int


@dataclass(frozen=True)
class Trial:
    target: str
    method: str
    seed: int
    episodes: int
    first_counterexample: int | None
    min_robustness: float
    curve: tuple[float, ...] = ()
    #: Control steps the whole search simulated over those of a whole episode of the target.
    episode_equivalents: float = math.nan
    #: The same up to and including the first counterexample's episode (None: no counterexample).
    first_episode_equivalents: float | None = None
    guide: str = ""  # the target's [falsify] guide ("": none, the method was told the robustness)
    min_guide: float = math.nan
    counterexamples: tuple[Counterexample, ...] = ()


class PlannedTrial(NamedTuple):
    """One checked search of :func:`plan_trials`, not yet run: its target, method, trial number, search
    and folder (``out_dir/<target>/<method>/trial-NN``)."""

    target: str
    method: str
    number: int
    config: search.SearchConfig
    where: Path


def run_trials(
    targets: Sequence[Path], methods_: Sequence[str], trials: int, budget: int, seed: int, out_dir: Path,
    settings: Sequence[str] = (), progress: Callable[[str], None] | None = None, **search_kw: Any,
) -> list[Trial]:
    """Every (target, method, trial) search; a finished trial folder is re-read, an unfinished one
    resumed, so a killed benchmark continues where it stopped. Every search is checked (and every
    stored trial folder matched against its search) before the first one runs."""
    planned = plan_trials(targets, methods_, trials, budget, seed, out_dir, settings)
    return run_planned(planned, progress, **search_kw)


def plan_trials(targets: Sequence[Path], methods_: Sequence[str], trials: int, budget: int, seed: int,
                out_dir: Path, settings: Sequence[str] = ()) -> list[PlannedTrial]:
    """The searches of :func:`run_trials`, each checked (and its stored trial folder, if any, matched
    against it) without running any: a bad target or a foreign folder is one RunError line."""
    planned = []
    for path in targets:
        campaign = load_campaign(path, settings=settings)
        raw = apply_settings(tomllib.loads(Path(path).read_text(encoding="utf-8")), settings)
        if "falsify" not in raw:
            raise RunError(f"{path}: no [falsify] table (bounds of the search space); see docs/falsification.md "
                           "or campaigns/falsify_*.toml")
        raw["falsify"] = {**raw["falsify"], "stop_at_first": True}
        for method in methods_:
            for t in range(trials):
                config = search.SearchConfig(copy.deepcopy(raw), str(path), method, budget, seed + t,
                                             campaign.falsify.requirement)
                search.check(config)
                where = out_dir / campaign.name / method / f"trial-{t:02d}"
                if (where / search.CONFIG).is_file():
                    _check_same_trial(where, config)
                planned.append(PlannedTrial(campaign.name, method, t, config, where))
    return planned


def run_planned(planned: Sequence[PlannedTrial], progress: Callable[[str], None] | None = None,
                **search_kw: Any) -> list[Trial]:
    """Run (or re-read, or resume) the searches of :func:`plan_trials`, in order."""
    out: list[Trial] = []
    for name, method, t, config, where in planned:
        if (where / search.CONFIG).is_file():
            res = search.resume(where, **search_kw)
        else:
            res = search.start(config, where, **search_kw)
        trial = trial_of(name, res)
        out.append(trial)
        if progress is not None:
            progress(f"{name} {method} trial {t}: "
                     + (f"counterexample after {res.first_counterexample} episodes "
                        f"({trial.first_episode_equivalents:.3g} episode-equivalents)" if res.first_counterexample
                        else f"none in {res.episodes}, min robustness {res.min_robustness:.4g}"))
    return out


def trial_of(target: str, res: search.SearchResult) -> Trial:
    """A finished search as one trial: its costs (the search's cost columns) and its counterexamples."""
    first = res.first_counterexample
    guides = [e.guide for e in res.evaluations if not math.isnan(e.guide)]
    found = tuple(Counterexample(res.out_dir / search.GENERATIONS / f"g{e.generation:03d}", int(e.row["episode_id"]))
                  for e in res.evaluations if e.robustness < 0.0)
    return Trial(target, res.config.method, res.config.seed, res.episodes, first, res.min_robustness,
                 tuple(e.robustness for e in res.evaluations), res.episode_equivalents(),
                 None if first is None else res.episode_equivalents(first), res.space.guide or "",
                 min(guides) if guides else math.nan, found)


def _check_same_trial(where: Path, config: search.SearchConfig) -> None:
    """A stored trial folder is re-read or resumed only if it holds this very search; otherwise its
    numbers would be reported under a command that did not make them."""
    stored = search.SearchConfig.from_json(store.read_json(where / search.CONFIG))
    differ = [f"{name} {getattr(stored, name)}, not {getattr(config, name)}"
              for name in ("method", "budget", "seed", "requirement") if getattr(stored, name) != getattr(config, name)]
    if json.loads(json.dumps(stored.raw)) != json.loads(json.dumps(config.raw)):
        differ.append("another campaign content or --set")
    if differ:
        raise RunError(f"{where} holds a trial of another search ({'; '.join(differ)}); give another --out-dir "
                       "or remove that folder")


def draw_curves(trials: Sequence[Trial], out_dir: Path) -> list[Path]:
    """Per target, robustness against episodes of every method's first trial:
    ``out_dir/<target>/robustness.png``."""
    from mcverify.falsify import report  # noqa: PLC0415 - matplotlib only here

    paths = []
    for target in dict.fromkeys(t.target for t in trials):
        firsts = {}
        for t in trials:
            if t.target == target and t.method not in firsts:
                firsts[t.method] = t.curve
        path = out_dir / target / "robustness.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        report.robustness_curves({f"{m} (seed {min(t.seed for t in trials)})": c for m, c in firsts.items()}, path,
                                 "target requirement")
        paths.append(path)
    return paths


#: Issue 16's definition of a rare target: random search's median to the first counterexample is at
#: least this many episodes (or it fails within the budget).
RARE_MEDIAN_EPISODES = 50
#: The goal on a rare target: a method succeeds in at least this share of its trials ...
GOAL_SUCCESS_SHARE = 0.9
#: ... with a median to the first counterexample at most this share of random search's.
GOAL_MEDIAN_SHARE = 0.1


def median_to_first(group: Sequence[Trial]) -> float:
    """Median episodes to the first counterexample over *all* trials, a failed trial counting as
    beyond its budget (``inf``): the median exceeds the budget when half or more of the trials failed."""
    return statistics.median(math.inf if t.first_counterexample is None else t.first_counterexample for t in group)


def goal_verdict(trials: Sequence[Trial], target: str, budget: int) -> str:
    """One sentence for ``target``: rare or not for random search (median to the first counterexample,
    failures counted as beyond the budget, at least :data:`RARE_MEDIAN_EPISODES`), and on a rare target
    which methods meet the goal (successes in at least 90 % of the trials, median at most a tenth of
    random search's), fail it, or cannot be judged (random's median lies beyond the budget, so a tenth
    of it is known only to exceed budget / 10)."""
    by_method: dict[str, list[Trial]] = {}
    for t in trials:
        if t.target == target:
            by_method.setdefault(t.method, []).append(t)
    if "random" not in by_method:
        return f"{target}: no random-search trials, so its rarity is not measured."
    base = median_to_first(by_method["random"])
    beyond = math.isinf(base)
    base_text = f"beyond the budget of {budget}" if beyond else f"{base:g}"
    if not beyond and base < RARE_MEDIAN_EPISODES:
        return (f"{target}: not rare (random search's median to the first counterexample {base_text} "
                f"< {RARE_MEDIAN_EPISODES}); the goal applies to rare targets only.")
    bound = (budget if beyond else base) * GOAL_MEDIAN_SHARE
    verdicts = []
    for method, group in by_method.items():
        if method == "random":
            continue
        hits = sum(t.first_counterexample is not None for t in group)
        med = median_to_first(group)
        med_text = "beyond the budget" if math.isinf(med) else f"{med:g}"
        if hits < GOAL_SUCCESS_SHARE * len(group) or (not beyond and med > bound):
            word = "not met"
        elif med <= bound:
            word = "met"
        else:
            word = "undecided"
        verdicts.append(f"{method} {word} ({hits}/{len(group)}, median {med_text})")
    return (f"{target}: rare (random search's median {base_text}); goal (>= {GOAL_SUCCESS_SHARE:.0%} of trials, "
            f"median <= {GOAL_MEDIAN_SHARE:g} x random's, "
            + (f"known only to exceed {bound:g}" if beyond else f"i.e. <= {bound:g}") + "): "
            + ("; ".join(verdicts) if verdicts else "no other method ran") + ".")


class MethodSummary(NamedTuple):
    """One (target, method)'s trials in numbers; costs to the first counterexample over the successful
    trials (None: none succeeded), except ``median_eq_all`` (every trial, a failure beyond the budget)."""

    trials: int
    successes: int
    rate: float
    low: float  # 95% Clopper-Pearson interval of the success rate
    high: float
    median_episodes: float | None
    mean_eq: float | None
    median_eq: float | None
    median_eq_all: float
    min_robustness: float
    episodes_spent: int
    eq_spent: float
    lowest: tuple[float, ...]  # each trial's lowest robustness, in trial order
    lowest_guide: tuple[float, ...]  # each trial's lowest guide value (NaN: no guide)
    eq_to_first: tuple[float | None, ...]  # each trial's episode-equivalents to its first counterexample


def summarise(group: Sequence[Trial]) -> MethodSummary:
    """The trials of one target and method (in trial order) in numbers."""
    hits = [t for t in group if t.first_counterexample is not None]
    rate = stats.rate_summary(len(hits), len(group), 0.95, "clopper-pearson")
    eqs = [t.first_episode_equivalents for t in hits if t.first_episode_equivalents is not None]
    return MethodSummary(
        len(group), len(hits), rate["rate"], rate["low"], rate["high"],
        statistics.median(t.first_counterexample for t in hits) if hits else None,
        statistics.fmean(eqs) if eqs else None, statistics.median(eqs) if eqs else None,
        median_eq_to_first(group), min(t.min_robustness for t in group), sum(t.episodes for t in group),
        sum(t.episode_equivalents for t in group), tuple(t.min_robustness for t in group),
        tuple(t.min_guide for t in group), tuple(t.first_episode_equivalents for t in group))


def median_eq_to_first(group: Sequence[Trial]) -> float:
    """:func:`median_to_first` in episode-equivalents: a failed trial counts as beyond the budget (``inf``)."""
    return statistics.median(math.inf if t.first_episode_equivalents is None else t.first_episode_equivalents
                             for t in group)


def compact(x: float | None) -> str:
    """Two significant digits, the sign kept (a tiny negative robustness reads -1e-09, never 0 or
    +0.000); ``–`` for None."""
    return "–" if x is None else f"{x:.2g}"


def cost_text(x: float | None) -> str:
    """A cost in episode-equivalents: three significant digits, ``beyond the budget`` for ``inf``, ``–`` for None."""
    if x is None:
        return "–"
    return "beyond the budget" if math.isinf(x) else f"{x:.3g}"


class ReplayCheck(NamedTuple):
    """One counterexample re-simulated: ``problem`` is empty when it reproduced bit for bit."""

    trial: Trial
    counterexample: Counterexample
    problem: str = ""


def replay_counterexamples(trials: Sequence[Trial], progress: Callable[[str], None] | None = None
                           ) -> list[ReplayCheck]:
    """Re-simulate every counterexample of every trial as ``mcverify replay`` does, checking its stored
    row bit for bit; the replayed trajectories go to ``TRIAL/replay/gNNN``, beside the generations."""
    from mcverify.campaign import replay  # noqa: PLC0415 - simulation only with --replay

    checks = []
    for trial in trials:
        for cx in trial.counterexamples:
            try:
                replay.replay(cx.run_dir, cx.episode_id, out_dir=cx.run_dir.parent.parent / "replay" / cx.run_dir.name)
                problem = ""
            except (replay.ReplayMismatch, UserError) as err:
                problem = str(err)
            checks.append(ReplayCheck(trial, cx, problem))
            if progress is not None:
                progress(f"replay {cx.run_dir} {cx.episode_id}: " + (problem or "bit for bit"))
    return checks


def replay_sentence(checks: Sequence[ReplayCheck] | None) -> str:
    """What the section says about the replays: all reproduced, or which did not (and why)."""
    if checks is None:
        return "Counterexamples not replayed (run with `--replay` to re-simulate every one)."
    if not checks:
        return "Replay: no counterexample was found, so none was replayed."
    bad = [c for c in checks if c.problem]
    if not bad:
        return f"Replay: {len(checks)} of {len(checks)} counterexamples replay bit for bit (`mcverify replay`)."
    named = "; ".join(f"{c.trial.target} {c.trial.method} seed {c.trial.seed}, `mcverify replay "
                      f"{c.counterexample.run_dir} {c.counterexample.episode_id}`: {c.problem}" for c in bad)
    return (f"Replay: {len(checks) - len(bad)} of {len(checks)} counterexamples replay bit for bit; "
            f"these do not: {named}.")


def markdown(trials: Sequence[Trial], *, budget: int, command: str, name: str = NAME,
             replays: Sequence[ReplayCheck] | None = None) -> str:
    begin, end = markers(name)
    keys = list(dict.fromkeys((t.target, t.method) for t in trials))
    groups = {key: [t for t in trials if (t.target, t.method) == key] for key in keys}
    summaries = {key: summarise(group) for key, group in groups.items()}
    guided = any(t.guide for t in trials)
    lines = [begin, "", "## Falsification benchmark", "",
             section.provenance_line(command), "",
             "Each trial is a search with its own seed (search and noise), budget "
             f"{budget} episodes, stopping at its first counterexample. Success: a counterexample within the "
             "budget (95% Clopper-Pearson interval). Cost to the first counterexample in episodes and in "
             "episode-equivalents (ep-eq: control steps simulated up to and including the counterexample's "
             "episode over a whole episode's; an episode that stops early costs less); mean and median over "
             "the successful trials, and the median over all trials with a failed trial counted as beyond "
             "the budget.", "",
             "| target | method | trials | successes | success rate (95% CI) | mean ep-eq to 1st | "
             "median ep-eq to 1st | median ep-eq to 1st, all trials | median episodes to 1st | "
             "min robustness | episodes spent | ep-eq spent |",
             "|---|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for (target, method), s in summaries.items():
        med = "–" if s.median_episodes is None else f"{s.median_episodes:g}"
        lines.append(f"| {target} | {method} | {s.trials} | {s.successes} | {s.rate:.2f} [{s.low:.2f}, {s.high:.2f}] "
                     f"| {cost_text(s.mean_eq)} | {cost_text(s.median_eq)} | {cost_text(s.median_eq_all)} | {med} | "
                     f"{s.min_robustness:.4g} | {s.episodes_spent} | {s.eq_spent:.4g} |")
    lines += ["", "Per trial, in seed order from the first seed (– : no counterexample): ep-eq to the first "
              "counterexample and the lowest robustness reached"
              + (" and the lowest value of the guide the search was steered by" if guided else "") + ":", "",
              "| target | method | ep-eq to 1st | lowest robustness |" + (" lowest guide |" if guided else ""),
              "|---|---|---|---|" + ("---|" if guided else "")]
    for (target, method), s in summaries.items():
        guide = groups[(target, method)][0].guide
        lines.append(f"| {target} | {method} | {', '.join(cost_text(x) for x in s.eq_to_first)} | "
                     f"{', '.join(compact(x) for x in s.lowest)} |"
                     + (f" {guide or 'none'}: {', '.join(compact(x) for x in s.lowest_guide)} |" if guided else ""))
    lines += ["", replay_sentence(replays), "",
              "Issue 16's goal, per target (medians over all trials, a failed trial counting as beyond the "
              "budget):", ""]
    lines += [f"- {goal_verdict(trials, target, budget)}" for target in dict.fromkeys(t.target for t in trials)]
    lines += ["", end, ""]
    return "\n".join(lines)


def markers(name: str) -> tuple[str, str]:
    """The markers of section ``name``: the default section's are every benchmark's; another one says it
    is made by this benchmark with ``--section name``."""
    if name == NAME:
        return BEGIN_MARK, END_MARK
    return (f"<!-- benchmarks.{name}:begin (generated by python -m benchmarks.falsify --section {name}; edits "
            "inside are overwritten) -->", f"<!-- benchmarks.{name}:end -->")


def check_section_name(name: str) -> str:
    """``name`` if it can name this benchmark's section: lower-case letters and ``_``, and not the section of
    another benchmark (which it would overwrite)."""
    if not SECTION_NAME.fullmatch(name):
        raise RunError(f"--section {name!r}: lower-case letters and _ only (e.g. falsify_adversary)")
    if name != NAME and (Path(__file__).parent / f"{name}.py").is_file():
        raise RunError(f"--section {name}: that is the section of python -m benchmarks.{name}; choose another name")
    return name


def write_section(path: Path, text: str, name: str = NAME) -> None:
    """Replace section ``name`` of ``path`` (or append it), keeping the rest of the file."""
    begin, end = markers(name)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    files.replace_section(path, text, begin, end)


DEFAULT_TARGETS = (
    "campaigns/falsify_mpcdc_table4b.toml",
    "campaigns/falsify_vlcbf_eps0_noise2.toml",
    "campaigns/falsify_theorem5_opposing.toml",
    "campaigns/falsify_theorem5_certified_opposing.toml",
    "campaigns/falsify_vlcbf_eps03_paper_noise.toml",
)
ALL_METHODS = methods.METHODS


def chosen_methods(text: str) -> list[str]:
    """The methods of ``--methods`` (comma-separated), each a known one; otherwise one RunError line."""
    chosen = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in chosen if m not in methods.METHODS]
    if bad or not chosen:
        raise RunError(f"--methods: unknown {', '.join(bad) or '(none given)'}; "
                       f"choose from {', '.join(methods.METHODS)}")
    return chosen


def _parser() -> argparse.ArgumentParser:
    p = section.parser("falsify", "Success rate and median episodes to the first counterexample per search method "
                                  "and target.")
    p.add_argument("targets", nargs="*", type=Path,
                   help="campaign files with [falsify] (default: the five benchmark targets falsify_mpcdc_table4b, "
                   "falsify_vlcbf_eps0_noise2, falsify_theorem5_opposing, falsify_theorem5_certified_opposing, "
                   "falsify_vlcbf_eps03_paper_noise in campaigns/)")
    p.add_argument("--methods", default="cma,cross-entropy,random", help="comma-separated methods")
    p.add_argument("--trials", type=positive_int, default=10, help="independent trials per method and target")
    p.add_argument("--budget", type=positive_int, default=100, help="episodes per trial")
    p.add_argument("--seed", type=nonneg_int, default=0, help="seed of the first trial (then seed+1, ...)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="settings",
                   help="override a model parameter of every target (repeatable)")
    p.add_argument("--out-dir", type=Path, default=Path("results/bench-falsify"), help="search folders")
    p.add_argument("--workers", type=positive_int, default=None, help="worker processes")
    p.add_argument("--section", default=NAME, metavar="NAME",
                   help=f"name of the generated section ([a-z_]+; default {NAME}), e.g. falsify_adversary for "
                   "the adversary targets, so that each set of targets keeps its own section")
    p.add_argument("--replay", action="store_true",
                   help="re-simulate every counterexample found and check it bit for bit (as mcverify replay)")
    section.add_output_options(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the trials and write (or print) the generated section."""
    def body() -> int:
        from mcverify.campaign import executors  # noqa: PLC0415 - keep --help fast

        args = _parser().parse_args(argv)
        name = check_section_name(args.section)
        chosen = chosen_methods(args.methods)
        targets = args.targets or [Path(t) for t in DEFAULT_TARGETS]
        for t in targets:
            if not Path(t).is_file():
                raise RunError(f"campaign file not found: {t}")
        trials = run_trials(
            targets, chosen, args.trials, args.budget, args.seed, args.out_dir, settings=args.settings,
            progress=lambda line: print(line, file=sys.stderr),
            make_executor=lambda: executors.make_executor("local", workers=args.workers),
        )
        for path in draw_curves(trials, args.out_dir):
            print(f"figure: {path}", file=sys.stderr)
        replays = (replay_counterexamples(trials, progress=lambda line: print(line, file=sys.stderr))
                   if args.replay else None)
        text = markdown(trials, budget=args.budget, command=section.command(NAME, argv), name=name, replays=replays)
        print(text)
        if not args.no_write:
            write_section(args.write, text, name)
            print(f"written: {args.write} (section benchmarks.{name})", file=sys.stderr)
        return 0

    return section.run_main(NAME, body)


if __name__ == "__main__":
    sys.exit(main())
