"""The scheduler's order: dearest work first, dear chunks split on many workers, results unchanged."""

from __future__ import annotations

import functools

import synthetic_episodes as synth

from mcverify import store
from mcverify.campaign import executors
from mcverify.campaign.episode_cost import typical_seconds
from mcverify.campaign.executors import ChunkOutput, SerialExecutor
from mcverify.campaign.replay import compare_rows
from mcverify.campaign.scheduler import TASKS_PER_WORKER, plan_tasks
from mcverify.campaign.spec import campaign_from_dict, load_campaign


def collect(camp, chunk_size, executor=None) -> dict[str, ChunkOutput]:
    """Run every chunk of synthetic episodes; {chunk name: output}, each chunk once and whole."""
    chunks = store.plan_chunks([c.episodes for c in camp.cells], chunk_size)
    got: dict[str, ChunkOutput] = {}

    def on_done(chunk, output):
        assert chunk.name not in got and [r["cell_episode"] for r in output.rows] == list(chunk.episode_ids)
        got[chunk.name] = output

    with executor or SerialExecutor() as ex:
        executors.execute(camp, chunks, on_done, executor=ex, episode_fn=synth.episodes)
    assert set(got) == {c.name for c in chunks}
    return got


def by_episode(outputs: dict[str, ChunkOutput]) -> dict[int, dict]:
    return {r["episode_id"]: r for out in outputs.values() for r in out.rows}


def _every_episode_once(chunks, tasks) -> None:
    planned = sorted((c.cell_index, e) for c in chunks for e in c.episode_ids)
    assert sorted((c.cell_index, e) for c, ids in tasks for e in ids) == planned
    for chunk, ids in tasks:  # a task is consecutive episodes of its own chunk
        assert set(ids) <= set(chunk.episode_ids) and list(ids) == list(range(ids[0], ids[-1] + 1))


def test_one_worker_runs_whole_chunks_in_plan_order():
    chunks = store.plan_chunks([5, 5, 5], 2)
    assert plan_tasks(chunks, [1.0, 8.0, 2.0], workers=1) == [(c, c.episode_ids) for c in chunks]


def test_two_workers_start_the_dearest_tasks_first_in_plan_order_within_a_cell():
    chunks = store.plan_chunks([5, 5, 5], 2)  # cells 0, 1, 2: chunks of 2, 2, 1 episodes
    tasks = plan_tasks(chunks, [1.0, 8.0, 2.0], workers=2)  # share 55 / 6: cell 1 in single episodes
    _every_episode_once(chunks, tasks)
    assert [(c.cell_index, ids) for c, ids in tasks] == [
        (1, (0,)), (1, (1,)), (1, (2,)), (1, (3,)), (1, (4,)), (2, (0, 1)), (2, (2, 3)), (0, (0, 1)), (0, (2, 3)),
        (2, (4,)), (0, (4,)),
    ]


def test_many_workers_split_the_dear_chunks_and_leave_the_cheap_ones_whole():
    chunks = store.plan_chunks([8, 8, 8, 8], 8)
    costs = [2.0, 2.0, 16.0, 2.5]  # Table IV's spread: MPC-DC, MPC-DC, VL-CBF B, VL-CBF A
    workers = 3
    tasks = plan_tasks(chunks, costs, workers)
    _every_episode_once(chunks, tasks)
    share = sum(c * 8 for c in costs) / (workers * TASKS_PER_WORKER)  # 20 s
    task_costs = [costs[c.cell_index] * len(ids) for c, ids in tasks]
    assert max(task_costs) <= share
    assert task_costs == sorted(task_costs, reverse=True)  # dearest first
    assert [ids for c, ids in tasks if c.cell_index == 2] == [(e,) for e in range(8)]
    assert [ids for c, ids in tasks if c.cell_index != 2] == [tuple(range(8))] * 3  # 16-20 s: whole


def test_a_split_is_near_even():
    chunks = store.plan_chunks([8, 8], 8)
    tasks = plan_tasks(chunks, [3.0, 1.0], workers=2)  # share 32 / 6: at most 1 episode of 3 s ... 5 of 1 s
    assert [len(ids) for c, ids in tasks if c.cell_index == 0] == [1] * 8
    assert [ids for c, ids in tasks if c.cell_index == 1] == [(0, 1, 2, 3), (4, 5, 6, 7)]


def test_a_chunk_is_never_split_below_one_episode():
    chunks = store.plan_chunks([3, 1], 3)
    tasks = plan_tasks(chunks, [100.0, 1.0], workers=16)
    _every_episode_once(chunks, tasks)
    assert [ids for _, ids in tasks] == [(0,), (1,), (2,), (0,)]


def test_the_typical_costs_put_table_iv_vlcbf_before_mpcdc():
    camp = load_campaign("campaigns/table4.toml", episodes=1)
    cost = {cell.name: typical_seconds(cell) for cell in camp.cells}
    assert cost["scenario=B,method=VL-CBF eps=0.3"] > 3 * cost["scenario=B,method=MPC-DC"]


def _vlcbf_and_mpcdc(episodes: int):
    return campaign_from_dict({
        "campaign": {"name": "mix", "seed": 5, "episodes": episodes},
        "model": {"opposing": {"kind": "human"}},
        "grid": {"mpc.controller": ["mpcdc", "vlcbf"]},
    })


def test_split_and_reordered_tasks_give_the_same_rows_and_whole_chunks():
    camp = _vlcbf_and_mpcdc(episodes=6)
    chunks = store.plan_chunks([c.episodes for c in camp.cells], 6)
    planned = plan_tasks(chunks, [typical_seconds(c) for c in camp.cells], workers=2)
    assert [(c.cell_index, len(ids)) for c, ids in planned] == [(1, 1)] * 6 + [(0, 3)] * 2
    plain = by_episode(collect(camp, chunk_size=6))  # serial: whole chunks in plan order
    split = collect(camp, chunk_size=6, executor=executors.LocalExecutor(2))  # as planned above
    assert by_episode(split).keys() == plain.keys()
    for k, row in by_episode(split).items():
        assert compare_rows(plain[k], row) == {}  # bit for bit
    assert all(out.attempts == 1 for out in split.values())


def test_a_split_chunk_of_a_decided_cell_is_dropped_whole(tmp_path):
    camp = _vlcbf_and_mpcdc(episodes=6)
    chunks = store.plan_chunks([c.episodes for c in camp.cells], 6)
    asked, ran = [], []
    fn = functools.partial(synth.faulty, log_dir=str(tmp_path))

    class TwoSlots(SerialExecutor):
        capacity = 2  # plan as for two workers, run in this process

    def skip(chunk):
        asked.append(chunk.name)
        return chunk.cell_index == 1  # the VL-CBF cell is already decided

    with TwoSlots() as ex:
        executors.execute(camp, chunks, lambda c, o: ran.append(c.name), executor=ex, episode_fn=fn, skip=skip)
    assert sorted(asked) == sorted(c.name for c in chunks)  # once per chunk, not per task
    assert ran == [chunks[0].name]
    ran_ids = {int(x) for p in tmp_path.iterdir() for x in p.name.split("-")[2:-1]}  # global ids
    assert ran_ids == set(range(6))  # nothing of cell 1 (ids 6-11) ran
