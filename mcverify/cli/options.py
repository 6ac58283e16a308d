"""The command line's shared parts: one-line usage errors, the argument types, and the option
blocks several commands take (verbosity, campaign, folder, executor), each written once as a parent
parser."""

from __future__ import annotations

import argparse
from pathlib import Path

#: Exit status of a usage error (and of every user error).
EXIT_USAGE = 2
#: Exit status of a replay that does not reproduce its episode.
EXIT_MISMATCH = 1


class UsageError(Exception):
    """A command-line usage error (argparse's), reported as one line instead of usage + message."""


class Parser(argparse.ArgumentParser):
    def error(self, message: str):  # argparse would print the usage block and exit
        raise UsageError(f"{self.prog}: {message} (see `{self.prog} --help`)")


class VersionAction(argparse.Action):
    """``--version``: ``mcverify X.Y.Z`` and, in a git checkout, the commit it runs from (asked of git
    only when the option is given)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        from mcverify import __version__, provenance

        commit = provenance.git_commit(short=True)
        print(f"mcverify {__version__}" + (f" (git {commit})" if commit else ""))
        parser.exit(0)


# ----------------------------------------------------------------------------- parent parsers


def verbosity() -> argparse.ArgumentParser:
    """-v / -q, taken by every command."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("-v", "--verbose", action="count", default=0, help="more detail on stderr")
    p.add_argument("-q", "--quiet", action="count", default=0,
                   help="only warnings and errors on stderr (no progress bar, no notices)")
    return p


def campaign(file_help: str = "campaign TOML file", seed_help: str = "campaign seed (overrides the file)"
             ) -> argparse.ArgumentParser:
    """The campaign file (optional: ``--resume`` needs none), its seed and ``--set`` overrides."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("campaign", nargs="?", type=Path, help=file_help)
    p.add_argument("--seed", type=nonneg_int, help=seed_help)
    p.add_argument(
        "--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="settings",
        help="override a model parameter of the file, e.g. --set mpc.backend=ipopt (repeatable)",
    )
    return p


def folder(noun: str, pattern: str, metavar: str = "RUN_DIR",
           progress_help: str = "no progress bar") -> argparse.ArgumentParser:
    """Where a new run, estimate or search goes (``--out`` or ``--run-dir``), ``--resume`` of an
    interrupted one, and ``--no-progress``. ``pattern``: the name of a fresh folder under ``--out``."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--out", type=Path, metavar="DIR",
                   help=f"parent folder of the new {noun} folder DIR/{pattern} (default: $MCVERIFY_RESULTS, "
                        "else ./results)")
    p.add_argument("--run-dir", type=Path, dest="new_run_dir", metavar=metavar,
                   help=f"the exact (new or empty) folder for this {noun}, instead of a fresh one under --out")
    p.add_argument("--resume", type=Path, metavar=metavar,
                   help=f"finish an interrupted {noun} (a complete one: nothing to run, exit 0)")
    p.add_argument("--no-progress", action="store_true", help=progress_help)
    return p


def executor(choices: tuple[str, ...] = ("local", "ray", "serial"),
             workers_help: str = "worker processes / Ray tasks in flight (default: the machine's cores)"
             ) -> argparse.ArgumentParser:
    """Where the episodes run: local worker processes, a Ray cluster or (where offered) this process."""
    p = argparse.ArgumentParser(add_help=False)
    where = ("local worker processes (default), tasks on a Ray cluster, or this process" if "serial" in choices
             else "local worker processes (default) or tasks on a Ray cluster")
    p.add_argument("--executor", choices=choices, default="local", help=where)
    p.add_argument("--address", metavar="ADDR",
                   help="Ray cluster to join (HOST:PORT, ray://HOST:PORT or auto; default $RAY_ADDRESS, else a "
                        "local Ray; with --executor ray)")
    p.add_argument("--workers", type=positive_int, default=None, help=workers_help)
    return p


# ----------------------------------------------------------------------------- argument types


def int_list(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        values = ()
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}")
    return values


def noise_tilt(text: str) -> dict:
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


def positive_int(text: str) -> int:
    value = integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def nonneg_int(text: str) -> int:
    value = integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def halfwidth(text: str) -> tuple[float, bool]:
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


def open_unit(text: str, example: str = "") -> float:
    """A number strictly between 0 and 1 (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}") from None
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1){', e.g. ' + example if example else ''}, got {value}")
    return value


def level(text: str) -> float:
    return open_unit(text, "0.95")


def integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


# ----------------------------------------------------------------------------- --resume


#: Where each kind of folder records that it is complete (``finished_utc``): a run's or an estimate's
#: manifest, a falsification search's ``falsify.json``.
_FINISHED_RECORDS = ("manifest.json", "falsify.json")


def already_complete(run_dir: Path | None) -> bool:
    """Whether ``run_dir`` holds a complete run, estimate or search. The one ``--resume`` rule of
    ``run``, ``estimate`` and ``falsify``: resuming a complete folder is no error; it runs and rewrites
    nothing, says so (:func:`say_complete`) and exits 0 (``mcverify report`` rebuilds a report)."""
    import json

    if run_dir is None:
        return False
    for name in _FINISHED_RECORDS:
        try:
            record = json.loads((Path(run_dir) / name).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(record, dict) and record.get("finished_utc"):
            return True
    return False


def say_complete(run_dir: Path) -> int:
    """The line a ``--resume`` of a complete folder prints (on stdout, where the report would go); exit 0."""
    print(f"{run_dir} is already complete: nothing to run (`mcverify report {run_dir}` rebuilds its report)")
    return 0
