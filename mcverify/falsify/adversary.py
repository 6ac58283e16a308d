"""The adversary's entry points: run episodes of a campaign cell under given error schedules.

The perception error is the input (:mod:`mcverify.sim.schedule`): with an error schedule an episode
draws no noise, so it is a deterministic function of (cell, seed, episode id, schedule), and "is there
an error within the bounds that breaks it?" is a search over schedules. Search methods (CMA-ES, tree
search) and subset simulation call :func:`evaluate`, a batch of candidates in one chunk rollout (one
row each, and the trajectory on request); subset simulation maps its standard normals to units with
:func:`mcverify.sim.schedule.units_from_normals`. :func:`run_folder` runs a campaign with a schedule per
episode into an ordinary run folder whose episodes ``mcverify replay`` re-simulates bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from mcverify.campaign import executors, runner
from mcverify.campaign.executors import Executor
from mcverify.campaign.spec import Campaign
from mcverify.cell import Cell
from mcverify.control.planner import Planner
from mcverify.episode.rollout import ChunkResult, run_episodes
from mcverify.sim.schedule import ErrorInput


def evaluate(
    cell: Cell,
    schedules: Sequence[ErrorInput],
    *,
    seed: int = 0,
    episode_ids: Sequence[int] | None = None,
    scenario: Mapping[str, float] | None = None,
    record: bool = False,
    planner: Planner | None = None,
) -> ChunkResult:
    """Run one episode of ``cell`` per schedule, all in one chunk; rows (and recordings) by candidate.

    episode_ids: the cell-local id of each candidate's episode (default 0, 1, ...; distinct), which with
    ``seed`` fixes its scenario draws; scenario: scenario values (keys of
    :func:`mcverify.episode.draws.sample_scenario`) that replace every candidate's own draws, so that all
    candidates meet the same scenario (None: each its own); record: also return every episode's trajectory
    (``recordings``); planner: default the cell's (built or loaded once per process). The result's
    ``realised`` holds the time schedule each episode applied (a gap-band schedule's too), by episode id.
    """
    ids = list(range(len(schedules))) if episode_ids is None else [int(e) for e in episode_ids]
    if len(ids) != len(schedules):
        raise ValueError(f"{len(schedules)} schedules for {len(ids)} episode ids: give one id per schedule")
    if len(set(ids)) != len(ids):
        raise ValueError("episode ids must be distinct (the same scenario for all: pass scenario=)")
    if not ids:
        return ChunkResult([])
    scenarios = None if scenario is None else {e: dict(scenario) for e in ids}
    return run_episodes(cell, ids, seed, planner or executors.solver_for(cell.params), record=record,
                        scenarios=scenarios, schedules=list(schedules))


def run_folder(campaign: Campaign, schedules: Mapping[int, ErrorInput], run_dir: Path, *,
               executor: Executor | None = None, progress: bool = False) -> Path:
    """Run ``campaign`` with an error schedule for each of its episodes (global episode id -> schedule)
    into the new run folder ``run_dir``; the schedules are kept in it, so ``mcverify replay RUN_DIR ID``
    and ``mcverify run --resume`` use them. Returns the report path."""
    return runner.run(campaign, Path(run_dir), executor=executor or executors.SerialExecutor(), progress=progress,
                      schedules=schedules)
