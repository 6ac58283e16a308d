"""``mcverify falsify``: search for counterexamples (robustness-guided, :mod:`mcverify.falsify`); also
the line ``run --dry-run`` prints for a campaign with a ``[falsify]`` table."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

from mcverify import requirements
from mcverify.cli import options
from mcverify.errors import RunError

#: The methods of ``--method``: the searchers of :mod:`mcverify.falsify.methods`, then the beam search.
METHODS: tuple[str, ...] = ("cma", "cross-entropy", "random", "bo", "splitting", "beam")


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("falsify", help="search for counterexamples (robustness-guided; mcverify.falsify)", parents=[
        *parents, options.campaign("campaign TOML file with a [falsify] table",
                                   "search seed (default: the campaign's seed)"),
        options.folder("search", "falsify-<name>-<method>-<timestamp>", metavar="OUT",
                       progress_help="no per-generation lines and no progress bar"),
        options.executor()])
    p.add_argument("--method", choices=METHODS,
                   help="search method (default cma; bo: Bayesian optimisation, needs the extra mcverify[bo]; "
                        "splitting: branches the best episodes with fresh per-step noise, for noise-driven failures; "
                        "beam: a beam search over the per-step error inside a window of one episode, each child "
                        "continuing its parent's snapshot, from the campaign's [falsify.beam] table)")
    p.add_argument("--budget", type=options.positive_int,
                   help="episodes the search may spend (required for a new search); --method beam: a ceiling in "
                        "episode-equivalents (control steps over a whole episode's): a beam whose cost bound "
                        "exceeds it is refused before it runs (--dry-run states the bound)")
    p.add_argument("--requirement",
                   help=f"requirement to falsify: {requirements.requirement_help()} (docs/falsification.md; "
                        "default: the file's [falsify] requirement, else safe)")
    p.add_argument("--dry-run", action="store_true",
                   help="check the campaign, its [falsify] table and the options, say what the search would "
                        "spend, and run nothing (--method beam: its depths, children per depth and a bound on the "
                        "control steps it simulates)")
    p.set_defaults(handler="falsify")


def describe_table(path: Path, settings: Any = ()) -> str:
    """``run --dry-run``'s line for a campaign with a ``[falsify]`` table, after checking the table
    as ``falsify`` would (every bound against its field's limits): a bad table is one error line."""
    import tomllib  # noqa: PLC0415

    from mcverify.campaign.spec import apply_settings, load_campaign  # noqa: PLC0415
    from mcverify.falsify import search  # noqa: PLC0415

    campaign = load_campaign(path, settings=settings)
    raw = apply_settings(tomllib.loads(Path(path).read_text(encoding="utf-8")), settings)
    space = campaign.falsify
    if space is not None and not space.bounds and space.adversary is None and space.beam is not None:
        from mcverify.falsify import beam_folder  # noqa: PLC0415

        config = search.SearchConfig(raw, str(path), "beam", 1, campaign.seed, space.requirement)
        spec = beam_folder.target(config)[1]
        return (f"[falsify.beam]: requirement {config.requirement}, {spec.depths} depth(s) in control steps "
                f"[{spec.first_step}, {spec.last_step}); search it with `mcverify falsify {path} --method beam "
                "--budget N` (--dry-run states the cost bound)")
    config = search.SearchConfig(raw, str(path), "random", 1, campaign.seed, campaign.falsify.requirement)
    space = search.check(config)
    return (f"[falsify]: requirement {config.requirement}, {len(space.bounds)} searched field(s), every bound "
            f"within its field's limits; search it with `mcverify falsify {path} --budget N`")


def _dry_run(config: Any, campaign: Any, workers: int | None) -> str:
    """``falsify --dry-run``: what the search is and what its budget would cost (the run dry run's
    per-episode CPU model, every episode run to its end: stopping at a violation only saves)."""
    from mcverify.campaign import cost, executors  # noqa: PLC0415
    from mcverify.falsify import ask_tell, search  # noqa: PLC0415

    space = search.check(config)
    low, high = cost.cell_seconds(campaign.cells[0])
    n = workers or executors.default_workers()
    cpu_range = cost.duration_range(low * config.budget, high * config.budget)
    wall_range = cost.duration_range(low * config.budget / n, high * config.budget / n)
    return "\n".join([
        f"falsify {config.source}: {config.method}, budget {config.budget} episodes, requirement "
        f"{config.requirement}, seed {config.seed}",
        f"search space: {len(space.bounds)} field(s): {', '.join(b[0] for b in space.bounds)}"
        + ("" if space.adversary is None else
           f"; {space.adversary.describe()}, {ask_tell.search_dimension(campaign, space)} coordinates in all"),
        f"estimated CPU: {cpu_range} at most; wall time on {n} worker(s): {wall_range} at most (a rough range from "
        "measured rates; "
        + ("the search stops after the generation of its first counterexample)" if space.stop_at_first
           else "[falsify] stop_at_first = false: the search spends its whole budget)"),
        cost.kernels_to_build(campaign.cells).text(),
    ])


def command(args: Any) -> int:
    """Start a search (``CAMPAIGN.toml``) or resume one (``--resume OUT``); prints the report."""
    from mcverify.campaign import executors  # noqa: PLC0415 - keep `mcverify --help` fast
    from mcverify.falsify import beam_folder, search  # noqa: PLC0415

    if args.address is not None and args.executor != "ray":
        raise RunError("--address is for the Ray executor: add --executor ray")

    def make_executor():
        return executors.make_executor(args.executor, workers=args.workers, address=args.address)

    def say(line: str) -> None:
        if not args.no_progress:
            print(line, file=sys.stderr)

    if args.resume is not None and args.dry_run:
        raise RunError("--dry-run checks a campaign file; it does not apply to --resume")
    if args.resume is not None:
        if args.campaign is not None or args.out is not None or args.new_run_dir is not None or args.settings \
                or args.budget is not None or args.method is not None or args.seed is not None \
                or args.requirement is not None:
            raise RunError("--resume keeps the search's campaign, method, budget, seed, requirement and folder: "
                           "give only --resume OUT (and --executor/--workers)")
        if options.already_complete(args.resume):
            return options.say_complete(args.resume)
        args.run_dir = args.resume
        if beam_folder.is_beam_folder(args.resume):
            _serial_only(args)
            say(f"resuming {args.resume}: {beam_folder.stored_depths(args.resume)} depth(s) already stored")
            return _beam_done(beam_folder.resume(args.resume, progress=say), Path(args.resume))
        if (Path(args.resume) / search.CONFIG).is_file():
            say(f"resuming {args.resume}: {search.stored_generations(args.resume)} generation(s) already stored")
        result = search.resume(args.resume, make_executor=make_executor, progress=say,
                               bar=not args.no_progress)
    else:
        config, campaign = _new_config(args)
        if config.method == "beam":
            return _beam_new(args, config, campaign, say)
        search.check(config)  # every mistake as one line, before the start line and the folder
        if args.dry_run:
            print(_dry_run(config, campaign, args.workers))
            return 0
        out = args.run_dir = _new_out(args, campaign.name, config.method)
        search.check_new_folder(Path(out))
        say(f"falsify {args.campaign}: {config.method}, budget {args.budget} episodes, requirement "
            f"{config.requirement}, into {out}")
        result = search.start(config, out, make_executor=make_executor, progress=say, bar=not args.no_progress)
    print((result.out_dir / "report.md").read_text())
    first = result.first_counterexample_text()
    found = (f"first counterexample {first}" if first else
             f"no counterexample in {result.episodes} episodes, minimum robustness {result.min_robustness:.4g}")
    found += f"; cost {result.episode_equivalents():.3g} episode-equivalents"
    logging.getLogger("mcverify.falsify").info("report: %s (also report.html); %s", result.out_dir / "report.md", found)
    return 0


def _new_config(args: Any) -> tuple[Any, Any]:
    """The SearchConfig and campaign of a new search from the options (each mistake one line)."""
    from mcverify.campaign.spec import apply_settings, load_campaign  # noqa: PLC0415
    from mcverify.falsify import search  # noqa: PLC0415

    if args.campaign is None:
        raise RunError("missing campaign file, e.g. `mcverify falsify campaigns/falsify_mpcdc_table4b.toml`")
    if args.budget is None:
        raise RunError("missing --budget N (episodes the search may spend; --method beam: episode-equivalents)")
    campaign = load_campaign(args.campaign, settings=args.settings)
    if campaign.falsify is None:
        raise RunError(f"{args.campaign}: no [falsify] table (bounds of the search space); see "
                       "docs or campaigns/falsify_*.toml")
    method = args.method or "cma"
    if method not in METHODS:
        raise RunError(f"unknown --method {method!r}; choose one of {', '.join(METHODS)}")
    if args.requirement is not None and args.requirement not in requirements.REQUIREMENTS:
        if not requirements.is_stl(args.requirement):
            raise RunError(f"--requirement {args.requirement!r}: unknown requirement; known: "
                           f"{', '.join(requirements.REQUIREMENTS)} or {requirements.STL_PREFIX}<formula>")
        from mcverify.analysis import robustness as rb  # noqa: PLC0415

        try:
            rb.check_requirement(args.requirement)
        except ValueError as exc:
            raise RunError(f"--requirement: {exc}") from None
    import tomllib  # noqa: PLC0415

    raw = apply_settings(tomllib.loads(Path(args.campaign).read_text(encoding="utf-8")), args.settings)
    if args.requirement is not None:
        raw["falsify"] = {**raw["falsify"], "requirement": args.requirement}
    config = search.SearchConfig(
        raw=raw, source=str(args.campaign), method=method, budget=args.budget,
        seed=campaign.seed if args.seed is None else args.seed,
        requirement=args.requirement or campaign.falsify.requirement,
    )
    return config, campaign


def _new_out(args: Any, name: str, method: str) -> Path:
    from mcverify.campaign import run_folders  # noqa: PLC0415

    return run_folders.new_folder(args.out, args.new_run_dir, lambda parent: _default_out(name, method, parent))


def _serial_only(args: Any) -> None:
    """The beam runs its nodes one after another in this process (each child continues its parent's snapshot)."""
    if args.executor != "local" or args.workers not in (None, 1):
        raise RunError("--method beam runs its nodes one after another in this process (each continues its "
                       "parent's snapshot): drop --executor and --workers")


def _beam_new(args: Any, config: Any, campaign: Any, say: Any) -> int:
    """``--method beam``: check, dry run or start (:mod:`mcverify.falsify.beam_folder`)."""
    from mcverify.falsify import beam_folder, search  # noqa: PLC0415

    _serial_only(args)
    beam_folder.check(config)  # every mistake as one line, before the start line and the folder
    if args.dry_run:
        print(beam_folder.describe(config))
        return 0
    out = args.run_dir = _new_out(args, campaign.name, config.method)
    search.check_new_folder(Path(out))
    say(f"falsify {args.campaign}: beam, budget {args.budget} episode-equivalents, requirement "
        f"{config.requirement}, into {out}")
    return _beam_done(beam_folder.start(config, Path(out), progress=say), Path(out))


def _beam_done(summary: Any, out: Path) -> int:
    from mcverify.falsify import beam_folder  # noqa: PLC0415

    print((out / "report.md").read_text())
    logging.getLogger("mcverify.falsify").info("report: %s; %s", out / "report.md", beam_folder.verdict(summary, out))
    return 0


def _default_out(name: str, method: str, parent: Path | None) -> Path:
    """A new folder ``parent/falsify-<name>-<method>-<timestamp>`` (parent: $MCVERIFY_RESULTS, else
    ./results, when None), like ``mcverify run``'s run folders."""
    from datetime import datetime  # noqa: PLC0415

    from mcverify.campaign import run_folders  # noqa: PLC0415

    parent = Path(parent) if parent is not None else run_folders.default_results_dir()
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = parent / run_folders.folder_name(f"falsify-{name}-{method}-{stamp}")
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f"{base.name}-{n}")
    return path
