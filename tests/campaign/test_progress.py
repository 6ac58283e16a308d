"""Progress per episode inside a chunk (mcverify.campaign.progress and the executors' on_episode):
the bar moves as each episode stops, with the cumulative unsafe count; the chunk's rows stay the
truth; the Ray executor reports whole chunks only."""

from __future__ import annotations

import pytest
import synthetic_episodes as synth

from mcverify import store
from mcverify.campaign import executors
from mcverify.campaign.progress import ProgressTally
from mcverify.campaign.spec import campaign_from_dict
from mcverify.campaign.work import EpisodeDone


class Bar:
    """Stands in for tqdm: the position and the last postfix."""

    def __init__(self) -> None:
        self.n, self.postfix = 0, ""

    def update(self, n: int) -> None:
        self.n += n

    def set_postfix_str(self, text: str) -> None:
        self.postfix = text


def camp(episodes=5, cells=2):
    return campaign_from_dict({"campaign": {"name": "p", "seed": 7, "episodes": episodes},
                               "grid": {"scenario.front_speed_kmh": [25, 36][:cells]}})


def events(executor, chunk_size=4, episode_fn=synth.episodes):
    """Run a campaign; the sequence of ("episode", chunk, id, unsafe) and ("chunk", chunk, rows)."""
    c = camp()
    chunks = store.plan_chunks([x.episodes for x in c.cells], chunk_size)
    seen: list[tuple] = []
    with executor:
        executors.execute(c, chunks, lambda ch, out: seen.append(("chunk", ch.name, out.rows)),
                          executor=executor, episode_fn=episode_fn,
                          on_episode=lambda ch, msg: seen.append(("episode", ch.name, msg.episode, msg.unsafe)))
    return seen


@pytest.mark.parametrize("executor", [executors.SerialExecutor, lambda: executors.LocalExecutor(1)],
                         ids=["serial", "local"])
def test_every_episode_is_reported_inside_its_chunk_before_the_rows(executor):
    seen = events(executor())
    chunks = [e for e in seen if e[0] == "chunk"]
    assert len(chunks) == 4  # 2 cells x 5 episodes in chunks of 4: 4 + 1 per cell
    for i, (_, name, rows) in enumerate(chunks):
        at = seen.index(chunks[i])
        told = [e for e in seen[:at] if e[0] == "episode" and e[1] == name]
        assert [e[2] for e in told] == [r["cell_episode"] for r in rows]  # each once, before the rows
        assert [e[3] for e in told] == [not r["safe"] for r in rows]  # unsafe as the row says


def test_the_tally_moves_per_episode_and_the_rows_correct_it():
    bar = Bar()
    tally = ProgressTally(bar, unsafe=2)  # a resume: two unsafe episodes already on disk
    chunk = store.plan_chunks([4], 4)[0]
    tally.episode(chunk, EpisodeDone(0, True))
    tally.episode(chunk, EpisodeDone(1, False))
    assert (bar.n, tally.unsafe, bar.postfix) == (2, 3, "unsafe 3")
    tally.episode(chunk, EpisodeDone(1, False))  # a retried chunk reports an episode again
    assert bar.n == 2
    rows = [{"cell_episode": e, "safe": e != 3} for e in range(4)]  # the rows: only episode 3 unsafe
    tally.chunk(chunk, rows, errors=0)
    assert (bar.n, tally.unsafe, tally.pending) == (4, 3, {})  # 2 moved one by one + 2 with the rows
    other = store.plan_chunks([4, 2], 4)[1]
    tally.chunk(other, [{"cell_episode": 0, "safe": None}, {"cell_episode": 1, "safe": False}], errors=1)
    assert (bar.n, tally.unsafe, bar.postfix) == (6, 4, "unsafe 4, error episodes 1")


def silent(cell, episode_ids, seed, common_random_numbers, record) -> synth.Result:
    """Synthetic episodes that never call episode_done (as an episode function of one's own may)."""
    return synth.Result([synth.row(cell, seed, int(e), common_random_numbers) for e in episode_ids], {})


def test_an_episode_function_that_reports_nothing_moves_the_bar_per_chunk(tmp_path, monkeypatch):
    from mcverify.campaign import runner

    class Recorder(Bar):
        def __init__(self, *a, **kw) -> None:
            super().__init__()
            self.steps: list[int] = []

        def update(self, n: int) -> None:
            self.steps.append(n)

        def __enter__(self):
            return self

        def __exit__(self, *exc) -> None:
            pass

    bars: list[Recorder] = []
    monkeypatch.setattr(runner, "tqdm", lambda *a, **kw: bars.append(Recorder()) or bars[-1])
    for fn in (synth.episodes, silent):
        runner.run(camp(), tmp_path / fn.__name__, executor=executors.SerialExecutor(), chunk_size=4,
                   progress=True, episode_fn=fn)
    per_episode, per_chunk = bars
    assert sum(per_episode.steps) == sum(per_chunk.steps) == 10
    assert per_episode.steps == [1, 1, 1, 1, 0, 1, 0] * 2  # one per episode; its chunk's rows add nothing
    assert per_chunk.steps == [4, 1, 4, 1]
