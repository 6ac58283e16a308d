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
(:func:`replay_counterexamples`); with ``--audit`` each trial's first counterexample is re-simulated on the
same error with the reference solver, IPOPT solving every problem in full (:func:`audit_counterexamples`, as
``mcverify replay --backend ipopt``), because a fast-path violation may be the solver's rather than the
controller's. Written as a generated section of ``results/BENCHMARKS.md``, named by
``--section`` (so the adversary targets keep a section apart from the default targets'); the search
folders stay under ``out_dir``.

``beam`` (:mod:`mcverify.falsify.beam`) is a method of targets with a ``[falsify.beam]`` table: trial t is
the beam search of seed ``seed + t`` (its children draws), run in ``trial-NN`` as ``mcverify falsify
--method beam`` runs it (:mod:`mcverify.falsify.beam_folder`), with ``budget`` read as its ceiling in
episode-equivalents. It simulates segments from snapshots, not episodes one by one, so its costs are in
episode-equivalents only, and its counterexample (the best final-frontier episode, when its robustness is
negative) comes after the whole search. ``random-schedules`` is its baseline at equal cost: the same table with
``branching = 1``, so the root's ``width`` children (keyed as the beam's root children, hence paired with the
beam's trial of the same seed) each run one random schedule through the window, with no selection, and restart
under the same budget. Per method the table also gives the peak resident memory of the trials
(:mod:`benchmarks.memory`).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import statistics
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import tomllib

from benchmarks import memory, section
from mcverify import files, store
from mcverify.analysis import stats
from mcverify.analysis.robustness import robustness
from mcverify.campaign.spec import apply_settings, load_campaign
from mcverify.cli.options import nonneg_int, positive_int
from mcverify.errors import RunError, UserError
from mcverify.falsify import beam, beam_folder, methods, search

NAME = "falsify"
#: The beam's baseline: its table with ``branching = 1`` (module docstring).
RANDOM_SCHEDULES = "random-schedules"
#: The methods run as beam folders.
BEAM_METHODS = (beam.BEAM, RANDOM_SCHEDULES)
#: Each trial folder's peak resident memory (:mod:`benchmarks.memory`), written when the trial ran.
PEAK_RSS = "bench-peak-rss.json"


class Counterexample(NamedTuple):
    """A violating episode, as ``mcverify replay RUN_DIR EPISODE_ID`` takes it (a generation folder)."""

    run_dir: Path
    episode_id: int

    def replay_dir(self) -> Path:
        """Where ``--replay`` writes its trajectory: ``TRIAL/replay/<folder>``, beside the trial's generations
        (``TRIAL/generations/gNNN``) or its best beam episode (``TRIAL/best``)."""
        trial = self.run_dir.parent.parent if self.run_dir.parent.name == search.GENERATIONS else self.run_dir.parent
        return trial / "replay" / self.run_dir.name

    def audit_dir(self) -> Path:
        """Where ``--audit`` writes the reference solver's trajectory: ``TRIAL/audit/<folder>``."""
        return self.replay_dir().parent.parent / "audit" / self.run_dir.name


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
    #: False for a beam trial: it simulates segments from snapshots, not episodes one by one, so ``episodes``
    #: is 0 and ``first_counterexample`` 0 when it found one; its costs are the episode-equivalents.
    counts_episodes: bool = True
    #: The largest resident set size of the process tree while the trial ran, MB (None: not measured).
    peak_rss_mb: float | None = None
    #: A beam trial's most snapshots alive at once (None: not a beam).
    peak_snapshots: int | None = None
    #: The named requirement the search falsified (its robustness is the trial's).
    requirement: str = ""


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
        for method in methods_:
            for t in range(trials):
                config = _trial_config(raw, path, method, budget, seed + t, campaign.falsify.requirement)
                where = out_dir / campaign.name / method / f"trial-{t:02d}"
                if (where / search.CONFIG).is_file():
                    _check_same_trial(where, config)
                planned.append(PlannedTrial(campaign.name, method, t, config, where))
    return planned


def _trial_config(raw: dict[str, Any], path: Path, method: str, budget: int, seed: int,
                  requirement: str) -> search.SearchConfig:
    """One trial's search, checked as ``mcverify falsify --method METHOD`` checks it (one RunError line): a
    searcher stops at its first counterexample; the beam takes the table as it is (it refuses other keys) and
    ``budget`` as its ceiling in episode-equivalents."""
    if method in BEAM_METHODS:
        table = copy.deepcopy(raw)
        if method == RANDOM_SCHEDULES and isinstance(table.get("falsify", {}).get("beam"), dict):
            table["falsify"]["beam"]["branching"] = 1
        config = search.SearchConfig(table, str(path), beam.BEAM, budget, seed, requirement)
        beam_folder.check(config)
        return config
    stopping = {**raw, "falsify": {**raw["falsify"], "stop_at_first": True}}
    config = search.SearchConfig(copy.deepcopy(stopping), str(path), method, budget, seed, requirement)
    search.check(config)
    return config


def run_planned(planned: Sequence[PlannedTrial], progress: Callable[[str], None] | None = None,
                **search_kw: Any) -> list[Trial]:
    """Run (or re-read, or resume) the searches of :func:`plan_trials`, in order. A trial that runs (or is
    resumed) is measured for its peak resident memory, kept in its folder; a re-read one reports what was
    kept (none if it finished before that was recorded)."""
    out: list[Trial] = []
    for name, method, t, config, where in planned:
        finished = _finished(where)
        with memory.PeakRss() as peak:
            if method in BEAM_METHODS:
                trial = beam_trial(name, _run_beam(config, where, finished), where, method)
            else:
                res = search.resume(where, **search_kw) if (where / search.CONFIG).is_file() else \
                    search.start(config, where, **search_kw)
                trial = trial_of(name, res)
        if finished:
            peak_mb = _stored_peak(where)
        else:
            peak_mb = peak.peak_mb
            files.write_json_atomic(where / PEAK_RSS, {"peak_rss_mb": peak_mb, "interval_s": peak.interval_s})
        trial = replace(trial, peak_rss_mb=peak_mb, requirement=config.requirement)
        out.append(trial)
        if progress is not None:
            progress(f"{name} {method} trial {t}: " + _found_text(trial))
    return out


def _found_text(trial: Trial) -> str:
    if trial.first_counterexample is None:
        spent = f"{trial.episodes}" if trial.counts_episodes else f"{trial.episode_equivalents:.3g} episode-equivalents"
        return f"none in {spent}, min robustness {trial.min_robustness:.4g}"
    eq = f"{trial.first_episode_equivalents:.3g} episode-equivalents"
    if not trial.counts_episodes:
        return f"counterexample after {eq}, robustness {trial.min_robustness:.4g}"
    return f"counterexample after {trial.first_counterexample} episodes ({eq})"


def _finished(where: Path) -> bool:
    path = where / search.CONFIG
    return path.is_file() and bool(store.read_json(path).get("finished_utc"))


def _stored_peak(where: Path) -> float | None:
    path = where / PEAK_RSS
    return store.read_json(path).get("peak_rss_mb") if path.is_file() else None


def _run_beam(config: search.SearchConfig, where: Path, finished: bool) -> beam_folder.BeamSummary:
    """A beam trial's summary: re-read when finished, resumed from its last depth file, or started."""
    if finished:
        return beam_folder.read_summary(where)
    if (where / search.CONFIG).is_file():
        return beam_folder.resume(where)
    return beam_folder.start(config, where)


def beam_trial(target: str, summary: beam_folder.BeamSummary, where: Path, method: str = beam.BEAM) -> Trial:
    """A finished beam search as one trial. Its counterexample is its best final-frontier episode when that
    violates the requirement, known only once the whole search has run, so the episode-equivalents to it are
    the search's; that episode is ``where/best`` episode 0 (what ``mcverify replay`` takes)."""
    low = summary.best_robustness
    found = low < 0.0
    eq = summary.episode_equivalents
    scores = [n.score for r in summary.restarts for n in r.frontier if not math.isinf(n.score)]
    return Trial(target, method, summary.seed, 0, 0 if found else None, low, (), eq, eq if found else None,
                 summary.spec.shape.score, min(scores) if scores else math.nan,
                 (Counterexample(where / beam_folder.BEST, 0),) if found else (), counts_episodes=False,
                 peak_snapshots=summary.peak_snapshots)


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
        for t in trials:  # a beam trial has no curve: it does not evaluate episodes one by one
            if t.target == target and t.method not in firsts and t.curve:
                firsts[t.method] = t.curve
        if not firsts:
            continue
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


def paired_sentence(trials: Sequence[Trial], target: str, method: str, baseline: str) -> str:
    """On ``target``, ``method`` against ``baseline`` trial by trial on the seeds both ran: the falsified counts,
    the medians of ep-eq to the first counterexample over all trials (a failure beyond the budget), and in how
    many pairs ``method`` reached the lower robustness, with the exact two-sided sign test (ties dropped);
    "" when either did not run on ``target``."""
    a = {t.seed: t for t in trials if t.target == target and t.method == method}
    b = {t.seed: t for t in trials if t.target == target and t.method == baseline}
    seeds = sorted(set(a) & set(b))
    if not seeds:
        return ""
    lower = sum(a[k].min_robustness < b[k].min_robustness for k in seeds)
    higher = sum(a[k].min_robustness > b[k].min_robustness for k in seeds)
    hits = [sum(g[k].first_counterexample is not None for k in seeds) for g in (a, b)]
    first = [{k: math.inf if g[k].first_episode_equivalents is None else g[k].first_episode_equivalents
              for k in seeds} for g in (a, b)]
    meds = [cost_text(statistics.median(f.values())) for f in first]
    sooner = sum(first[0][k] < first[1][k] for k in seeds)
    later = sum(first[0][k] > first[1][k] for k in seeds)
    return (f"{target}, {len(seeds)} paired seeds: {method} falsified {hits[0]}, {baseline} {hits[1]}; median ep-eq "
            f"to the first counterexample (all trials) {meds[0]} against {meds[1]}, {method} sooner in {sooner} pairs "
            f"and later in {later} (exact sign test p = {stats.mcnemar_exact_pvalue(sooner, later):.3g}); {method}'s "
            f"lowest robustness below {baseline}'s in {lower} of {len(seeds)} pairs, above in {higher} (exact sign "
            f"test p = {stats.mcnemar_exact_pvalue(lower, higher):.3g})")


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
        if not all(t.counts_episodes for t in group):
            verdicts.append(f"{method} not judged (its costs are in episode-equivalents, not episodes)")
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
    episodes_spent: int | None  # None: a beam's, which does not count episodes
    eq_spent: float
    lowest: tuple[float, ...]  # each trial's lowest robustness, in trial order
    lowest_guide: tuple[float, ...]  # each trial's lowest guide value (NaN: no guide)
    eq_to_first: tuple[float | None, ...]  # each trial's episode-equivalents to its first counterexample
    peak_rss_mb: float | None = None  # the largest over the measured trials (None: none measured)
    rss_measured: int = 0  # trials with a measured peak


def summarise(group: Sequence[Trial]) -> MethodSummary:
    """The trials of one target and method (in trial order) in numbers."""
    hits = [t for t in group if t.first_counterexample is not None]
    rate = stats.rate_summary(len(hits), len(group), 0.95, "clopper-pearson")
    eqs = [t.first_episode_equivalents for t in hits if t.first_episode_equivalents is not None]
    counted = all(t.counts_episodes for t in group)
    peaks = [t.peak_rss_mb for t in group if t.peak_rss_mb is not None]
    return MethodSummary(
        len(group), len(hits), rate["rate"], rate["low"], rate["high"],
        statistics.median(t.first_counterexample for t in hits) if hits and counted else None,
        statistics.fmean(eqs) if eqs else None, statistics.median(eqs) if eqs else None,
        median_eq_to_first(group), min(t.min_robustness for t in group),
        sum(t.episodes for t in group) if counted else None,
        sum(t.episode_equivalents for t in group), tuple(t.min_robustness for t in group),
        tuple(t.min_guide for t in group), tuple(t.first_episode_equivalents for t in group),
        max(peaks) if peaks else None, len(peaks))


def peak_text(s: MethodSummary) -> str:
    """The peak RSS cell: MB, with the share of trials measured when not all were; ``–`` for none."""
    if s.peak_rss_mb is None:
        return "–"
    return f"{s.peak_rss_mb:.0f}" + ("" if s.rss_measured == s.trials else f" ({s.rss_measured} of {s.trials} trials)")


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
                replay.replay(cx.run_dir, cx.episode_id, out_dir=cx.replay_dir())
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


class AuditCheck(NamedTuple):
    """A trial's first counterexample under the reference solver: whether it still violates the trial's
    requirement (``confirmed``) and the requirement's robustness there (None: not finite)."""

    trial: Trial
    counterexample: Counterexample
    confirmed: bool
    reference_robustness: float | None


def audit_counterexamples(trials: Sequence[Trial], progress: Callable[[str], None] | None = None
                          ) -> list[AuditCheck]:
    """Re-simulate each trial's first counterexample with the reference solver on the trial's requirement
    (:func:`mcverify.campaign.audit.audit`), keeping the audit in the counterexample's folder (``audits.json``)
    so that a re-read benchmark does not repeat it; the trajectories go to ``TRIAL/audit/<folder>``."""
    from mcverify.campaign import audit  # noqa: PLC0415 - simulation only with --audit

    checks = []
    for trial in trials:
        if not trial.counterexamples:
            continue
        cx = trial.counterexamples[0]
        entry = audit.recorded(cx.run_dir).get(str(cx.episode_id))
        if not _kept_audit_of(entry, trial.requirement):
            result = audit.audit(cx.run_dir, cx.episode_id, out_dir=cx.audit_dir(), requirement=trial.requirement)
            # a search run with the reference solver is its own audit: its robustness is the reference's
            entry = audit.record(cx.run_dir, result) or {
                "verdict": audit.AuditVerdict.CONFIRMED.value,
                "reference_robustness": float(robustness(result.stored, trial.requirement))}
        confirmed = entry["verdict"] == audit.AuditVerdict.CONFIRMED.value
        checks.append(AuditCheck(trial, cx, confirmed, entry["reference_robustness"]))
        if progress is not None:
            progress(f"audit {cx.run_dir} {cx.episode_id}: {entry['verdict']}, reference robustness "
                     f"{compact(entry['reference_robustness'])}")
    return checks


def _kept_audit_of(entry: dict | None, requirement: str) -> bool:
    """Whether a kept audit answers for ``requirement`` (one kept before the reference robustness was, does not)."""
    return (entry is not None and entry.get("requirement", "safe") == requirement
            and "reference_robustness" in entry)


def audit_sentence(checks: Sequence[AuditCheck] | None) -> str:
    """What the section says about the audits: how many counterexamples the reference solver confirms, and the
    reference robustness of every one."""
    if checks is None:
        return ("Counterexamples not audited with the reference solver (run with `--audit`): a fast-path violation "
                "may be the solver's rather than the controller's.")
    if not checks:
        return "Audit: no counterexample was found, so none was audited."
    confirmed = sum(c.confirmed for c in checks)
    each = "; ".join(f"{c.trial.method} seed {c.trial.seed}: {'confirmed' if c.confirmed else 'solver-dependent'}, "
                     f"robustness {compact(c.reference_robustness)}" for c in checks)
    return (f"Audit (`--audit`): each trial's first counterexample re-simulated on the same error and draws with the "
            f"reference solver, IPOPT solving every problem in full (`mcverify replay DIR E --backend ipopt`); "
            f"{confirmed} of {len(checks)} still violate the requirement (confirmed), the others are solver-dependent "
            f"(the fast path's, not the controller's). Per counterexample: {each}.")


def confirmed_text(group: Sequence[Trial], checks: Sequence[AuditCheck] | None) -> str:
    """The table's audit cell of one method: confirmed successes out of successes; ``–`` without audits."""
    if checks is None:
        return "–"
    mine = [c for c in checks if any(c.trial is t for t in group)]
    return f"{sum(c.confirmed for c in mine)} of {len(mine)}"


#: What the peak RSS column is (:mod:`benchmarks.memory`).
PEAK_RSS_TEXT = (
    "Peak RSS: the largest summed resident set size of the benchmark process and its worker processes, sampled "
    f"every {memory.INTERVAL_S:g} s while the method's trials ran (largest over its trials; a re-read trial "
    "reports the value kept when it ran, a resumed one that of the run that finished it). It includes the "
    "interpreter, JAX, CasADi and whatever earlier trials left loaded in the benchmark process, so it is the "
    "footprint of running the search, not the search's data alone; a peak shorter than the interval can be missed.")
def _beam_text(budget: int) -> str:
    return BEAM_TEXT.format(budget=budget, decided=", ".join(beam.DECIDED_IN_PREFIX))


#: What the section says when beam trials ran.
BEAM_TEXT = (
    "Beam (`--method beam`, a beam search over the per-step error of one scenario): the same budget, {budget}, "
    "read as a ceiling in episode-equivalents on the beam's cost bound (a beam that could exceed it is refused "
    "before it runs). It simulates segments from snapshots rather than episodes one by one, so its episode "
    "columns read –. Its counterexample is the first child whose prefix already violates a running-minimum "
    "requirement ({decided}: the search stops there and runs that child to "
    "its episode's end), else the best final-frontier episode when its robustness is negative; its ep-eq to the "
    "first counterexample is the search's cost up to it, and it is `TRIAL/best` episode 0 (`mcverify replay`). Its "
    "lowest guide is the lowest running score (`[falsify.beam] score`) of the nodes it ended with. The seed of "
    "trial t, seed + t, keys its children draws (the scenario and its seed are the campaign's). Without a "
    "counterexample a beam restarts with new draws while the budget left covers another beam's cost bound, so its "
    "cost counts every restart. random-schedules is its baseline at equal budget: the same table with branching = "
    "1, i.e. the root's width children (keyed as the beam's, so a trial is paired with the beam's trial of the same "
    "seed) each run one random schedule through the window, with no selection, restarting under the same budget.")


def markdown(trials: Sequence[Trial], *, budget: int, command: str, name: str = NAME,
             replays: Sequence[ReplayCheck] | None = None, audits: Sequence[AuditCheck] | None = None) -> str:
    begin, end = markers(name)
    keys = list(dict.fromkeys((t.target, t.method) for t in trials))
    groups = {key: [t for t in trials if (t.target, t.method) == key] for key in keys}
    summaries = {key: summarise(group) for key, group in groups.items()}
    guided = any(t.guide for t in trials)
    beamed = any(not t.counts_episodes for t in trials)
    lines = [begin, "", "## Falsification benchmark", "",
             section.provenance_line(command), "",
             "Each trial is a search with its own seed (search and noise), budget "
             f"{budget} episodes, stopping at its first counterexample. Success: a counterexample within the "
             "budget (95% Clopper-Pearson interval). Cost to the first counterexample in episodes and in "
             "episode-equivalents (ep-eq: control steps simulated up to and including the counterexample's "
             "episode over a whole episode's; an episode that stops early costs less); mean and median over "
             "the successful trials, and the median over all trials with a failed trial counted as beyond "
             "the budget. " + PEAK_RSS_TEXT, *([""] + [_beam_text(budget)] if beamed else []), "",
             "| target | method | trials | successes | success rate (95% CI) | mean ep-eq to 1st | "
             "median ep-eq to 1st | median ep-eq to 1st, all trials | median episodes to 1st | "
             "min robustness | episodes spent | ep-eq spent | peak RSS (MB) | confirmed by IPOPT |",
             "|---|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for (target, method), s in summaries.items():
        med = "–" if s.median_episodes is None else f"{s.median_episodes:g}"
        spent = "–" if s.episodes_spent is None else f"{s.episodes_spent}"
        lines.append(f"| {target} | {method} | {s.trials} | {s.successes} | {s.rate:.2f} [{s.low:.2f}, {s.high:.2f}] "
                     f"| {cost_text(s.mean_eq)} | {cost_text(s.median_eq)} | {cost_text(s.median_eq_all)} | {med} | "
                     f"{s.min_robustness:.4g} | {spent} | {s.eq_spent:.4g} | {peak_text(s)} | "
                     f"{confirmed_text(groups[(target, method)], audits)} |")
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
    if beamed:
        lines += ["", "Beam trials, snapshots alive at most per trial (the bound is 2 width + 1):", ""]
        lines += [f"- {target} {method}: {', '.join(str(t.peak_snapshots) for t in group)}"
                  for (target, method), group in groups.items() if not group[0].counts_episodes]
    lines += ["", replay_sentence(replays), "", audit_sentence(audits)]
    if any(t.counts_episodes for t in trials):
        lines += ["", "Issue 16's goal, per target (medians over all trials, a failed trial counting as beyond the "
                  "budget):", ""]
    lines += [f"- {goal_verdict(trials, target, budget)}" for target in dict.fromkeys(t.target for t in trials)
              if any(t.counts_episodes for t in trials if t.target == target)]
    paired = [line for target in dict.fromkeys(t.target for t in trials)
              if (line := paired_sentence(trials, target, beam.BEAM, RANDOM_SCHEDULES))]
    if paired:
        lines += ["", "The beam against its random-schedule baseline on paired seeds:", "", *[f"- {p}" for p in paired]]
    lines += ["", end, ""]
    return "\n".join(lines)


def markers(name: str) -> tuple[str, str]:
    """The markers of section ``name`` of this benchmark (:func:`benchmarks.section.markers`)."""
    return section.markers(NAME, name)


def write_section(path: Path, text: str, name: str = NAME) -> None:
    """Replace section ``name`` of ``path`` (or append it), keeping the rest of the file."""
    section.write(NAME, text, path, name)


DEFAULT_TARGETS = (
    "campaigns/falsify_mpcdc_table4b.toml",
    "campaigns/falsify_vlcbf_eps0_noise2.toml",
    "campaigns/falsify_theorem5_opposing.toml",
    "campaigns/falsify_theorem5_certified_opposing.toml",
    "campaigns/falsify_vlcbf_eps03_paper_noise.toml",
)
#: The population searchers, then the beam (targets with a [falsify.beam] table only).
ALL_METHODS = (*methods.METHODS, *BEAM_METHODS)


def chosen_methods(text: str) -> list[str]:
    """The methods of ``--methods`` (comma-separated), each a known one; otherwise one RunError line."""
    chosen = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in chosen if m not in ALL_METHODS]
    if bad or not chosen:
        raise RunError(f"--methods: unknown {', '.join(bad) or '(none given)'}; "
                       f"choose from {', '.join(ALL_METHODS)}")
    return chosen


def _parser() -> argparse.ArgumentParser:
    p = section.parser("falsify", "Success rate and median episodes to the first counterexample per search method "
                                  "and target.")
    p.add_argument("targets", nargs="*", type=Path,
                   help="campaign files with [falsify] (default: the five benchmark targets falsify_mpcdc_table4b, "
                   "falsify_vlcbf_eps0_noise2, falsify_theorem5_opposing, falsify_theorem5_certified_opposing, "
                   "falsify_vlcbf_eps03_paper_noise in campaigns/)")
    p.add_argument("--methods", default="cma,cross-entropy,random",
                   help="comma-separated methods; beam only on targets with a [falsify.beam] table (which the "
                   "others refuse)")
    p.add_argument("--trials", type=positive_int, default=10, help="independent trials per method and target")
    p.add_argument("--budget", type=positive_int, default=100,
                   help="episodes per trial; for beam the same number in episode-equivalents, a ceiling on its cost "
                   "bound")
    p.add_argument("--seed", type=nonneg_int, default=0, help="seed of the first trial (then seed+1, ...)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="settings",
                   help="override a model parameter of every target (repeatable)")
    p.add_argument("--out-dir", type=Path, default=Path("results/bench-falsify"), help="search folders")
    p.add_argument("--workers", type=positive_int, default=None, help="worker processes")
    section.add_section_option(p, NAME, "falsify_adversary for the adversary targets")
    p.add_argument("--replay", action="store_true",
                   help="re-simulate every counterexample found and check it bit for bit (as mcverify replay)")
    p.add_argument("--audit", action="store_true",
                   help="re-simulate each trial's first counterexample with the reference solver (as mcverify replay "
                   "--backend ipopt; about a minute of CPU each at 50 Hz) and report whether it still violates")
    section.add_output_options(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the trials and write (or print) the generated section."""
    def body() -> int:
        from mcverify.campaign import executors  # noqa: PLC0415 - keep --help fast

        args = _parser().parse_args(argv)
        name = section.check_section_name(NAME, args.section)
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
        audits = (audit_counterexamples(trials, progress=lambda line: print(line, file=sys.stderr))
                  if args.audit else None)
        text = markdown(trials, budget=args.budget, command=section.command(NAME, argv), name=name, replays=replays,
                        audits=audits)
        print(text)
        if not args.no_write:
            write_section(args.write, text, name)
            print(f"written: {args.write} (section benchmarks.{name})", file=sys.stderr)
        return 0

    return section.run_main(NAME, body)


if __name__ == "__main__":
    sys.exit(main())
