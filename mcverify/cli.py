"""mcverify: Monte-Carlo verification and falsification of the TO-CBF-MPC overtaking controller.

Every user error (bad campaign, missing run folder, bad argument) ends with one line on stderr and
exit status 2; a replay that does not reproduce exits with status 1.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import sys
from pathlib import Path

from mcverify import errors

_log = logging.getLogger("mcverify.cli")

EXIT_USAGE = 2
EXIT_MISMATCH = 1
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a writer whose reader closed the pipe
#: Exit status after Ctrl-C (128 + SIGINT) and after SIGTERM (128 + SIGTERM), as a shell reports them.
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143


class Terminated(KeyboardInterrupt):
    """SIGTERM (what a cluster scheduler or ``kill`` sends), handled like Ctrl-C: finished chunks are
    on disk, the workers are stopped, and the resume hint is printed."""


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as err:
        print(f"mcverify: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except SystemExit as done:  # --help, --version: printed, nothing to run
        return done.code if isinstance(done.code, int) else 0
    if not hasattr(args, "func"):
        (getattr(args, "help_parser", None) or parser).print_help()
        return EXIT_USAGE
    restore_logging = _configure_logging(getattr(args, "verbose", 0) - getattr(args, "quiet", 0))
    if getattr(args, "quiet", 0) and hasattr(args, "no_progress"):
        args.no_progress = True
    try:
        return _dispatch(args)
    finally:
        restore_logging()


# The commands whose folders resume with `mcverify COMMAND --resume DIR`, and the files that say a
# folder was written (a run's or estimate's manifest, a search's configuration).
_RESUMABLE = ("run", "estimate", "falsify")
_FOLDER_MARKERS = ("manifest.json", "falsify.json", "estimate.json")


def _what_is_kept(command: str, run_dir: Path) -> str:
    """What an interrupt leaves for ``--resume``: whole chunks of episodes, except for the estimators
    whose unit of work is not a chunk."""
    if command == "estimate":
        try:
            method = json.loads((run_dir / "manifest.json").read_text()).get("estimate", {}).get("method")
        except (OSError, ValueError, AttributeError):
            method = None
        if method == "splitting":
            return "finished AMS runs are kept"
        if method == "importance":
            return "finished cells and the finished batches of the cell in progress are kept"
    return "finished chunks are kept"


def _dispatch(args) -> int:
    from mcverify.errors import UserError

    try:
        with _sigterm_as_interrupt():
            return args.func(args) or 0
    except UserError as err:
        print(f"mcverify: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # `mcverify ... | head`: the reader left; stop quietly, as a pipe's writer does
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit's flush
        return EXIT_BROKEN_PIPE
    except OSError as err:  # a folder that cannot be written, a full disk: the environment, not a bug
        where = f": {err.filename}" if err.filename else ""
        print(f"mcverify: error: {err.strerror or err}{where}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as err:
        terminated = isinstance(err, Terminated)
        command = getattr(args, "command", None)
        run_dir = getattr(args, "run_dir", None) if command in _RESUMABLE else None
        if run_dir is not None and not any((Path(run_dir) / name).is_file() for name in _FOLDER_MARKERS):
            run_dir = None  # stopped before the folder was written: nothing to resume
        what = "terminated (SIGTERM)" if terminated else "interrupted"
        if run_dir is not None:
            print(f"mcverify: {what}; {_what_is_kept(command, Path(run_dir))} (mcverify {command} --resume "
                  f"{run_dir})", file=sys.stderr)
        else:
            print(f"mcverify: {what}", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED


class _StderrHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is when a line is emitted (not when the handler was made), so a
    replaced or captured stderr never receives a line meant for a closed one."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property
    def stream(self):  # type: ignore[override]
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:  # StreamHandler.__init__ assigns it
        pass


def _configure_logging(verbosity: int):
    """Lines of the ``mcverify`` loggers on stderr as ``mcverify: ...``: notices before long phases
    (kernel compilation, worker start-up) by default, only warnings with ``-q``, debug detail with
    ``-v``. Configured here, not on import: a library user's logging stays theirs."""
    level = logging.DEBUG if verbosity > 0 else logging.WARNING if verbosity < 0 else logging.INFO
    logger = logging.getLogger("mcverify")
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter("mcverify: %(message)s"))
    previous = logger.level
    logger.addHandler(handler)
    logger.setLevel(level)

    def restore() -> None:  # main() may be called from Python (tests, scripts): leave logging as it was
        logger.removeHandler(handler)
        logger.setLevel(previous)

    return restore


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """While a command runs, SIGTERM raises :class:`Terminated` (a KeyboardInterrupt) in the main
    thread, so it takes the same path as Ctrl-C. Both are noted (:func:`mcverify.errors.note_interrupt`)
    so that one raised inside IPOPT, which CasADi swallows, is raised again by the solver instead of
    becoming a failed solve. Only installed from the main thread."""
    def on_term(signum, frame):
        raise errors.note_interrupt(Terminated())

    def on_int(signum, frame):
        raise errors.note_interrupt(KeyboardInterrupt())

    errors.clear_noted_interrupts()
    try:
        previous = signal.signal(signal.SIGTERM, on_term)
    except ValueError:  # not the main thread (e.g. called from a worker thread): leave signals alone
        yield
        return
    previous_int = signal.signal(signal.SIGINT, on_int)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)


class _UsageError(Exception):
    """A command-line usage error (argparse's), reported as one line instead of usage + message."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # argparse would print the usage block and exit
        raise _UsageError(f"{self.prog}: {message} (see `{self.prog} --help`)")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="mcverify", description=__doc__.splitlines()[0])
    p.add_argument("--version", action=_VersionAction, help="print the version (and git commit) and exit")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=0, help="more detail on stderr")
    common.add_argument("-q", "--quiet", action="count", default=0,
                        help="only warnings and errors on stderr (no progress bar, no notices)")
    sub = p.add_subparsers(metavar="COMMAND", parser_class=_Parser, dest="command")
    _add = sub.add_parser
    sub.add_parser = lambda *a, **k: _add(*a, parents=[common], **k)  # every command takes -v / -q

    run = sub.add_parser("run", help="run a campaign into a run folder")
    run.add_argument("campaign", nargs="?", type=Path, help="campaign TOML file")
    run.add_argument("--episodes", type=_positive_int, help="episodes per cell (overrides the file)")
    run.add_argument("--seed", type=_nonneg_int, help="campaign seed (overrides the file)")
    run.add_argument(
        "--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="settings",
        help="override a model parameter of the file, e.g. --set mpc.backend=ipopt (repeatable)",
    )
    run.add_argument(
        "--out", type=Path, metavar="DIR",
        help="parent folder of the new run folder DIR/<name>-<timestamp> (default: $MCVERIFY_RESULTS, "
             "else ./results)",
    )
    run.add_argument("--run-dir", type=Path, dest="new_run_dir", metavar="RUN_DIR",
                     help="the exact (new or empty) folder for this run, instead of a fresh one under --out")
    run.add_argument(
        "--executor", choices=("local", "ray"), default="local",
        help="local worker processes (default) or tasks on a Ray cluster",
    )
    run.add_argument(
        "--address", metavar="ADDR",
        help="Ray cluster to join (HOST:PORT, ray://HOST:PORT or auto; default $RAY_ADDRESS, else a local Ray)",
    )
    run.add_argument(
        "--workers", type=_positive_int, default=None,
        help="local: worker processes (default: all cores); ray: tasks in flight (default: the cluster's CPUs)",
    )
    run.add_argument(
        "--chunk-size", type=_positive_int, default=None, metavar="K",
        help="episodes per chunk, the unit of work and of crash safety (default 8; a resume keeps the run's)",
    )
    run.add_argument("--resume", type=Path, metavar="RUN_DIR", help="finish an interrupted run")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.add_argument("--dry-run", action="store_true",
                     help="check the campaign and print its cells, episodes, chunks, warnings and an estimate of "
                          "the CPU time; run nothing")
    run.set_defaults(func=_cmd_run)

    est = sub.add_parser("estimate", help="estimate a target event's rate per cell, with sequential stopping")
    est.add_argument("campaign", nargs="?", type=Path, help="campaign TOML file")
    est.add_argument("--method", choices=("mc", "splitting", "importance"), default=None,
                     help="mc: crude Monte Carlo stopped on an anytime-valid interval (default); splitting: "
                          "adaptive multilevel splitting on the per-step noise; importance: cross-entropy "
                          "importance sampling over the scenario ranges (both in this process unless --workers "
                          "or --executor ray is given)")
    est.add_argument("--target", default=None,
                     help="event whose rate is estimated: collision (default), ellipse, unsafe, invariance, "
                          "opp_invariance")
    est.add_argument("--until-halfwidth", type=_halfwidth, default=None, metavar="H",
                     help="stop a cell when the interval's half-width is <= H (absolute, e.g. 0.01) or <= H "
                          "of the estimate (relative, e.g. 30%%)")
    est.add_argument("--budget", type=_positive_int, default=None, help="mc: most episodes per cell (default 1000)")
    est.add_argument("--level", type=_level, default=None, help="confidence level of the interval (default 0.95)")
    est.add_argument("--seed", type=_nonneg_int, help="campaign seed (overrides the file)")
    est.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="settings",
                     help="override a model parameter of the file (repeatable)")
    est.add_argument("--out", type=Path, metavar="DIR",
                     help="parent folder of the new estimate folder DIR/<name>-<timestamp> (default: "
                          "$MCVERIFY_RESULTS, else ./results)")
    est.add_argument("--run-dir", type=Path, dest="new_run_dir", metavar="RUN_DIR",
                     help="the exact (new or empty) folder for this estimate, instead of a fresh one under --out")
    est.add_argument("--executor", choices=("local", "ray", "serial"), default="local",
                     help="local worker processes (default), tasks on a Ray cluster, or this process")
    est.add_argument("--address", metavar="ADDR", help="Ray cluster to join (with --executor ray)")
    est.add_argument("--workers", type=_positive_int, default=None, help="worker processes or Ray tasks in flight")
    est.add_argument("--chunk-size", type=_positive_int, default=None, metavar="K",
                     help="mc: episodes per chunk, the unit of work and of the stopping checks (default 8)")
    est.add_argument("--score", choices=("gap", "gap_run", "h_ef", "h_ef_held", "h_ef_run"), default=None,
                     help="splitting, importance: footprint gap (target collision, the default) or gap_run (the gap "
                     "brought forward by the current run of steps with neither problem solved; target collision), "
                     "h_ef, h_ef_held or h_ef_run (h_ef brought forward by all such steps, or by the current run; "
                     "all three target ellipse); for importance it steers the cross-entropy stages only")
    est.add_argument("--particles", type=_positive_int, default=None, help="splitting: particles per run (default 20)")
    est.add_argument("--replicates", type=_positive_int, default=None,
                     help="splitting: independent runs whose spread gives the interval (default 8; "
                          "fewer under-cover, docs/rare_events.md)")
    est.add_argument("--cell", action="append", default=[], metavar="NAME",
                     help="splitting, importance: only this cell (repeatable; default: every cell); splitting runs its "
                          "AMS runs, importance its batches of 8 episodes, in this process unless --workers (local) "
                          "or --executor ray is given")
    est.add_argument("--samples", type=_positive_int, default=None,
                     help="importance: episodes drawn from the defensive mixture (default 400)")
    est.add_argument("--ce-samples", type=_positive_int, default=None,
                     help="importance: episodes per cross-entropy iteration (default 100)")
    est.add_argument("--elite-share", type=_open_unit, default=None, metavar="RHO",
                     help="importance: share of each cross-entropy iteration's episodes kept as its elite "
                          "(default 0.1; with few episodes per iteration a larger share keeps the elite at 10 or more)")
    est.add_argument("--ce-iterations", type=_nonneg_int, default=None,
                     help="importance: most cross-entropy iterations (default 10; 0: the scenario stays nominal, "
                          "e.g. with --noise-tilt when the score would steer the scenario away from the event)")
    est.add_argument("--noise-tilt", type=_noise_tilt, metavar="KEY=VALUE,...",
                     help="importance: draw veh_f's measurement noise near veh_f from exponential tilts, refitted "
                          "by the cross-entropy iterations, and weight each episode by its likelihood ratio; keys "
                          "gap_max_m (required), split_m, band_steps, defensive, theta_max and starting tilts "
                          "UNIT_BAND (x|y|v _ approach|jump|alongside) (docs/rare_events.md), e.g. "
                          "gap_max_m=4.1,split_m=3.05,y_approach=-5,y_jump=5")
    est.add_argument("--max-iterations", type=_positive_int, default=None,
                     help="splitting: iteration cap per run (default 2000; a capped run is flagged, not an estimate)")
    est.add_argument("--resume", type=Path, metavar="RUN_DIR", help="finish an interrupted estimate")
    est.add_argument("--no-progress", action="store_true", help="no progress bar")
    est.add_argument("--dry-run", action="store_true",
                     help="check the campaign and the options, say how many episodes the estimate may run and a "
                          "rough CPU range, and run nothing")
    est.set_defaults(func=_cmd_estimate)

    rep = sub.add_parser("replay", help="re-simulate one stored episode and write its trajectory")
    rep.add_argument("run_dir", type=Path,
                     help="run folder (a search's generation folder, e.g. SEARCH/generations/g000, is one), or "
                          "an importance-sampling or splitting estimate folder")
    rep.add_argument("episode_id", type=_nonneg_int,
                     help="the episode's id (column episode_id, from 0); in an importance-sampling estimate "
                          "folder a final draw's cell_episode, in a splitting one a failing particle's place in "
                          "the cell's failing_particles")
    rep.add_argument("--out", type=Path, help="folder for the trajectory and plot (default: RUN_DIR/replay)")
    rep.add_argument("--cell", metavar="NAME",
                     help="estimate folders: the cell of the draw or particle (needed when the folder "
                          "estimates several cells)")
    rep.set_defaults(func=_cmd_replay)

    rpt = sub.add_parser(
        "report", help="regenerate summary.json, cells.parquet, tables, figures, report.md and report.html"
    )
    rpt.add_argument("run_dir", type=Path)
    rpt.add_argument("--level", type=_level, default=0.95, help="confidence level of every interval (default 0.95)")
    rpt.add_argument("--method", choices=("clopper-pearson", "wilson"), default="clopper-pearson",
                     help="two-sided interval for rates (default: exact Clopper-Pearson)")
    rpt.add_argument("--bootstrap-resamples", type=_positive_int, default=2000,
                     help="resamples of the (seeded) bootstrap interval of every mean (default 2000)")
    rpt.add_argument("--format", action="append", choices=("png", "svg", "pdf"), dest="formats", default=[],
                     help="also write every figure in this format beside the report's PNG (repeatable)")
    rpt.add_argument("--dpi", type=_positive_int, default=None,
                     help="resolution of the --format files (default 300; the report's own PNGs stay at 100)")
    rpt.set_defaults(func=_cmd_report)

    bench = sub.add_parser("bench", help="the engine against the compiled IPOPT loop (and the naive loop), in one run")
    bench.add_argument("--campaign", default="campaigns/table4_fixed_start.toml",
                       help="campaign file (default: Table IV with veh_o on the road from the start)")
    bench.add_argument("--cell", default="all",
                       help="cell name of that campaign, or 'all' (default: all, the Table IV mix)")
    bench.add_argument("--engine-episodes", type=_positive_int, default=2, help="episodes per cell, engine")
    bench.add_argument("--baseline-episodes", type=_nonneg_int, default=2,
                       help="paired episodes per cell, compiled warm-started IPOPT loop (0: skip)")
    bench.add_argument("--naive-episodes", type=_nonneg_int, default=0,
                       help="paired episodes per cell, the paper-style Opti loop (0: skip, the default)")
    bench.add_argument("--backend", help="the engine's solver backend (default: the cell's)")
    bench.add_argument("--seed", type=_nonneg_int, help="campaign seed (overrides the file: other episodes)")
    bench.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="settings",
                       help="override a model parameter of every cell, on every side (repeatable)")
    bench.add_argument("--no-write", action="store_true", help="do not append to results/BENCHMARKS.md")
    bench.set_defaults(func=_cmd_bench)

    cmp = sub.add_parser("compare", help="per-cell differences between two runs (paired when they share episode keys)")
    cmp.add_argument("run_a", type=Path)
    cmp.add_argument("run_b", type=Path)
    cmp.add_argument("--level", type=_level, default=0.95, help="confidence level of the intervals (default 0.95)")
    cmp.add_argument("--test", choices=("fisher", "boschloo"), default="fisher",
                     help="exact test for unpaired cells (paired cells always use the exact McNemar test)")
    cmp.add_argument("--pair", nargs=2, action="append", metavar=("CELL_A", "CELL_B"),
                     help="compare these two cells (repeatable; default: cells with the same name)")
    cmp.add_argument("--out", type=Path, help="also write compare.md, compare.json and compare.tex here")
    cmp.set_defaults(func=_cmd_compare)

    ben = sub.add_parser("bench-solver", help="measure the solver backends against each other "
                         "(figures written into results/BENCHMARKS.md)")
    ben.add_argument("--campaign", type=Path, default=Path("campaigns/table2.toml"),
                     help="campaign whose cells are run (default: campaigns/table2.toml)")
    ben.add_argument("--episodes", type=_positive_int, default=2, help="paired episodes per cell and backend")
    ben.add_argument("--record-episodes", type=_positive_int, default=1,
                     help="reference episodes recorded for the per-solve timing (first cell)")
    ben.add_argument("--workers", type=_positive_int, default=None, help="worker processes (default: cores)")
    ben.add_argument("--chunk-size", type=_positive_int, default=4, help="episodes per chunk")
    ben.add_argument("--out", type=Path, default=Path("results/BENCHMARKS.md"),
                     help="Markdown file whose generated section is replaced (default: results/BENCHMARKS.md)")
    ben.set_defaults(func=_cmd_bench_solver)

    fal = sub.add_parser("falsify", help="search for counterexamples (robustness-guided; mcverify.falsify)")
    fal.add_argument("campaign", nargs="?", type=Path, help="campaign TOML file with a [falsify] table")
    fal.add_argument("--method", choices=("cma", "cross-entropy", "random", "bo", "splitting"),
                     help="search method (default cma; bo: Bayesian optimisation, needs the extra mcverify[bo]; "
                          "splitting: branches the best episodes with fresh per-step noise, for noise-driven failures)")
    fal.add_argument("--budget", type=_positive_int,
                     help="episodes the search may spend (required for a new search)")
    fal.add_argument("--requirement",
                     help="requirement to falsify: collision_front, collision_opp, ellipse, invariance, h_eo, "
                          "theorem5, theorem5_certified or safe (docs/falsification.md; default: the file's "
                          "[falsify] requirement, else safe)")
    fal.add_argument("--seed", type=_nonneg_int, help="search seed (default: the campaign's seed)")
    fal.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="settings",
                     help="override a model parameter of the file (repeatable)")
    fal.add_argument("--out", type=Path, metavar="DIR",
                     help="parent folder of the new search folder DIR/falsify-<name>-<method>-<timestamp> (default: "
                          "$MCVERIFY_RESULTS, else ./results)")
    fal.add_argument("--run-dir", type=Path, dest="new_run_dir", metavar="OUT",
                     help="the exact (new or empty) folder for this search, instead of a fresh one under --out")
    fal.add_argument("--executor", choices=("local", "ray", "serial"), default="local",
                     help="local worker processes (default), tasks on a Ray cluster, or this process")
    fal.add_argument("--address", metavar="ADDR", help="Ray cluster to join (with --executor ray)")
    fal.add_argument("--workers", type=_positive_int, default=None,
                     help="worker processes / Ray tasks in flight (default: the machine's cores)")
    fal.add_argument("--resume", type=Path, metavar="OUT", help="finish an interrupted search")
    fal.add_argument("--no-progress", action="store_true", help="no per-generation lines and no progress bar")
    fal.add_argument("--dry-run", action="store_true",
                     help="check the campaign, its [falsify] table and the options, say what the search would "
                          "spend, and run nothing")
    fal.set_defaults(func=_cmd_falsify)

    bf = sub.add_parser("bench-falsify", help="success rate and median episodes to the first counterexample per "
                        "search method and target (written into results/BENCHMARKS.md)")
    bf.add_argument("targets", nargs="*", type=Path,
                    help="campaign files with [falsify] (default: the five benchmark targets falsify_mpcdc_table4b, "
                    "falsify_vlcbf_eps0_noise2, falsify_theorem5_opposing, falsify_theorem5_certified_opposing, "
                    "falsify_vlcbf_eps03_paper_noise in campaigns/)")
    bf.add_argument("--methods", default="cma,cross-entropy,random", help="comma-separated methods")
    bf.add_argument("--trials", type=_positive_int, default=10, help="independent trials per method and target")
    bf.add_argument("--budget", type=_positive_int, default=100, help="episodes per trial")
    bf.add_argument("--seed", type=_nonneg_int, default=0, help="seed of the first trial (then seed+1, ...)")
    bf.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="settings",
                    help="override a model parameter of every target (repeatable)")
    bf.add_argument("--out-dir", type=Path, default=Path("results/bench-falsify"), help="search folders")
    bf.add_argument("--workers", type=_positive_int, default=None, help="worker processes")
    bf.add_argument("--write", type=Path, default=Path("results/BENCHMARKS.md"), help="Markdown file to update")
    bf.add_argument("--no-write", action="store_true", help="print the section only")
    bf.set_defaults(func=_cmd_bench_falsify)

    rare = sub.add_parser("bench-rare", help="splitting against crude Monte Carlo on the calibration walk "
                          "(p about 1e-4; section written into results/BENCHMARKS.md)")
    rare.add_argument("--barrier", type=float, default=6.2, help="event level of the walk (default 6.2: p ~ 1e-4)")
    rare.add_argument("--particles", type=_positive_int, default=100, help="particles per AMS run (default 100)")
    rare.add_argument("--replicates", type=_positive_int, default=25,
                      help="AMS runs per estimate (default 25: about +-30 %% at p ~ 1e-4)")
    rare.add_argument("--repetitions", type=_positive_int, default=20, help="independent estimates (default 20)")
    rare.add_argument("--reference-episodes", type=_positive_int, default=30_000_000,
                      help="crude reference walks (default 30000000)")
    rare.add_argument("--no-write", action="store_true", help="do not write into results/BENCHMARKS.md")
    rare.set_defaults(func=_cmd_bench_rare)

    plant = sub.add_parser("bench-plant", help="the JAX side alone (plant, noise, safety checks) per batch size, on "
                           "CPU and on a GPU where one is present (section written into results/BENCHMARKS.md)")
    plant.add_argument("--campaign", type=Path, default=Path("campaigns/table4.toml"),
                       help="campaign whose first cell is simulated (default campaigns/table4.toml)")
    plant.add_argument("--batches", type=_int_list, default=None,
                       help="comma-separated batch sizes (default: CPU 8,64,512,4096; GPU up to 262144)")
    plant.add_argument("--steps", type=_positive_int, default=None,
                       help="control steps per timed rollout (default 250, at most the cell's episode)")
    plant.add_argument("--repeats", type=_positive_int, default=3, help="timed rollouts per batch (default 3)")
    plant.add_argument("--platforms", default="cpu,gpu", help="JAX backends to measure where present (default cpu,gpu)")
    plant.add_argument("--include", type=Path, action="append", default=[], metavar="JSON",
                       help="results of this bench from another machine (its --json file), shown beside this run's")
    plant.add_argument("--only-include", action="store_true",
                       help="measure nothing here: write the section from the --include files alone")
    plant.add_argument("--json", type=Path, default=None, help="also write this run's results as JSON")
    plant.add_argument("--no-write", action="store_true", help="do not write into results/BENCHMARKS.md")
    plant.set_defaults(func=_cmd_bench_plant)

    val = sub.add_parser("bench-validate", help="the rare-event estimators against a crude Monte Carlo reference on "
                         "one closed-loop cell: coverage, bias, relative error, cost (section written into "
                         "results/BENCHMARKS.md)")
    val.add_argument("reference", type=Path, help="crude Monte Carlo estimate folder (mcverify estimate --method mc)")
    val.add_argument("--splitting", type=Path, nargs="+", action="append", default=[], metavar="DIR",
                     help="splitting estimate folders of the same cell, target, particles and score, distinct seeds "
                     "(repeat the option for another pool, e.g. another score)")
    val.add_argument("--importance", type=Path, nargs="+", default=[], metavar="DIR",
                     help="importance estimate folders of the same cell and target, distinct seeds")
    val.add_argument("--group", type=_positive_int, nargs="+", default=[4], metavar="R",
                     help="splitting: AMS runs per repetition (the estimator's --replicates), one row per value "
                     "(default 4)")
    val.add_argument("--sequential", type=_halfwidth, nargs="+", default=[], metavar="H",
                     help="crude Monte Carlo with sequential stopping: the reference's episodes cut into consecutive "
                     "runs of --until-halfwidth H (absolute, e.g. 0.08, or relative, e.g. 50%%), each checked against "
                     "the reference without its episodes; one row per H, and the invalid fixed-n Clopper-Pearson "
                     "stopping beside it")
    val.add_argument("--write", type=Path, default=Path("results/BENCHMARKS.md"), help="Markdown file to update")
    val.add_argument("--no-write", action="store_true", help="print the section only")
    val.add_argument("--json", type=Path, default=None, help="also write every figure as JSON to this file")
    val.add_argument("--figure", type=Path, default=None, metavar="PNG",
                     help="also draw every repetition's interval against the reference into this PNG")
    val.set_defaults(func=_cmd_bench_validate)

    fld = sub.add_parser("fields", help="every model field a campaign can set: type, unit, default, meaning")
    fld.add_argument("pattern", nargs="?", default="", help="only fields whose name contains this text")
    fld.set_defaults(func=_cmd_fields)

    ker = sub.add_parser("kernels", help="the compiled-solver cache")
    ker.set_defaults(help_parser=ker)  # `mcverify kernels` alone prints this help, not the top-level one
    ksub = ker.add_subparsers(metavar="ACTION")
    kl = ksub.add_parser("list", help="list cached kernels", parents=[common])
    kl.set_defaults(func=_cmd_kernels_list)
    kc = ksub.add_parser("clear", help="delete cached kernels", parents=[common])
    kc.set_defaults(func=_cmd_kernels_clear)
    return p


def _cmd_run(args) -> int:
    from mcverify.campaign import executors, runner
    from mcverify.campaign.spec import load_campaign
    from mcverify.errors import RunError

    if args.address is not None and args.executor != "ray":
        raise RunError("--address is for the Ray executor: add --executor ray")
    progress = not args.no_progress
    if args.resume and args.dry_run:
        raise RunError("--dry-run checks a campaign file; it does not apply to --resume")
    if args.resume:
        if args.episodes is not None or args.seed is not None or args.settings:
            raise RunError("--resume keeps the run's episodes, seed and settings: leave out --episodes, --seed "
                           "and --set")
        if args.out is not None or args.new_run_dir is not None:
            raise RunError("--resume writes into RUN_DIR: leave out --out and --run-dir")
        # A campaign file given with --resume is a check: it must be the one the run started with.
        campaign = load_campaign(args.campaign) if args.campaign else None
        executor = executors.make_executor(args.executor, workers=args.workers, address=args.address)
        args.run_dir = args.resume

        def resuming(planned: int, done: int) -> None:
            _log.info("resuming %s: %d of %d chunks already done", args.resume, done, planned)

        path = runner.resume(
            args.resume, executor=executor, progress=progress, campaign=campaign, chunk_size=args.chunk_size,
            on_start=resuming,
        )
    else:
        if args.campaign is None:
            raise RunError("missing campaign file, e.g. `mcverify run campaigns/smoke.toml`")
        campaign = load_campaign(args.campaign, episodes=args.episodes, seed=args.seed, settings=args.settings)
        if args.dry_run:
            from mcverify.campaign import cost, lint

            for warning in lint.warnings(campaign):
                _log.warning("warning: %s", warning)
            searched = None
            if campaign.falsify is not None:  # checked first: a bad table is the only line printed
                from mcverify.falsify.command import describe_table

                searched = describe_table(args.campaign, args.settings)
            print(cost.render(campaign, args.chunk_size or runner.DEFAULT_CHUNK_SIZE,
                              args.workers or executors.default_workers()))
            if searched:
                print(searched)
            return 0
        out = args.run_dir = new_folder(args, lambda parent: runner.default_run_dir(campaign, parent))
        executor = executors.make_executor(args.executor, workers=args.workers, address=args.address)

        def starting(planned: int, done: int) -> None:  # after every check: errors stay one line
            _log.info("%s", runner.describe(campaign))
            how = ", ".join(f"{k} {v}" for k, v in executor.describe().items() if v is not None)
            _log.info("run folder: %s (%d chunks; %s)", out, planned, how)

        path = runner.run(
            campaign, out, executor=executor, chunk_size=args.chunk_size or runner.DEFAULT_CHUNK_SIZE,
            progress=progress, on_start=starting,
        )
    print(path.read_text())
    _log.info("report: %s", path)
    return 0


def new_folder(args, fresh) -> Path:
    """The folder of a new run or estimate (:func:`mcverify.campaign.runner.new_folder`)."""
    from mcverify.campaign import runner

    return runner.new_folder(args.out, args.new_run_dir, fresh)


def _cmd_falsify(args) -> int:
    from mcverify.falsify.command import falsify

    return falsify(args)


def _cmd_bench_falsify(args) -> int:
    from mcverify.falsify.command import bench_falsify

    return bench_falsify(args, argv=sys.argv[1:])


#: ``mcverify estimate`` options that only some methods read: (attribute, option, methods).
_ESTIMATE_METHOD_OPTIONS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("until_halfwidth", "--until-halfwidth", ("mc",)),
    ("budget", "--budget", ("mc",)),
    ("chunk_size", "--chunk-size", ("mc",)),
    ("score", "--score", ("splitting", "importance")),
    ("cell", "--cell", ("splitting", "importance")),
    ("particles", "--particles", ("splitting",)),
    ("replicates", "--replicates", ("splitting",)),
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


def _cmd_estimate(args) -> int:
    from mcverify.campaign import executors, runner
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
    if method in ("splitting", "importance"):
        return _cmd_estimate_in_process(args, method)
    executor = executors.make_executor(args.executor, workers=args.workers, address=args.address)
    if args.resume:
        if args.campaign or args.out or args.new_run_dir or args.seed is not None or args.settings:
            raise RunError("--resume keeps the estimate's campaign and rule: give only RUN_DIR (and the executor)")
        args.run_dir = args.resume

        def resuming(planned: int, done: int) -> None:
            _log.info("resuming %s: %d of %d chunks already done", args.resume, done, planned)

        path = mc.resume(args.resume, executor=executor, progress=not args.no_progress, on_start=resuming)
    else:
        spec = _estimate_spec(args, "mc")
        campaign = _estimate_campaign(args, "mc")
        out = args.run_dir = new_folder(args, lambda parent: runner.default_run_dir(campaign, parent))
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
    from mcverify.estimate import importance_run, splitting_run

    if args.campaign is None:
        raise RunError("missing campaign file, e.g. `mcverify estimate campaigns/eps_sweep_rare.toml`")
    if method != "mc" and args.target not in ("collision", "ellipse"):
        raise RunError(f"{method} estimates --target collision or ellipse")
    try:
        if method == "mc":
            halfwidth, relative = args.until_halfwidth or (None, False)
            return EstimateSpec(args.method, args.target, halfwidth, relative, args.budget, args.level)
        if method == "splitting":
            score = args.score or ("gap" if args.target == "collision" else "h_ef")
            spec = splitting_run.SplittingSpec(score, args.particles, 1, args.replicates, args.level,
                                               args.max_iterations)
            if spec.target != args.target:
                raise RunError(f"--score {score} estimates {spec.target}, not --target {args.target}")
            return spec
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
        max_iterations=args.max_iterations, cells=tuple(args.cell), workers=workers)
    print(plan.render(campaign, options))
    return 0


def _executor_for(args, method: str) -> dict:
    """splitting and importance: their work units (AMS runs; batches of episodes) go to the executor
    named on the command line (default: this process)."""
    from mcverify.campaign import executors

    if method not in ("splitting", "importance"):
        return {}
    kind = "serial" if args.executor == "local" and args.workers is None else args.executor
    return {"executor": executors.make_executor(kind, workers=args.workers, address=args.address)}


def _folder_method(run_dir: Path) -> str | None:
    """The method recorded in an estimate folder's manifest (None if unreadable or absent)."""
    import json

    try:
        return json.loads((run_dir / "manifest.json").read_text()).get("estimate", {}).get("method")
    except (OSError, ValueError, AttributeError):
        return None


def _cmd_estimate_in_process(args, method: str) -> int:
    from mcverify.campaign import runner
    from mcverify.campaign.spec import campaign_from_dict
    from mcverify.errors import RunError
    from mcverify.estimate import importance_run, splitting_run

    module = splitting_run if method == "splitting" else importance_run
    # progress lines on stderr, unless -q ("only warnings and errors on stderr")
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))  # noqa: E731
    if args.resume:
        from mcverify import store

        if args.out is not None or args.new_run_dir is not None:
            raise RunError("--resume writes into RUN_DIR: leave out --out and --run-dir")
        if args.campaign or args.seed is not None or args.settings:
            raise RunError("--resume keeps the estimate's campaign, seed and settings: give only RUN_DIR (and the "
                           "executor)")
        manifest = store.read_manifest(args.resume)
        camp = manifest["campaign"]
        campaign = runner.with_recorded_params(  # the cells' parameters as the run recorded them
            campaign_from_dict(camp["raw"], source=camp["source"], seed=camp["seed"]), manifest.get("cells", []),
            str(args.resume))
        path = module.resume(args.resume, campaign, progress=log, **_executor_for(args, method))
    else:
        spec = _estimate_spec(args, method)
        campaign = _estimate_campaign(args, method)  # checked before any folder is made
        out = args.run_dir = new_folder(args, lambda parent: runner.default_run_dir(campaign, parent))
        log(runner.describe(campaign, episodes=False))  # the estimator chooses how many episodes
        log(f"estimate folder: {out}")
        path = module.run(campaign, spec, out, progress=log, cells=args.cell or None, **_executor_for(args, method))
    print(path.read_text())
    _log.info("report: %s", path)
    return 0


def _cmd_replay(args) -> int:
    from mcverify import api
    from mcverify.campaign.replay import ReplayMismatch
    from mcverify.estimate.replay import estimate_method

    method = estimate_method(args.run_dir)
    try:
        res = api.replay(args.run_dir, args.episode_id, args.out, cell=args.cell)
    except ReplayMismatch as err:
        print(f"mcverify: replay FAILED: {err}", file=sys.stderr)
        return EXIT_MISMATCH
    if method == "splitting":
        print(f"failing particle {res.episode_id} reproduced exactly (its running score at its last step) "
              f"({res.row['outcome']}, safe={res.row['safe']})")
    else:
        kept = " (the values its estimate folder keeps)" if method else ""
        print(f"episode {res.episode_id} reproduced exactly{kept} ({res.row['outcome']}, safe={res.row['safe']})")
    if res.not_stored:
        print(f"(not compared: {len(res.not_stored)} column(s) newer than the run: {', '.join(res.not_stored)})")
    print(f"trajectory: {res.trajectory_path}")
    print(f"plot: {res.plot_path}")
    return 0


def _cmd_report(args) -> int:
    from mcverify.reporting import run_report

    if args.dpi is not None and not args.formats:
        from mcverify.errors import RunError

        raise RunError("--dpi sets the resolution of the --format files: add --format png, svg or pdf")
    path = run_report.write(
        args.run_dir, level=args.level, method=args.method, bootstrap_resamples=args.bootstrap_resamples,
        figure_formats=args.formats, figure_dpi=args.dpi or 300,
    )
    print(f"report: {path} (also report.html, summary.json, cells.parquet, tables/, figures/)")
    return 0


def _cmd_compare(args) -> int:
    from mcverify.reporting import compare

    result = compare.compare_runs(
        compare.load_run(args.run_a),
        compare.load_run(args.run_b),
        level=args.level,
        test=args.test,
        pairs=[tuple(p) for p in args.pair] if args.pair else None,
    )
    if not result["comparisons"]:
        from mcverify.errors import RunError

        raise RunError(
            f"no cell of {args.run_a} matches a cell of {args.run_b} by name "
            f"(A: {'; '.join(result['only_in_a']) or 'none'}; B: {'; '.join(result['only_in_b']) or 'none'}); "
            "give pairs with --pair CELL_A CELL_B"
        )
    print(compare.render_markdown(result))
    if args.out:
        for path in compare.write(args.out, result):
            print(f"wrote {path}", file=sys.stderr)
    return 0


def _cmd_bench(args) -> int:
    from mcverify.bench import engine, engine_report
    from mcverify.campaign.spec import CampaignError

    if max(args.naive_episodes, args.baseline_episodes) > args.engine_episodes:
        raise CampaignError("--baseline-episodes and --naive-episodes must be at most --engine-episodes "
                            "(their episodes are paired with the engine's)")
    result = engine.run(
        campaign=args.campaign, cell_name=args.cell, engine_episodes=args.engine_episodes,
        baseline_episodes=args.baseline_episodes, naive_episodes=args.naive_episodes, backend=args.backend,
        write=not args.no_write, progress=lambda msg: print(msg, file=sys.stderr),
        seed=args.seed, settings=args.settings,
    )
    print(engine_report.render(result))
    if not args.no_write:
        print(f"appended to {engine_report.BENCHMARKS_MD}", file=sys.stderr)
    return 0


def _cmd_bench_solver(args) -> int:
    from datetime import datetime

    from mcverify.bench import solver_bench, solver_bench_report
    from mcverify.campaign import executors
    from mcverify.campaign.spec import CampaignError

    if not args.campaign.is_file():
        raise CampaignError(f"campaign file not found: {args.campaign}")
    workers = args.workers or executors.default_workers()
    command = "mcverify " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["bench-solver"] else "mcverify bench-solver"
    results = solver_bench.run(args.campaign, args.episodes, args.record_episodes, workers, args.chunk_size)
    section = solver_bench_report.markdown(results, command)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    solver_bench_report.write_section(args.out, section)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    json_path = args.out.parent / f"bench-solver-{stamp}.json"
    json_path.write_text(solver_bench_report.to_json(results))
    print(section)
    print(f"written: {args.out} (section), {json_path}", file=sys.stderr)
    return 0


def _cmd_bench_rare(args) -> int:
    from mcverify.bench import rare
    from mcverify.errors import UserError

    if args.replicates < 2:
        raise UserError("--replicates must be at least 2 (the interval comes from their spread)")
    if args.particles < 2:
        raise UserError(f"--particles must be at least 2 (got {args.particles}): each AMS iteration kills the lowest "
                        "particle and branches a survivor")
    res = rare.run(barrier=args.barrier, particles=args.particles, replicates=args.replicates,
                   repetitions=args.repetitions, reference_episodes=args.reference_episodes)
    command = "mcverify " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["bench-rare"] else "mcverify bench-rare"
    text = rare.markdown(res, command)
    print(text)
    if not args.no_write:
        rare.write(res, command, Path("results/BENCHMARKS.md"))
        print("written: results/BENCHMARKS.md (section)", file=sys.stderr)
    return 0


def _cmd_bench_plant(args) -> int:
    import json

    from mcverify import store
    from mcverify.bench import plant_scaling
    from mcverify.errors import UserError

    included = []
    for path in args.include:
        try:
            included += json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            raise UserError(f"--include {path}: not a bench-plant JSON file ({err})") from None
    if args.only_include and not included:
        raise UserError("--only-include needs at least one --include JSON file")
    platforms = [p.strip() for p in args.platforms.split(",") if p.strip()]
    unknown = [p for p in platforms if p not in plant_scaling.KNOWN_PLATFORMS]
    if unknown or not platforms:
        raise UserError(f"--platforms {args.platforms!r}: unknown backend {', '.join(unknown) or '(none given)'}; "
                        f"known: {', '.join(plant_scaling.KNOWN_PLATFORMS)}")
    results = [] if args.only_include else plant_scaling.run(
        args.campaign, args.batches, args.steps, args.repeats, platforms,
        progress=lambda line: print(line, file=sys.stderr))
    if not args.only_include and not results:
        raise UserError(f"--platforms {args.platforms}: none of these JAX backends is on this machine; nothing was "
                        "measured and results/BENCHMARKS.md was left as it was")
    if args.json:
        store.atomic_write_bytes(args.json, json.dumps(results, indent=1).encode())
    command = "mcverify " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["bench-plant"] else "mcverify bench-plant"
    text = plant_scaling.markdown(included + results, command)
    print(text)
    if not args.no_write:
        store.replace_section(Path("results/BENCHMARKS.md"), text, plant_scaling.BEGIN, plant_scaling.END)
        print("written: results/BENCHMARKS.md (section)", file=sys.stderr)
    return 0


def _cmd_bench_validate(args) -> int:
    from mcverify import store
    from mcverify.bench import validation

    res = validation.run(args.reference, splitting_pools=args.splitting, importance_dirs=args.importance,
                         groups=args.group, sequential=args.sequential)
    command = "mcverify " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["bench-validate"] else "mcverify bench-validate"
    text = validation.markdown(res, command)
    print(text)
    if args.json:
        store.write_json_atomic(args.json, res)
    if args.figure:
        print(f"figure: {validation.figure(res, args.figure)}", file=sys.stderr)
    if not args.no_write:
        validation.write(res, command, args.write)
        print(f"written: {args.write} (section)", file=sys.stderr)
    return 0


def _cmd_fields(args) -> int:
    from mcverify import fields

    table = fields.markdown_table().splitlines()
    rows = [row for row in table[2:] if args.pattern in row.split("|")[1]]
    if not rows:
        from mcverify.errors import CampaignError

        raise CampaignError(f"no model field contains {args.pattern!r} (`mcverify fields` lists them all)")
    print("\n".join(table[:2] + rows))
    return 0


def _cmd_kernels_list(args) -> int:
    from mcverify.solver import kernels

    rows = kernels.list_kernels()
    if not rows:
        print("no cached kernels")
    for r in rows:
        print("  ".join(f"{k}={v}" for k, v in r.items()))
    return 0


def _cmd_kernels_clear(args) -> int:
    from mcverify.solver import kernels

    print(f"removed {kernels.clear_kernels()} kernel(s)")
    return 0


class _VersionAction(argparse.Action):
    """``--version``: ``mcverify X.Y.Z`` and, in a git checkout, the commit it runs from (asked of git
    only when the option is given)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        from mcverify import __version__, provenance

        commit = provenance.git_commit(short=True)
        print(f"mcverify {__version__}" + (f" (git {commit})" if commit else ""))
        parser.exit(0)


def _int_list(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        values = ()
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}")
    return values


def _noise_tilt(text: str) -> dict:
    """``--noise-tilt gap_max_m=4,split_m=3,y_approach=-5,y_jump=5``: the starting NoiseTilt (the rest
    at their defaults; a tilt per band and unit is named UNIT_BAND, e.g. y_jump)."""
    from mcverify.sim.noise import TILT_BANDS, TILT_UNITS, NoiseTilt  # noqa: PLC0415 - JAX only when used

    tilts = [f"{u}_{b}" for b in TILT_BANDS for u in TILT_UNITS]
    scalars = [f for f in NoiseTilt._fields if f != "theta"]
    values: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = (x.strip() for x in part.partition("="))
        if not sep or key not in (*scalars, *tilts):
            raise argparse.ArgumentTypeError(f"expected KEY=VALUE with KEY one of {', '.join(scalars)} or a tilt "
                                             f"UNIT_BAND ({', '.join(tilts)}), got {part!r}")
        try:
            values[key] = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{key}: not a number: {value!r}") from None
    if "gap_max_m" not in values:
        raise argparse.ArgumentTypeError("gap_max_m is required (the tilt acts where veh_f's gap is at most that)")
    theta = [values.pop(t, 0.0) for t in tilts]
    return {**NoiseTilt(**values)._asdict(), "theta": theta}


def _positive_int(text: str) -> int:
    value = _int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _nonneg_int(text: str) -> int:
    value = _int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _halfwidth(text: str) -> tuple[float, bool]:
    """``0.01`` (absolute) or ``30%`` (relative to the estimate) -> (value, relative)."""
    relative = text.strip().endswith("%")
    try:
        value = float(text.strip().rstrip("%"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or a percentage, e.g. 0.01 or 30%, got {text!r}") from None
    value = value / 100.0 if relative else value
    if not 0.0 < value < (1.0 if not relative else float("inf")):
        raise argparse.ArgumentTypeError(f"must be > 0 (and < 1 when absolute), got {text}")
    return value, relative


def _open_unit(text: str, example: str = "") -> float:
    """A number strictly between 0 and 1 (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}") from None
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1){', e.g. ' + example if example else ''}, got {value}")
    return value


def _level(text: str) -> float:
    return _open_unit(text, "0.95")


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


if __name__ == "__main__":
    sys.exit(main())
