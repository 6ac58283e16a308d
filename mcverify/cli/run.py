"""``mcverify run``: run a campaign into a run folder (or check it with ``--dry-run``)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from mcverify.cli import options

_log = logging.getLogger("mcverify.cli")


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    run = sub.add_parser("run", help="run a campaign into a run folder", parents=[
        *parents, options.campaign(), options.folder("run", "<name>-<timestamp>"),
        options.executor(("local", "ray"), "local: worker processes (default: all cores); ray: tasks in flight "
                                           "(default: the cluster's CPUs)")])
    run.add_argument("--episodes", type=options.positive_int, help="episodes per cell (overrides the file)")
    run.add_argument(
        "--chunk-size", type=options.positive_int, default=None, metavar="K",
        help="episodes per chunk, the unit of work and of crash safety (default 8; a resume keeps the run's)",
    )
    run.add_argument("--dry-run", action="store_true",
                     help="check the campaign and print its cells, episodes, chunks, warnings and an estimate of "
                          "the CPU time; run nothing")
    run.set_defaults(handler="run")


def command(args) -> int:
    from mcverify.campaign import executors, run_folders, runner
    from mcverify.errors import RunError

    if args.address is not None and args.executor != "ray":
        raise RunError("--address is for the Ray executor: add --executor ray")
    if args.resume and args.dry_run:
        raise RunError("--dry-run checks a campaign file; it does not apply to --resume")
    if args.resume:
        path = _resume(args)
        if path is None:
            return options.say_complete(args.resume)
    else:
        if args.campaign is None:
            raise RunError("missing campaign file, e.g. `mcverify run campaigns/smoke.toml`")
        from mcverify.campaign.spec import load_campaign

        campaign = load_campaign(args.campaign, episodes=args.episodes, seed=args.seed, settings=args.settings)
        if args.dry_run:
            return _dry_run(args, campaign)
        out = args.run_dir = new_folder(args, lambda parent: run_folders.default_run_dir(campaign, parent))
        executor = executors.make_executor(args.executor, workers=args.workers, address=args.address)

        def starting(planned: int, done: int) -> None:  # after every check: errors stay one line
            _log.info("%s", runner.describe(campaign))
            how = ", ".join(f"{k} {v}" for k, v in executor.describe().items() if v is not None)
            _log.info("run folder: %s (%d chunks; %s)", out, planned, how)

        path = runner.run(
            campaign, out, executor=executor, chunk_size=args.chunk_size or runner.DEFAULT_CHUNK_SIZE,
            progress=not args.no_progress, on_start=starting,
        )
    print(path.read_text())
    _log.info("report: %s", path)
    return 0


def _resume(args) -> Path | None:
    from mcverify.campaign import executors, runner
    from mcverify.campaign.spec import load_campaign
    from mcverify.errors import RunError

    if args.episodes is not None or args.seed is not None or args.settings:
        raise RunError("--resume keeps the run's episodes, seed and settings: leave out --episodes, --seed "
                       "and --set")
    if args.out is not None or args.new_run_dir is not None:
        raise RunError("--resume writes into RUN_DIR: leave out --out and --run-dir")
    if options.already_complete(args.resume):
        return None
    # A campaign file given with --resume is a check: it must be the one the run started with.
    campaign = load_campaign(args.campaign) if args.campaign else None
    executor = executors.make_executor(args.executor, workers=args.workers, address=args.address)
    args.run_dir = args.resume

    def resuming(planned: int, done: int) -> None:
        _log.info("resuming %s: %d of %d chunks already done", args.resume, done, planned)

    return runner.resume(
        args.resume, executor=executor, progress=not args.no_progress, campaign=campaign,
        chunk_size=args.chunk_size, on_start=resuming,
    )


def _dry_run(args, campaign) -> int:
    from mcverify.campaign import cost, executors, lint, runner

    for warning in lint.warnings(campaign):
        _log.warning("warning: %s", warning)
    searched = None
    if campaign.falsify is not None:  # checked first: a bad table is the only line printed
        from mcverify.cli.falsify import describe_table

        searched = describe_table(args.campaign, args.settings)
    print(cost.render(campaign, args.chunk_size or runner.DEFAULT_CHUNK_SIZE,
                      args.workers or executors.default_workers()))
    if searched:
        print(searched)
    return 0


def new_folder(args, fresh) -> Path:
    """The folder of a new run or estimate (:func:`mcverify.campaign.run_folders.new_folder`)."""
    from mcverify.campaign import run_folders

    return run_folders.new_folder(args.out, args.new_run_dir, fresh)
