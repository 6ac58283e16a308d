"""``mcverify estimate``: a target event's rate per cell, by crude Monte Carlo with sequential
stopping, adaptive multilevel splitting or cross-entropy importance sampling."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from mcverify import requirements
from mcverify.cli import options, run

_log = logging.getLogger("mcverify.cli")


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("estimate", help="estimate a target event's rate per cell, with sequential stopping",
                       parents=[*parents, options.campaign(), options.folder("estimate", "<name>-<timestamp>"),
                                options.executor(workers_help="worker processes or Ray tasks in flight")])
    _add_method_options(p)
    _add_rare_event_options(p)
    p.set_defaults(handler="estimate")


def _add_method_options(p: argparse.ArgumentParser) -> None:
    """The method, its target, the stopping rule and crude Monte Carlo's options."""
    p.add_argument("--method", choices=("mc", "splitting", "importance", "subset"), default=None,
                   help="mc: crude Monte Carlo stopped on an anytime-valid interval (default); splitting: "
                        "adaptive multilevel splitting on the per-step noise; importance: cross-entropy "
                        "importance sampling over the scenario ranges; subset: subset simulation over every "
                        "input of an episode (scenario draws and per-step perception errors) (the last three in "
                        "this process unless --workers or --executor ray is given)")
    p.add_argument("--target", default=None,
                   help=f"event whose rate is estimated: {requirements.target_help()} (default collision)")
    p.add_argument("--until-halfwidth", type=options.halfwidth, default=None, metavar="H",
                   help="stop a cell when the interval's half-width is <= H (absolute, e.g. 0.01) or <= H "
                        "of the estimate (relative, e.g. 30%%)")
    p.add_argument("--budget", type=options.positive_int, default=None,
                   help="mc: most episodes per cell (default 1000)")
    p.add_argument("--level", type=options.level, default=None, help="confidence level of the interval (default 0.95)")
    p.add_argument("--chunk-size", type=options.positive_int, default=None, metavar="K",
                   help="mc: episodes per chunk, the unit of work and of the stopping checks (default 8)")
    p.add_argument("--dry-run", action="store_true",
                   help="check the campaign and the options, say how many episodes the estimate may run and a "
                        "rough CPU range, and run nothing")


def _add_rare_event_options(p: argparse.ArgumentParser) -> None:
    """Splitting's and importance sampling's options."""
    p.add_argument("--score", choices=tuple(requirements.SCORES), default=None,
                   help=f"splitting, importance: {requirements.score_help()} (default: the target's first); for "
                        "importance it steers the cross-entropy stages only")
    p.add_argument("--particles", type=options.positive_int, default=None,
                   help="splitting: particles per run (default 20)")
    p.add_argument("--replicates", type=options.positive_int, default=None,
                   help="splitting, subset: independent runs whose spread gives the interval (default 8; "
                        "fewer under-cover, docs/rare_events.md)")
    p.add_argument("--stage-samples", type=options.positive_int, default=None, metavar="N",
                   help="subset: episodes per stage (default 2000: fewer lose the rarer routes to the event, "
                        "docs/decisions.md)")
    p.add_argument("--p0", type=options.open_unit, default=None,
                   help="subset: conditional level of each stage (default 0.1; N * p0 chains of 1 / p0 episodes)")
    p.add_argument("--performance", choices=requirements.PERFORMANCES, default=None,
                   help="subset: the function whose levels the runs climb, <= 0 exactly at the event: robustness "
                        "(the target's), " + ", ".join(f"{name} ({text})" for name, text in
                                                       requirements.PERFORMANCE_TEXT.items())
                        + ": for events that follow a held plan (default robustness)")
    p.add_argument("--cell", action="append", default=[], metavar="NAME",
                   help="splitting, importance: only this cell (repeatable; default: every cell); splitting runs its "
                        "AMS runs, importance its batches of 8 episodes, in this process unless --workers (local) "
                        "or --executor ray is given")
    p.add_argument("--samples", type=options.positive_int, default=None,
                   help="importance: episodes drawn from the defensive mixture (default 400)")
    p.add_argument("--ce-samples", type=options.positive_int, default=None,
                   help="importance: episodes per cross-entropy iteration (default 100)")
    p.add_argument("--elite-share", type=options.open_unit, default=None, metavar="RHO",
                   help="importance: share of each cross-entropy iteration's episodes kept as its elite "
                        "(default 0.1; with few episodes per iteration a larger share keeps the elite at 10 or more)")
    p.add_argument("--ce-iterations", type=options.nonneg_int, default=None,
                   help="importance: most cross-entropy iterations (default 10; 0: the scenario stays nominal, "
                        "e.g. with --noise-tilt when the score would steer the scenario away from the event)")
    p.add_argument("--noise-tilt", type=options.noise_tilt, metavar="KEY=VALUE,...",
                   help="importance: draw veh_f's measurement noise near veh_f from exponential tilts, refitted "
                        "by the cross-entropy iterations, and weight each episode by its likelihood ratio; keys "
                        "gap_max_m (required), split_m, band_steps, defensive, theta_max and starting tilts "
                        "UNIT_BAND (x|y|v _ approach|jump|alongside) (docs/rare_events.md), e.g. "
                        "gap_max_m=4.1,split_m=3.05,y_approach=-5,y_jump=5")
    p.add_argument("--max-iterations", type=options.positive_int, default=None,
                   help="splitting: iteration cap per run (default 2000; a capped run is flagged, not an estimate)")


#: ``mcverify estimate`` options that only some methods read: (attribute, option, methods).
_ESTIMATE_METHOD_OPTIONS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("until_halfwidth", "--until-halfwidth", ("mc",)),
    ("budget", "--budget", ("mc",)),
    ("chunk_size", "--chunk-size", ("mc",)),
    ("score", "--score", ("splitting", "importance")),
    ("cell", "--cell", ("splitting", "importance", "subset")),
    ("particles", "--particles", ("splitting",)),
    ("replicates", "--replicates", ("splitting", "subset")),
    ("stage_samples", "--stage-samples", ("subset",)),
    ("p0", "--p0", ("subset",)),
    ("performance", "--performance", ("subset",)),
    ("max_iterations", "--max-iterations", ("splitting",)),
    ("samples", "--samples", ("importance",)),
    ("ce_samples", "--ce-samples", ("importance",)),
    ("ce_iterations", "--ce-iterations", ("importance",)),
    ("elite_share", "--elite-share", ("importance",)),
    ("noise_tilt", "--noise-tilt", ("importance",)),
)
#: Their defaults (None on the command line, so that a given option can be told from a default).
_ESTIMATE_DEFAULTS: dict[str, object] = {
    "method": "mc", "target": "collision", "budget": 1000, "level": 0.95, "particles": 20, "replicates": 8,
    "samples": 400, "ce_samples": 100, "ce_iterations": 10, "elite_share": 0.1, "max_iterations": 2000,
    "stage_samples": 2000, "p0": 0.1, "performance": requirements.PLAIN_ROBUSTNESS,
}


def _check_estimate_options(args, method: str) -> None:
    """Refuse, with one line, an option the method (or ``--resume``) would ignore; then fill the defaults."""
    from mcverify.errors import RunError

    def given(attr: str) -> bool:
        return getattr(args, attr) not in (None, [])

    if args.resume:
        kept = [opt for attr, opt in (("method", "--method"), ("target", "--target"), ("level", "--level"))
                if given(attr)] + [opt for attr, opt, _ in _ESTIMATE_METHOD_OPTIONS if given(attr)]
        if kept:
            raise RunError(f"--resume keeps the estimate's method, target and options: leave out {', '.join(kept)}")
    else:
        for attr, opt, methods in _ESTIMATE_METHOD_OPTIONS:
            if given(attr) and method not in methods:
                raise RunError(f"{opt} is for --method {' or '.join(methods)}, not {method}")
    for attr, value in _ESTIMATE_DEFAULTS.items():
        if getattr(args, attr) is None:
            setattr(args, attr, value)


def command(args) -> int:
    from mcverify.campaign import executors, run_folders, runner
    from mcverify.errors import RunError
    from mcverify.estimate import mc

    method = _folder_method(args.resume) if args.resume else (args.method or "mc")
    if args.noise_tilt is not None and (args.resume or method != "importance"):
        raise RunError("--noise-tilt is a proposal of --method importance, given when the estimate starts")
    if args.resume and args.dry_run:
        raise RunError("--dry-run checks a campaign file; it does not apply to --resume")
    _check_estimate_options(args, method)
    if args.dry_run:
        return _estimate_dry_run(args, method)
    if method in ("splitting", "importance", "subset"):
        return _in_process(args, method)
    executor = executors.make_executor(args.executor, workers=args.workers, address=args.address)
    if args.resume:
        if args.campaign or args.out or args.new_run_dir or args.seed is not None or args.settings:
            raise RunError("--resume keeps the estimate's campaign and rule: give only RUN_DIR (and the executor)")
        if options.already_complete(args.resume):
            return options.say_complete(args.resume)
        args.run_dir = args.resume

        def resuming(planned: int, done: int) -> None:
            _log.info("resuming %s: %d of %d chunks already done", args.resume, done, planned)

        path = mc.resume(args.resume, executor=executor, progress=not args.no_progress, on_start=resuming)
    else:
        spec = _estimate_spec(args, "mc")
        campaign = _estimate_campaign(args, "mc")
        out = args.run_dir = run.new_folder(args, lambda parent: run_folders.default_run_dir(campaign, parent))
        _log.info("%s", runner.describe(campaign))
        _log.info("estimate folder: %s", out)
        path = mc.run(campaign, spec, out, executor=executor,
                      chunk_size=args.chunk_size or runner.DEFAULT_CHUNK_SIZE, progress=not args.no_progress)
    print(path.read_text())
    _log.info("report: %s", path)
    return 0


def _estimate_spec(args, method: str):
    """The estimate's rule from the command line (a new estimate), refused in one line if invalid."""
    from mcverify.analysis.estimates import EstimateSpec
    from mcverify.errors import RunError
    from mcverify.estimate import importance_run, splitting_run, subset_run

    if args.campaign is None:
        raise RunError("missing campaign file, e.g. `mcverify estimate campaigns/eps_sweep_rare.toml`")
    if method in ("splitting", "importance") and args.target not in requirements.SCORED_TARGETS:
        raise RunError(f"{method} estimates --target {' or '.join(requirements.SCORED_TARGETS)}")
    try:
        if method == "mc":
            halfwidth, relative = args.until_halfwidth or (None, False)
            return EstimateSpec(args.method, args.target, halfwidth, relative, args.budget, args.level)
        if method == "splitting":
            score = args.score or requirements.default_score(args.target)
            spec = splitting_run.SplittingSpec(score, args.particles, 1, args.replicates, args.level,
                                               args.max_iterations)
            if spec.target != args.target:
                raise RunError(f"--score {score} estimates {spec.target}, not --target {args.target}")
            return spec
        if method == "subset":
            return subset_run.SubsetSpec(args.target, args.stage_samples, args.p0, args.replicates, args.level,
                                         performance=args.performance)
        return importance_run.ImportanceSpec(args.target, args.samples, args.ce_samples, rho=args.elite_share,
                                             level=args.level, max_ce_iterations=args.ce_iterations,
                                             score=args.score, noise_tilt=args.noise_tilt)
    except ValueError as err:
        raise RunError(str(err)) from None


def _estimate_campaign(args, method: str):
    """The campaign of a new estimate, with every check an estimate makes before its folder exists."""
    from mcverify.campaign.spec import load_campaign
    from mcverify.estimate import folder, importance_run

    budget = args.budget if method == "mc" else None
    campaign = load_campaign(args.campaign, episodes=budget, seed=args.seed, settings=args.settings)
    folder.check_noise_is_drawn(campaign)
    if method != "mc":
        folder.check_cells(campaign, args.cell)
    if method == "importance":
        importance_run.check_cells_have_ranges(campaign, args.cell or None)
    if method == "subset":
        from mcverify.estimate.input_vector import check_law

        for cell in campaign.cells:
            if not args.cell or cell.name in args.cell:
                check_law(cell)
    return campaign


def _estimate_dry_run(args, method: str) -> int:
    """``estimate --dry-run``: every check of a new estimate, then its plan (:mod:`mcverify.estimate.plan`)."""
    from mcverify.campaign import executors, lint
    from mcverify.estimate import plan

    _estimate_spec(args, method)
    campaign = _estimate_campaign(args, method)
    for warning in lint.warnings(campaign):
        _log.warning("warning: %s", warning)
    in_process = method != "mc" and args.executor == "local" and args.workers is None
    workers = 1 if in_process else (args.workers or executors.default_workers())
    options = plan.EstimateOptions(
        method, args.target, budget=args.budget, samples=args.samples, ce_samples=args.ce_samples,
        ce_iterations=args.ce_iterations, particles=args.particles, replicates=args.replicates,
        max_iterations=args.max_iterations, cells=tuple(args.cell), workers=workers,
        stage_samples=args.stage_samples, p0=args.p0, performance=args.performance)
    print(plan.render(campaign, options))
    return 0


def _executor_for(args, method: str) -> dict:
    """splitting and importance: their work units (AMS runs; batches of episodes) go to the executor
    named on the command line (default: this process)."""
    from mcverify.campaign import executors

    if method not in ("splitting", "importance", "subset"):
        return {}
    kind = "serial" if args.executor == "local" and args.workers is None else args.executor
    return {"executor": executors.make_executor(kind, workers=args.workers, address=args.address)}


def _stage_lines(args, method: str) -> dict:
    """subset: a line per closed stage of each run (minutes apart on the closed loop), unless -q."""
    return {"stage_lines": not args.quiet} if method == "subset" else {}


def _folder_method(run_dir: Path) -> str | None:
    """The method recorded in an estimate folder's manifest (None if unreadable or absent)."""
    import json

    try:
        return json.loads((run_dir / "manifest.json").read_text()).get("estimate", {}).get("method")
    except (OSError, ValueError, AttributeError):
        return None


def _in_process(args, method: str) -> int:
    from mcverify.campaign import run_folders, runner
    from mcverify.campaign.spec import campaign_from_dict
    from mcverify.errors import RunError
    from mcverify.estimate import importance_run, splitting_run, subset_run

    module = {"splitting": splitting_run, "importance": importance_run, "subset": subset_run}[method]
    # progress lines on stderr, unless -q ("only warnings and errors on stderr")
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))  # noqa: E731
    if args.resume:
        from mcverify import store

        if args.out is not None or args.new_run_dir is not None:
            raise RunError("--resume writes into RUN_DIR: leave out --out and --run-dir")
        if args.campaign or args.seed is not None or args.settings:
            raise RunError("--resume keeps the estimate's campaign, seed and settings: give only RUN_DIR (and the "
                           "executor)")
        if options.already_complete(args.resume):
            return options.say_complete(args.resume)
        manifest = store.read_manifest(args.resume)
        camp = manifest["campaign"]
        campaign = runner.with_recorded_params(  # the cells' parameters as the run recorded them
            campaign_from_dict(camp["raw"], source=camp["source"], seed=camp["seed"]), manifest.get("cells", []),
            str(args.resume))
        path = module.resume(args.resume, campaign, progress=log, **_executor_for(args, method),
                             **_stage_lines(args, method))
    else:
        spec = _estimate_spec(args, method)
        campaign = _estimate_campaign(args, method)  # checked before any folder is made
        out = args.run_dir = run.new_folder(args, lambda parent: run_folders.default_run_dir(campaign, parent))
        log(runner.describe(campaign, episodes=False))  # the estimator chooses how many episodes
        log(f"estimate folder: {out}")
        path = module.run(campaign, spec, out, progress=log, cells=args.cell or None, **_executor_for(args, method),
                          **_stage_lines(args, method))
    print(path.read_text())
    _log.info("report: %s", path)
    return 0
