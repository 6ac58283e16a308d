"""mcverify: Monte-Carlo verification and falsification of the TO-CBF-MPC overtaking controller.

Every user error (bad campaign, missing run folder, bad argument) ends with one line on stderr and
exit status 2; a replay that does not reproduce exits with status 1.

One module per command (:mod:`~mcverify.cli.run`, ``estimate``, ``replay``, ``report``, ``compare``,
``export``, ``falsify``, ``fields``, ``kernels``), each with ``add`` (its arguments) and its command function; the
option blocks several commands share are parent parsers in :mod:`~mcverify.cli.options`.
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
from mcverify.cli import compare, estimate, export, falsify, fields, kernels, options, replay, report, run

_log = logging.getLogger("mcverify.cli")

EXIT_USAGE = options.EXIT_USAGE
EXIT_MISMATCH = options.EXIT_MISMATCH
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
    except options.UsageError as err:
        print(f"mcverify: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except SystemExit as done:  # --help, --version: printed, nothing to run
        return done.code if isinstance(done.code, int) else 0
    if not hasattr(args, "handler"):
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
    if command == "falsify":
        try:
            method = json.loads((run_dir / "falsify.json").read_text()).get("method")
        except (OSError, ValueError, AttributeError):
            method = None
        if method == "beam":
            return "finished depths are kept"
    return "finished chunks are kept"


def _dispatch(args) -> int:
    from mcverify.errors import UserError

    try:
        with _sigterm_as_interrupt():
            return globals()[f"_cmd_{args.handler}"](args) or 0  # looked up here: tests replace a command
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


#: The command functions by handler name (``_cmd_<handler>``), looked up when a command runs.
_cmd_run = run.command
_cmd_estimate = estimate.command
_cmd_replay = replay.command
_cmd_report = report.command
_cmd_compare = compare.command
_cmd_export = export.command
_cmd_falsify = falsify.command
_cmd_fields = fields.command
_cmd_kernels_list = kernels.list_command
_cmd_kernels_clear = kernels.clear_command

#: The commands in the order ``mcverify --help`` lists them.
_COMMANDS = (run, estimate, replay, report, compare, export, falsify, fields, kernels)


def _parser() -> argparse.ArgumentParser:
    p = options.Parser(prog="mcverify", description=__doc__.splitlines()[0])
    p.add_argument("--version", action=options.VersionAction, help="print the version (and git commit) and exit")
    sub = p.add_subparsers(metavar="COMMAND", parser_class=options.Parser, dest="command")
    parents = [options.verbosity()]  # every command takes -v / -q
    for module in _COMMANDS:
        module.add(sub, parents)
    return p


if __name__ == "__main__":
    sys.exit(main())
