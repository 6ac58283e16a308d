"""``python -m benchmarks.falsify``: ARCH-COMP-style comparison of the search methods.

For every target campaign and method, ``trials`` independent searches (search seeds ``seed``,
``seed + 1``, ...; each seed also sets the episodes' noise) with the same episode budget, each
stopping at its first counterexample. Reported per target and method: the success rate with its
exact (Clopper-Pearson) interval, the median number of episodes to the first counterexample over
the successful trials, and the smallest robustness reached; per target, issue 16's verdict
(:func:`goal_verdict`): is the target rare for random search, and does a method meet the goal there.
Written as a generated section of ``results/BENCHMARKS.md``; the search folders stay under ``out_dir``
(replayable).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import statistics
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomllib

from benchmarks import section
from mcverify import store
from mcverify.analysis import stats
from mcverify.campaign.spec import apply_settings, load_campaign
from mcverify.cli.options import nonneg_int, positive_int
from mcverify.errors import RunError
from mcverify.falsify import methods, search

BEGIN_MARK, END_MARK = section.markers("falsify")


@dataclass(frozen=True)
class Trial:
    target: str
    method: str
    seed: int
    episodes: int
    first_counterexample: int | None
    min_robustness: float
    curve: tuple[float, ...] = ()


def run_trials(
    targets: Sequence[Path], methods_: Sequence[str], trials: int, budget: int, seed: int, out_dir: Path,
    settings: Sequence[str] = (), progress: Callable[[str], None] | None = None, **search_kw: Any,
) -> list[Trial]:
    """Every (target, method, trial) search; a finished trial folder is re-read, an unfinished one
    resumed, so a killed benchmark continues where it stopped. Every search is checked (and every
    stored trial folder matched against its search) before the first one runs."""
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
                planned.append((campaign.name, method, t, config, where))
    out: list[Trial] = []
    for name, method, t, config, where in planned:
        if (where / search.CONFIG).is_file():
            res = search.resume(where, **search_kw)
        else:
            res = search.start(config, where, **search_kw)
        out.append(Trial(name, method, config.seed, res.episodes, res.first_counterexample,
                         res.min_robustness, tuple(e.robustness for e in res.evaluations)))
        if progress is not None:
            progress(f"{name} {method} trial {t}: "
                     + (f"counterexample after {res.first_counterexample} episodes" if res.first_counterexample
                        else f"none in {res.episodes}, min robustness {res.min_robustness:.4g}"))
    return out


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


def markdown(trials: Sequence[Trial], *, budget: int, command: str) -> str:
    lines = [BEGIN_MARK, "", "## Falsification benchmark", "",
             section.provenance_line(command), "",
             "Each trial is a search with its own seed (search and noise), budget "
             f"{budget} episodes, stopping at its first counterexample. Success: a counterexample within the "
             "budget (95% Clopper-Pearson interval); median episodes to the first counterexample over the "
             "successful trials.", "",
             "| target | method | trials | successes | success rate (95% CI) | median episodes to 1st | "
             "min robustness | episodes spent |", "|---|---|---:|---:|---|---:|---:|---:|"]
    keys = list(dict.fromkeys((t.target, t.method) for t in trials))
    for target, method in keys:
        group = [t for t in trials if (t.target, t.method) == (target, method)]
        hits = [t.first_counterexample for t in group if t.first_counterexample is not None]
        rate = stats.rate_summary(len(hits), len(group), 0.95, "clopper-pearson")
        med = f"{statistics.median(hits):g}" if hits else "–"
        lines.append(f"| {target} | {method} | {len(group)} | {len(hits)} | {rate['rate']:.2f} "
                     f"[{rate['low']:.2f}, {rate['high']:.2f}] | {med} | "
                     f"{min(t.min_robustness for t in group):.4g} | {sum(t.episodes for t in group)} |")
    lines += ["", "Issue 16's goal, per target (medians over all trials, a failed trial counting as beyond the "
              "budget):", ""]
    lines += [f"- {goal_verdict(trials, target, budget)}" for target in dict.fromkeys(t.target for t in trials)]
    lines += ["", END_MARK, ""]
    return "\n".join(lines)


def write_section(path: Path, text: str) -> None:
    """Replace this benchmark's section of ``path`` (or append it), keeping the rest of the file."""
    section.write("falsify", text, path)


DEFAULT_TARGETS = (
    "campaigns/falsify_mpcdc_table4b.toml",
    "campaigns/falsify_vlcbf_eps0_noise2.toml",
    "campaigns/falsify_theorem5_opposing.toml",
    "campaigns/falsify_theorem5_certified_opposing.toml",
    "campaigns/falsify_vlcbf_eps03_paper_noise.toml",
)
ALL_METHODS = methods.METHODS


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
    section.add_output_options(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the trials and write (or print) the generated section."""
    def body() -> int:
        from mcverify.campaign import executors  # noqa: PLC0415 - keep --help fast

        args = _parser().parse_args(argv)
        chosen = [m.strip() for m in args.methods.split(",") if m.strip()]
        bad = [m for m in chosen if m not in methods.METHODS]
        if bad or not chosen:
            raise RunError(f"--methods: unknown {', '.join(bad) or '(none given)'}; "
                           f"choose from {', '.join(methods.METHODS)}")
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
        text = markdown(trials, budget=args.budget, command=section.command("falsify", argv))
        print(text)
        if not args.no_write:
            write_section(args.write, text)
            print(f"written: {args.write} (section benchmarks.falsify)", file=sys.stderr)
        return 0

    return section.run_main("falsify", body)


if __name__ == "__main__":
    sys.exit(main())
