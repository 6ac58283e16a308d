"""Executors and the scheduler: every chunk once, retries, isolation of failing episodes, dead
workers, non-finite results, solver failures inside real episodes, Ray start-up errors.

Most tests inject the cheap synthetic episode function of ``synthetic_episodes`` through the
executors' interface; the last group runs the real closed loop with failing solvers.
"""

from __future__ import annotations

import copy
import functools
import math
import socket
import sys
from pathlib import Path

import numpy as np
import pytest
import synthetic_episodes as synth

from mcverify import schema, store
from mcverify.campaign import executors
from mcverify.campaign.executors import ChunkOutput, SerialExecutor
from mcverify.campaign.spec import campaign_from_dict, load_campaign
from mcverify.solver.mpc import MpcSolution
from mcverify.solver.status import SolveStatus

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"


def campaign(episodes=3, cells=2, seed=5):
    speeds = [25, 36, 28, 32][:cells]
    return campaign_from_dict({
        "campaign": {"name": "synthetic", "seed": seed, "episodes": episodes},
        "grid": {"scenario.front_speed_kmh": speeds},
    })


def collect(camp, chunk_size, executor=None, episode_fn=synth.episodes, **kw):
    """Run every chunk; returns {chunk name: ChunkOutput} and checks each chunk arrives once."""
    chunks = store.plan_chunks([c.episodes for c in camp.cells], chunk_size)
    got: dict[str, ChunkOutput] = {}

    def on_done(chunk, output):
        assert chunk.name not in got, f"{chunk.name} delivered twice"
        assert [r["cell_episode"] for r in output.rows] == list(chunk.episode_ids)
        got[chunk.name] = output

    executor = executor or SerialExecutor()
    with executor:
        executors.execute(camp, chunks, on_done, executor=executor, episode_fn=episode_fn, **kw)
    assert set(got) == {c.name for c in chunks}
    return got


def by_episode(outputs) -> dict[int, dict]:
    return {r["episode_id"]: r for out in outputs.values() for r in out.rows}


def test_serial_and_local_pool_with_other_chunk_sizes_give_the_same_rows():
    camp = campaign(episodes=5)
    serial = by_episode(collect(camp, chunk_size=5))
    pooled = by_episode(collect(camp, chunk_size=2, executor=executors.LocalExecutor(2)))
    assert sorted(serial) == list(range(10))
    assert pooled.keys() == serial.keys()
    for k in serial:
        assert pooled[k] == pytest.approx(serial[k], nan_ok=True)


def test_an_exception_is_retried_then_isolated_to_its_own_episode(tmp_path):
    camp = campaign(episodes=5, cells=1)
    fn = functools.partial(synth.faulty, raise_on=(2,), log_dir=str(tmp_path))
    out = collect(camp, chunk_size=5, episode_fn=fn)["cell000_ep000000-000004"]
    rows = {r["episode_id"]: r for r in out.rows}
    assert rows[2]["outcome"] == "error"
    assert rows[2][schema.ERROR_COLUMN] == "RuntimeError: injected failure in episode 2"
    assert "safe" not in rows[2] and "min_h_front" not in rows[2]  # null in the table: never safe or unsafe
    clean = by_episode(collect(camp, chunk_size=5))
    for k in (0, 1, 3, 4):  # its chunk-mates are simulated as if nothing had happened
        assert rows[k] == pytest.approx(clean[k], nan_ok=True)
    calls = sorted(p.name.split("-", 2)[2].rsplit("-", 1)[0] for p in tmp_path.iterdir())
    # two runs of the whole chunk, then each episode alone (the failing one twice)
    assert calls == sorted(["0-1-2-3-4", "0-1-2-3-4", "0", "1", "2", "2", "3", "4"])
    assert out.attempts == 8 and out.errors == 1


def test_a_transient_failure_costs_a_retry_not_an_episode(tmp_path):
    camp = campaign(episodes=3, cells=1)
    fn = functools.partial(synth.faulty, once_on=(1,), once_dir=str(tmp_path))
    out = collect(camp, chunk_size=3, episode_fn=fn)["cell000_ep000000-000002"]
    assert out.errors == 0 and out.attempts == 2
    assert [r["outcome"] != "error" for r in out.rows] == [True, True, True]


def test_a_dead_worker_is_replaced_and_only_its_episode_is_lost():
    camp = campaign(episodes=3, cells=2)
    fn = functools.partial(synth.faulty, kill_on=(4,))
    outputs = collect(camp, chunk_size=1, executor=executors.LocalExecutor(2), episode_fn=fn)
    rows = by_episode(outputs)
    assert sorted(rows) == list(range(6))
    assert rows[4]["outcome"] == "error"
    assert rows[4][schema.ERROR_COLUMN] == "worker process died (SIGKILL)"
    assert outputs["cell001_ep000001-000001"].attempts == 2
    assert all(rows[k]["outcome"] != "error" for k in (0, 1, 2, 3, 5))


def test_a_non_finite_metric_becomes_an_error_row_without_retry(tmp_path):
    camp = campaign(episodes=3, cells=1)
    fn = functools.partial(synth.faulty, nan_on=(1,), log_dir=str(tmp_path))
    out = collect(camp, chunk_size=3, episode_fn=fn)["cell000_ep000000-000002"]
    assert [r["outcome"] == "error" for r in out.rows] == [False, True, False]
    assert out.rows[1][schema.ERROR_COLUMN].startswith("non-finite result: min_h_front = nan")
    assert len(list(tmp_path.iterdir())) == 1, "a deterministic NaN is not worth a retry"


def test_only_requested_recordings_come_back():
    camp = campaign(episodes=3, cells=2)
    outputs = collect(camp, chunk_size=2, record=[(0, 0), (1, 0)])
    assert outputs["cell000_ep000000-000001"].recordings.keys() == {0}
    assert outputs["cell001_ep000000-000001"].recordings.keys() == {0}
    assert outputs["cell000_ep000002-000002"].recordings == {}


def test_a_worker_with_other_code_stops_the_run():
    class OtherCode(SerialExecutor):
        def wait(self):
            handle, outcome = super().wait()
            outcome.code = {**outcome.code, "jax": "0.0.0"}
            outcome.worker = "node7:123"
            return handle, outcome

    with pytest.raises(executors.ExecutorError, match=r"worker node7:123 runs other code .*jax"):
        collect(campaign(), chunk_size=3, executor=OtherCode())


def test_one_line_messages():
    assert executors.one_line(RuntimeError("first\nsecond")) == "RuntimeError: first"
    assert executors.one_line(KeyError()) == "KeyError"
    assert len(executors.one_line(ValueError("x" * 1000))) == executors.MAX_MESSAGE


# ----------------------------------------------------------------------------------------- Ray


def test_ray_missing_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(executors.ExecutorError, match=r"needs Ray: pip install 'mcverify\[ray\]'"):
        with executors.RayExecutor():
            pass


def test_ray_unreachable_address_fails_fast():
    with socket.socket() as s:  # a port that nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(executors.ExecutorError, match=rf"cannot reach the Ray cluster at 127.0.0.1:{port}"):
        executors.probe_address(f"127.0.0.1:{port}", timeout_s=2)
    with pytest.raises(executors.ExecutorError, match="HOST:PORT"):
        executors.probe_address("nonsense")
    with pytest.raises(executors.ExecutorError, match="--executor ray"):
        executors.make_executor("local", address="10.0.0.1:6379")


# ------------------------------------------------------------ real closed loop, failing solvers


class FailingSolver:
    """Neither Q1 nor Q2 ever solves (IPOPT reports infeasibility every time)."""

    def __init__(self, n=50):
        self.n = n

    def solve(self, ego, front, direction, level, warm=None, **kw):
        n = self.n
        return MpcSolution(
            success=False, status=SolveStatus.ipopt("Infeasible_Problem_Detected"), iterations=3, solve_time_s=0.0,
            total_time_s=math.nan, x_plan=np.full((n + 1, 4), np.nan), u_plan=np.full((n, 2), np.nan),
            dt_plan=np.full(n, np.nan), warm=None,
        )


class RaisingSolver(FailingSolver):
    """Raises on its ``after``-th call (a bug escaping the solver's own error handling)."""

    def __init__(self, after):
        super().__init__()
        self.calls, self.after = 0, after

    def solve(self, *args, **kw):
        self.calls += 1
        if self.calls >= self.after:
            raise RuntimeError("solver exploded")
        return super().solve(*args, **kw)


class NanSolver(FailingSolver):
    """Claims success with a NaN plan: the plant state becomes NaN."""

    def solve(self, *args, **kw):
        sol = super().solve(*args, **kw)
        return MpcSolution(**{**sol.__dict__, "success": True, "status": SolveStatus.ipopt("Solve_Succeeded")})


def with_solver(solver_factory):
    """The real closed loop, with the planner's compiled solver replaced by ``solver_factory()``."""
    from mcverify.episode.rollout import run_episodes

    def fn(cell, episode_ids, seed, crn, record):
        planner = copy.copy(executors.solver_for(cell.params))
        planner.plain = solver_factory()
        return run_episodes(cell, list(episode_ids), seed, planner, common_random_numbers=crn)

    return fn


@pytest.fixture(scope="module")
def tiny():
    camp = load_campaign(FIXTURE, episodes=2)
    return campaign_from_dict(camp.raw | {"grid": {"scenario.front_speed_kmh": [25]}}, episodes=2)


def test_unsolvable_steps_apply_the_fallback_and_are_counted(tiny):
    rows = by_episode(collect(tiny, chunk_size=2, episode_fn=with_solver(FailingSolver)))
    for r in rows.values():
        assert r["outcome"] == "timeout"  # a recorded status, the campaign goes on
        assert r["steps"] == 10 and r["fallback_steps"] == 10 and r["both_infeasible_steps"] == 10
        assert '"Infeasible_Problem_Detected": 20' in r["solver_statuses"]


def test_a_solver_exception_in_a_real_episode_becomes_error_rows(tiny):
    rows = by_episode(collect(tiny, chunk_size=2, episode_fn=with_solver(lambda: RaisingSolver(after=3))))
    assert [r["outcome"] for r in rows.values()] == ["error", "error"]
    assert all(r[schema.ERROR_COLUMN] == "RuntimeError: solver exploded" for r in rows.values())


def test_a_nan_plant_in_a_real_episode_becomes_an_error_row(tiny):
    rows = by_episode(collect(tiny, chunk_size=2, episode_fn=with_solver(NanSolver)))
    for r in rows.values():
        assert r["outcome"] == "error"
        assert r[schema.ERROR_COLUMN].startswith("non-finite result: min_h_front = nan")


def test_kept_alive_lends_one_executor_to_several_runs():
    made = []

    def make():
        made.append(executors.SerialExecutor())
        return made[-1]

    shared = executors.KeptAlive(make)
    for _ in range(2):
        with shared as ex:
            assert ex is shared and shared.inner is made[0]
    assert len(made) == 1 and shared.describe() == made[0].describe()
    assert not shared.warm
    cell = campaign_from_dict({"campaign": {"name": "k", "seed": 1, "episodes": 1}}).cells[0]
    with shared:
        shared.submit(executors.Work(cell, (0,), 1, False, (), synth.episodes))
        assert shared.wait()[1].error is None
    assert shared.warm  # the next run has nothing to start up
    shared.release()
    assert shared._inner is None and not shared.warm
    with pytest.raises(RuntimeError), shared:  # a failed run releases the workers
        shared.inner  # noqa: B018 - starts the inner executor
        raise RuntimeError("boom")
    assert shared._inner is None and len(made) == 2
