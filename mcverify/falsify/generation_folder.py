"""One generation of a falsification search as its run folder ``OUT/generations/gNNN``.

A generation is an ordinary campaign run (:mod:`mcverify.campaign.runner`): :func:`run` starts it, or
resumes it chunk by chunk when its manifest is there; :func:`is_finished` says whether it is complete;
:func:`check_same` refuses a stored generation whose cells (or error schedules) are not the candidates
the search asks now, so a resumed search never mixes candidates of another search into its own.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mcverify import store
from mcverify.campaign import runner
from mcverify.campaign.executors import EpisodeFn, Executor
from mcverify.campaign.spec import Campaign
from mcverify.episode import schedule_file
from mcverify.errors import RunError
from mcverify.sim.schedule import ErrorInput

#: The folder of a search's generations, one run folder each (``gNNN``).
GENERATIONS = "generations"


def path(out_dir: Path, generation: int) -> Path:
    """Generation ``generation``'s run folder in the search folder ``out_dir``."""
    return Path(out_dir) / GENERATIONS / f"g{int(generation):03d}"


def is_finished(gen_dir: Path) -> bool:
    """Whether the generation's run is complete (its manifest records ``finished_utc``)."""
    manifest = gen_dir / store.MANIFEST
    return manifest.is_file() and bool(store.read_json(manifest).get("finished_utc"))


def check_same(gen_dir: Path, campaign: Campaign, schedules: dict[int, ErrorInput] | None = None) -> None:
    """RunError unless the stored generation ran ``campaign``'s cells (and, with an adversary, ``schedules``)."""
    recorded = store.read_json(gen_dir / store.MANIFEST)["cells"]
    diff = runner.first_difference(recorded, runner.campaign_record(campaign)["cells"])
    if not diff and schedules is not None:
        folder = gen_dir / schedule_file.SCHEDULES
        diff = next((f"episode {e}'s error schedule" for e, s in sorted(schedules.items())
                     if not _same_schedule(schedule_file.read_schedule(schedule_file.schedule_path(folder, e)), s)),
                    "")
    if diff:
        raise RunError(f"{gen_dir}: the search asks other candidates than this generation ran ({diff}); "
                       "was the folder made by other code or edited?")


def _same_schedule(a: ErrorInput, b: ErrorInput) -> bool:
    return type(a) is type(b) and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a, b, strict=True))


def run(campaign: Campaign, gen_dir: Path, make_executor: Callable[[], Executor],
        episode_fn: EpisodeFn, bar: bool = False, schedules: dict[int, ErrorInput] | None = None) -> None:
    """Run the generation into ``gen_dir``, or resume it if its manifest was written."""
    if (gen_dir / store.MANIFEST).is_file():  # its schedules, if any, are in the folder already
        runner.resume(gen_dir, executor=make_executor(), progress=bar, campaign=campaign, episode_fn=episode_fn)
        return
    if gen_dir.exists():  # killed before its manifest was written: nothing of it is usable
        shutil.rmtree(gen_dir)
    gen_dir.parent.mkdir(parents=True, exist_ok=True)
    runner.run(campaign, gen_dir, executor=make_executor(), progress=bar, episode_fn=episode_fn, schedules=schedules)
