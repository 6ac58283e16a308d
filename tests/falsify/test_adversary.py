"""Episodes under error schedules: deterministic, batch-invariant, stored with the run and replayed bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pyarrow.parquet as pq
import pytest

from mcverify import cli
from mcverify.campaign import executors, runner
from mcverify.campaign.spec import campaign_from_dict
from mcverify.episode.rollout import run_episodes
from mcverify.episode.schedule_file import SCHEDULES, read_schedule, schedule_path
from mcverify.falsify import adversary
from mcverify.falsify.parametrisations import GapBands, random_uniform
from mcverify.schema import TIMING_COLUMNS
from mcverify.sim.schedule import ErrorSchedule
from mcverify.sim.tilt import NoiseTilt

RAW = {"campaign": {"name": "adversary-test", "seed": 3, "episodes": 2},
       "model": {"sim": {"control_period_s": 0.1, "substeps": 20, "max_time_s": 3.0},
                 "scenario": {"front_x_m": 30.0}}}
STEPS = 30


def _same_rows(a: dict, b: dict) -> list[str]:
    """Columns that differ (timing columns skipped; NaN equals NaN)."""
    def same(x, y):
        return x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))
    return [k for k in a if k not in TIMING_COLUMNS and not same(a[k], b.get(k))]


@pytest.fixture(scope="module")
def cell():
    return campaign_from_dict(RAW).cells[0]


@pytest.fixture(scope="module")
def schedules():
    return [random_uniform(STEPS, seed=1, front_share=1.0, opp_share=0.0),
            GapBands(edges_m=(2.0, 3.0, 30.0)).schedule(np.linspace(-1.0, 1.0, 15))]


@pytest.fixture(scope="module")
def batch(cell, schedules):
    return adversary.evaluate(cell, schedules, seed=3)


def test_a_batch_equals_each_episode_alone_and_the_realised_schedule_replays(cell, schedules, batch):
    alone = adversary.evaluate(cell, [schedules[0]], seed=3)
    assert _same_rows(batch.rows[0], alone.rows[0]) == []
    # the gap-band episode re-simulated from the time schedule it applied: the same episode, bit for bit
    again = adversary.evaluate(cell, [batch.realised[1]], seed=3, episode_ids=[1])
    assert _same_rows(batch.rows[1], again.rows[0]) == []
    assert np.abs(batch.realised[1].units).max() > 0  # the bands acted
    np.testing.assert_array_equal(batch.realised[0].units, schedules[0].units)


def test_the_schedule_is_the_whole_error(cell, batch):
    exact = adversary.evaluate(cell, [ErrorSchedule.exact(STEPS)], seed=3)
    drawn = adversary.evaluate(cell, [], seed=3)
    assert drawn.rows == []
    assert _same_rows(batch.rows[0], exact.rows[0])  # the errors change the episode
    with pytest.raises(ValueError, match="noise tilt"):
        run_episodes(cell, [0], 3, None, noise_tilt=NoiseTilt(gap_max_m=5.0), schedules=[ErrorSchedule.exact(3)])


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory, schedules):
    out = tmp_path_factory.mktemp("adversary") / "run"
    adversary.run_folder(campaign_from_dict(RAW), dict(enumerate(schedules)), out)
    return out


@pytest.mark.parametrize("episode_id", [0, 1])
def test_a_run_with_schedules_replays_bit_for_bit(run_dir, batch, episode_id, capsys):
    kept = read_schedule(schedule_path(run_dir / SCHEDULES, episode_id))
    assert type(kept).__name__ in ("ErrorSchedule", "GapBandSchedule")
    assert cli.main(["replay", str(run_dir), str(episode_id)]) == 0
    assert "reproduced exactly" in capsys.readouterr().out
    stored = [r for r in pq.read_table(run_dir / "episodes.parquet").to_pylist() if r["episode_id"] == episode_id][0]
    assert _same_rows(batch.rows[episode_id], stored) == []  # the run folder's episode is evaluate's


def test_a_bad_stored_schedule_is_one_line_exit_2(run_dir, capsys):
    path = schedule_path(run_dir / SCHEDULES, 0)
    good = path.read_bytes()
    try:
        np.savez(path, format=np.array(1), kind=np.array("time"), units=np.full((3, 5), 1.5),
                 front_share=np.array(1.0), opp_share=np.array(1.0))
        assert cli.main(["replay", str(run_dir), "0"]) == 2
        err = capsys.readouterr().err.strip()
        assert "outside [-1, 1]" in err and len(err.splitlines()) == 1
    finally:
        path.write_bytes(good)


class _Interrupt(Exception):
    pass


def test_an_interrupted_run_with_schedules_resumes_with_them(tmp_path, schedules, batch):
    def stop(_record):
        raise _Interrupt

    run = tmp_path / "run"
    with pytest.raises(_Interrupt):
        runner.run(campaign_from_dict(RAW), run, executor=executors.SerialExecutor(), chunk_size=1, progress=False,
                   on_chunk=stop, schedules=dict(enumerate(schedules)))
    runner.resume(run, executor=executors.SerialExecutor(), progress=False)  # the plain episode function
    rows = sorted(pq.read_table(run / "episodes.parquet").to_pylist(), key=lambda r: r["episode_id"])
    assert [_same_rows(batch.rows[e], rows[e]) for e in (0, 1)] == [[], []]
