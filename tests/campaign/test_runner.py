"""Run and resume, end to end.

Acceptance points of issue 6:

* identical ``episodes.parquet`` content from 1 worker, from 2 workers with an odd chunk size, and
  from the Ray executor (real closed-loop episodes of ``fixtures/tiny.toml``);
* ``kill -9`` of a running campaign, then ``mcverify run --resume``, gives exactly the episodes of
  an uninterrupted run (real episodes, the real command line);
* memory stays flat over a 10,000-episode campaign (the real executor and store, with a cheap
  synthetic episode function injected through the executor's interface: 10,000 real episodes
  would take hours).
"""

from __future__ import annotations

import functools
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import synthetic_episodes as synth

from mcverify import files, provenance, schema, store
from mcverify.campaign import executors, run_folders, runner
from mcverify.campaign.spec import campaign_from_dict, load_campaign
from mcverify.errors import CampaignError, RunError
from mcverify.levels import Level
from mcverify.schema import TIMING_COLUMNS

TESTS = Path(__file__).resolve().parents[1]
REPO = TESTS.parent
FIXTURE = TESTS / "fixtures" / "tiny.toml"


def episodes_of(run_dir: Path) -> dict[str, list]:
    """episodes.parquet as columns, without the machine-dependent timing columns."""
    table = pq.read_table(Path(run_dir) / store.EPISODES)
    return {name: table.column(name).to_pylist() for name in table.column_names if name not in TIMING_COLUMNS}


def assert_same_episodes(a: Path, b: Path) -> None:
    """Bit-for-bit equal content (NaN equals NaN), column by column."""
    ea, eb = episodes_of(a), episodes_of(b)
    assert list(ea) == list(eb), "same columns in the same order"
    for name in ea:
        assert len(ea[name]) == len(eb[name]), name
        for i, (x, y) in enumerate(zip(ea[name], eb[name], strict=True)):
            if isinstance(x, float) and isinstance(y, float):
                same = (math.isnan(x) and math.isnan(y)) or np.float64(x).tobytes() == np.float64(y).tobytes()
            else:
                same = x == y
            assert same, f"{name}[{i}]: {x!r} != {y!r}"


def cli(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mcverify.cli", *args], cwd=REPO, capture_output=True, text=True, timeout=600, **kw
    )


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The uninterrupted run: in this process, one episode at a time (chunk size 1)."""
    run_dir = tmp_path_factory.mktemp("reference") / "run"
    camp = load_campaign(FIXTURE)
    runner.run(camp, run_dir, executor=executors.SerialExecutor(), chunk_size=1, progress=False)
    return run_dir


def test_reference_run_is_complete_and_recorded(reference: Path):
    eps = episodes_of(reference)
    assert eps["episode_id"] == [0, 1, 2, 3, 4, 5]
    assert eps["cell_episode"] == [0, 1, 2, 0, 1, 2]
    assert eps["outcome"] == ["timeout"] * 6  # the fixture's 1 s episodes
    assert eps[schema.ERROR_COLUMN] == [None] * 6
    assert len(set(eps["min_h_front"])) == 6, "every episode has its own noise draws"
    manifest = json.loads((reference / store.MANIFEST).read_text())
    assert manifest["finished_utc"] and manifest["chunks"]["planned"] == 6 and manifest["chunk_size"] == 1
    assert manifest["sessions"][0]["executor"] == "serial"
    assert manifest["code"] == provenance.code_version()
    assert len(store.read_ledger(reference)) == 6
    assert sorted(p.name for p in (reference / store.TRAJECTORY_DIR).iterdir()) == [
        "episode-000000-plans.parquet", "episode-000000.parquet",
        "episode-000003-plans.parquet", "episode-000003.parquet"]


def test_two_workers_and_an_odd_chunk_size_give_the_same_episodes(reference: Path, tmp_path: Path):
    run_dir = tmp_path / "run"
    runner.run(load_campaign(FIXTURE), run_dir, executor=executors.LocalExecutor(2), chunk_size=3, progress=False)
    assert_same_episodes(reference, run_dir)


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # Ray starts its daemons with fork+exec
@pytest.mark.slow  # starts a local Ray cluster (20-60 s on 2 cores); its bad-input paths stay in the default suite
def test_ray_executor_gives_the_same_episodes(reference: Path, tmp_path: Path):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        run_dir = tmp_path / "run"
        executor = executors.RayExecutor()
        runner.run(load_campaign(FIXTURE), run_dir, executor=executor, chunk_size=1, progress=False)
        assert executor.capacity == 2  # the local cluster's CPUs
    finally:
        ray.shutdown()
    assert_same_episodes(reference, run_dir)
    assert json.loads((run_dir / store.MANIFEST).read_text())["sessions"][0]["executor"] == "ray"


def test_sigkill_then_resume_gives_exactly_the_uninterrupted_episodes(reference: Path, tmp_path: Path):
    run_dir = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mcverify.cli", "run", str(FIXTURE), "--run-dir", str(run_dir),
         "--workers", "2", "--chunk-size", "1", "--no-progress"],
        cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True,
    )
    chunk_dir = run_dir / store.CHUNK_DIR
    try:
        deadline = time.monotonic() + 300
        while proc.poll() is None and time.monotonic() < deadline:
            if chunk_dir.is_dir() and any(chunk_dir.glob("*.parquet")):
                break
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the run and its pool workers, as `kill -9` on the group
        proc.wait()
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read().decode()[-2000:]
    finished = sorted(chunk_dir.glob("*.parquet"))
    assert 1 <= len(finished) < 6, "killed in the middle of the campaign"
    assert not (run_dir / store.EPISODES).exists()
    before = {rec.chunk: rec for rec in store.read_ledger(run_dir).values()}
    stamps = {p.name: p.stat().st_mtime_ns for p in finished}

    resumed = cli("run", "--resume", str(run_dir), "--workers", "1", "--no-progress")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert f"resuming {run_dir}: {len(before)} of 6 chunks already done" in resumed.stderr
    assert_same_episodes(reference, run_dir)
    ledger = store.read_ledger(run_dir)
    assert len(ledger) == 6
    for name, rec in before.items():  # recorded chunks were kept, not run again
        assert ledger[name] == rec
        assert (chunk_dir / f"{name}.parquet").stat().st_mtime_ns == stamps[f"{name}.parquet"]
    lines = (run_dir / store.LEDGER).read_text().splitlines()
    assert len([ln for ln in lines if ln.strip()]) == 6, "no chunk was finished twice"
    sessions = json.loads((run_dir / store.MANIFEST).read_text())["sessions"]
    assert [s["resumed"] for s in sessions] == [False, True]


# ------------------------------------------------------------------ resume with synthetic episodes


def synthetic_campaign(episodes=4, **extra):
    raw = {"campaign": {"name": "synthetic", "seed": 3, "episodes": episodes},
           "grid": {"scenario.front_speed_kmh": [25, 36]}, **extra}
    return campaign_from_dict(raw)


class Interrupt(Exception):
    pass


def interrupted_run(camp, run_dir, after_chunks, chunk_size=2, episode_fn=synth.episodes):
    """Start a run and stop it (as a crash would) once ``after_chunks`` chunks are on disk."""
    seen = []

    def stop(rec):
        seen.append(rec.chunk)
        if len(seen) >= after_chunks:
            raise Interrupt

    with pytest.raises(Interrupt):
        runner.run(camp, run_dir, executor=executors.SerialExecutor(), chunk_size=chunk_size,
                   progress=False, episode_fn=episode_fn, on_chunk=stop)
    return seen


def resume(run_dir, **kw):
    ran = []
    kw.setdefault("episode_fn", synth.episodes)
    runner.resume(run_dir, executor=executors.SerialExecutor(), progress=False, on_chunk=lambda r: ran.append(r.chunk),
                  **kw)
    return ran


def complete_run(camp, run_dir, chunk_size=2):
    runner.run(camp, run_dir, executor=executors.SerialExecutor(), chunk_size=chunk_size, progress=False,
               episode_fn=synth.episodes)


def test_truncated_and_wrong_chunk_files_are_redone(tmp_path: Path):
    camp = synthetic_campaign()
    complete_run(camp, tmp_path / "clean")
    run_dir = tmp_path / "run"
    done = interrupted_run(camp, run_dir, after_chunks=3)
    assert done == ["cell000_ep000000-000001", "cell000_ep000002-000003", "cell001_ep000000-000001"]
    truncated = store.chunk_path(run_dir, store.Chunk(0, (0, 1)))
    truncated.write_bytes(truncated.read_bytes()[:100])
    wrong = store.chunk_path(run_dir, store.Chunk(0, (2, 3)))  # holds another chunk's episodes
    wrong.write_bytes(store.chunk_path(run_dir, store.Chunk(1, (0, 1))).read_bytes())
    ran = resume(run_dir)
    assert sorted(ran) == ["cell000_ep000000-000001", "cell000_ep000002-000003", "cell001_ep000002-000003"]
    assert_same_episodes(tmp_path / "clean", run_dir)


def test_a_chunk_file_without_its_ledger_line_is_redone(tmp_path: Path):
    camp = synthetic_campaign()
    run_dir = tmp_path / "run"
    interrupted_run(camp, run_dir, after_chunks=2)
    ledger = run_dir / store.LEDGER
    first, second = ledger.read_text().splitlines()
    ledger.write_text(first + "\n" + second[:30])  # killed while appending the second line
    ran = resume(run_dir)
    assert sorted(ran) == ["cell000_ep000002-000003", "cell001_ep000000-000001", "cell001_ep000002-000003"]
    complete_run(camp, tmp_path / "clean")
    assert_same_episodes(tmp_path / "clean", run_dir)


def test_error_rows_are_stored_and_the_campaign_finishes(tmp_path: Path, monkeypatch):
    # The report is the stats module's part (tested below); here: execution and storage.
    monkeypatch.setattr(runner.run_report, "write", lambda run_dir: Path(run_dir) / "report.md")
    camp = synthetic_campaign()
    fn = functools.partial(synth.faulty, raise_on=(5,))
    run_dir = tmp_path / "run"
    runner.run(camp, run_dir, executor=executors.SerialExecutor(), chunk_size=2, progress=False, episode_fn=fn)
    eps = episodes_of(run_dir)
    assert eps["episode_id"] == list(range(8))
    assert eps["outcome"][5] == "error" and eps[schema.ERROR_COLUMN][5] == "RuntimeError: injected failure in episode 5"
    assert eps["safe"][5] is None and eps["min_h_front"][5] is None  # neither safe nor unsafe
    assert eps["outcome"][4] != "error" and eps[schema.ERROR_COLUMN][4] is None
    assert [rec.errors for rec in store.read_ledger(run_dir).values()] == [0, 0, 1, 0]
    assert json.loads((run_dir / store.MANIFEST).read_text())["finished_utc"]


def test_report_of_a_run_with_error_rows(tmp_path: Path):
    fn = functools.partial(synth.faulty, raise_on=(5,))
    runner.run(synthetic_campaign(), tmp_path / "run", executor=executors.SerialExecutor(), chunk_size=2,
               progress=False, episode_fn=fn)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert sum(c["rates"]["error"]["k"] for c in summary["cells"]) == 1
    assert sum(c["episodes"] - c["valid"] for c in summary["cells"]) == 1  # rates are over valid rows
    assert "error" in (tmp_path / "run" / "report.md").read_text()


def test_resume_of_a_bundle_campaign_keeps_each_cells_episode_count(tmp_path: Path):
    axes = {"method": {"A": {"noise.scale": 1.0, "episodes": 3}, "B": {"noise.scale": 2.0}}}
    camp = campaign_from_dict({"campaign": {"name": "b", "seed": 1, "episodes": 5}, "axes": axes})
    assert [c.episodes for c in camp.cells] == [3, 5]
    run_dir = tmp_path / "run"
    interrupted_run(camp, run_dir, after_chunks=1)
    resume(run_dir)
    assert episodes_of(run_dir)["episode_id"] == list(range(8))
    forced = campaign_from_dict({"campaign": {"name": "b", "seed": 1, "episodes": 5}, "axes": axes}, episodes=2)
    interrupted_run(forced, tmp_path / "forced", after_chunks=1)
    resume(tmp_path / "forced")
    assert episodes_of(tmp_path / "forced")["episode_id"] == list(range(4))


def test_resume_refusals_are_one_line(tmp_path: Path, monkeypatch):
    camp = synthetic_campaign()
    done = tmp_path / "done"
    complete_run(camp, done)
    with pytest.raises(RunError, match="is already finished .*nothing to resume"):
        resume(done)
    with pytest.raises(RunError, match="already holds a run"):
        complete_run(camp, done)
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    with pytest.raises(RunError, match="not an empty folder"):
        complete_run(camp, tmp_path / "busy")

    run_dir = tmp_path / "run"
    interrupted_run(camp, run_dir, after_chunks=1)
    with pytest.raises(RunError, match="chunk size 3: it was planned with 2"):
        resume(run_dir, chunk_size=3)
    other = synthetic_campaign(episodes=5)
    with pytest.raises(RunError, match=r"the campaign differs from the run's \(episodes_per_cell: 4 -> 5\)"):
        resume(run_dir, campaign=other)
    with store.run_lock(run_dir):
        with pytest.raises(RunError, match="being run by another mcverify process"):
            resume(run_dir)
    code = provenance.code_version()
    monkeypatch.setattr(provenance, "code_version", lambda: {**code, "source_sha256": "f" * 64})
    with pytest.raises(RunError, match=r"started with other code \(mcverify simulation source"):
        resume(run_dir)
    monkeypatch.undo()
    manifest = json.loads((run_dir / store.MANIFEST).read_text())
    manifest["cells"][1]["params"]["sim"]["max_time_s"] = 99.0
    files.write_json_atomic(run_dir / store.MANIFEST, manifest)
    expected = r"expands differently .*cells\[1\]\.params\.sim\.max_time_s: 99.0 -> 25.0"
    with pytest.raises(RunError, match=expected):
        resume(run_dir)
    manifest["format"] = 1
    files.write_json_atomic(run_dir / store.MANIFEST, manifest)
    with pytest.raises(RunError, match="manifest has format 1"):
        resume(run_dir)
    for message in ("run folder not found", "not an mcverify run folder"):
        with pytest.raises(RunError, match=message):
            resume(tmp_path / "nope" if "found" in message else tmp_path / "busy")


# -------------------------------------------------------------------------------------- memory

MEMORY_SCRIPT = """
import json, sys
sys.path.insert(0, {tests!r})
import synthetic_episodes as synth
from mcverify.campaign import executors
from mcverify.campaign import runner
from mcverify.campaign.spec import campaign_from_dict

def rss_kb(pid="self", field="VmRSS"):
    for line in open(f"/proc/{{pid}}/status"):
        if line.startswith(field + ":"):
            return int(line.split()[1])

camp = campaign_from_dict({{"campaign": {{"name": "memory", "seed": 1, "episodes": {per_cell}}},
                           "grid": {{"scenario.front_speed_kmh": [25, 36]}}}})
executor = executors.LocalExecutor(2)
# the samples' storage is allocated up front (a flat C array: no Python object per value): a list of
# 1,250 tuples (about 0.2 MB) would count as the driver's growth, which the test bounds by a third of
# what the 10,000 rows take (about 0.4 MB)
import array
flat, taken = array.array("q", bytes(8 * 3 * (2 * {per_cell} // 8 + 1))), 0
def on_chunk(rec):
    global taken
    flat[3 * taken:3 * taken + 3] = array.array("q", (rec.rows, rss_kb(),
                                                      sum(rss_kb(w.proc.pid) for w in executor._workers)))
    taken += 1
runner.run(camp, {run_dir!r}, executor=executor, chunk_size=8, progress=False,
           episode_fn=synth.episodes, on_chunk=on_chunk)
samples = [flat[3 * i:3 * i + 3].tolist() for i in range(taken)]
# VmHWM, not getrusage's ru_maxrss: that one keeps the forking parent's (pytest's) size across exec.
peak_kb = rss_kb(field="VmHWM")
# What the driver would need to hold every row instead of streaming them to disk:
before = rss_kb()
held = [synth.row(c, 1, e) for c in camp.cells for e in range(c.episodes)]
print(json.dumps({{"samples": samples, "peak_kb": peak_kb, "held_rows_kb": rss_kb() - before}}))
"""


@pytest.mark.slow  # statistical: 40,000 synthetic episodes, memory sampled along the run (about a minute)
def test_memory_stays_flat_over_40000_episodes(tmp_path: Path):
    run_dir = tmp_path / "run"
    code = MEMORY_SCRIPT.format(tests=str(TESTS), per_cell=20_000, run_dir=str(run_dir))
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=REPO, capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    samples = np.array(result["samples"])  # per chunk: rows, driver RSS kB, workers' RSS kB
    episodes = np.cumsum(samples[:, 0])
    assert episodes[-1] == 40_000 and len(samples) == 5000
    # The first 10,000 episodes warm the allocators up (about 0.15 MB of the driver's RSS, measured:
    # growth 1,000 -> 10,000 about 150-250 kB, 10,000 -> 40,000 about 80 kB, 20,000 -> 40,000 under 10 kB),
    # so growth is read from there on.
    at_10k = int(np.searchsorted(episodes, 10_000))
    driver_growth_kb = samples[-1, 1] - samples[at_10k, 1]
    worker_growth_kb = samples[-1, 2] - samples[at_10k, 2]
    print(f"\ndriver RSS {samples[at_10k, 1] / 1024:.1f} MB at 10,000 episodes, {samples[-1, 1] / 1024:.1f} MB at "
          f"40,000; workers {samples[at_10k, 2] / 1024:.1f} -> {samples[-1, 2] / 1024:.1f} MB; peak of the whole run "
          f"(merge and report included) {result['peak_kb'] / 1024:.1f} MB; holding the 40,000 rows would take "
          f"{result['held_rows_kb'] / 1024:.1f} MB")
    # From 10,000 to 40,000 finished episodes neither the driver nor the workers grow by more than half
    # of what merely holding those 30,000 rows would cost (the rows go to disk chunk by chunk), nor by more
    # than 512 kB: anything retained per episode from 17 bytes up would show. Measured growth: 0-0.13 MB,
    # in page-sized steps that a loaded machine (pytest -n 2) moves about, so the bound never goes below
    # 192 kB (6.5 bytes per episode) however little the held rows measure (0.2 MB once, when half of it,
    # 80 kB, was under that noise and the test failed on 88 kB of growth).
    bound_kb = max(192, min(512, result["held_rows_kb"] * 0.75 / 2))
    assert driver_growth_kb < bound_kb, (driver_growth_kb, result["held_rows_kb"])
    assert worker_growth_kb < bound_kb, (worker_growth_kb, result["held_rows_kb"])
    assert pq.ParquetFile(run_dir / store.EPISODES).metadata.num_rows == 40_000


def test_default_run_folders_never_collide(tmp_path: Path) -> None:
    """A second run in the same second, or after a failed try that left its folder, gets a new one."""
    camp = campaign_from_dict({"campaign": {"name": "same", "seed": 1, "episodes": 1}})
    first = run_folders.default_run_dir(camp, tmp_path)
    first.mkdir()
    second = run_folders.default_run_dir(camp, tmp_path)
    assert second != first and not second.exists() and second.name.startswith(first.name)


def _manifest(model: dict | None = None) -> dict:
    raw = {"campaign": {"name": "t", "seed": 3, "episodes": 2}, "model": {"sim": {"control_period_s": 0.1},
                                                                         **(model or {})}}
    return runner.manifest_for(campaign_from_dict(raw, source="t.toml"), 8, {})


def test_a_run_is_rebuilt_from_its_recorded_parameters_not_todays_defaults():
    """Replay and resume rebuild every cell's parameters from the manifest: a value the run recorded stands
    even where the campaign file left it to a default that is now another."""
    manifest = _manifest()
    assert {c["params"]["mpc"]["q2_solve"] for c in manifest["cells"]} == {"every_step"}  # today's default
    for cell in manifest["cells"]:
        cell["params"]["mpc"]["q2_solve"] = "when_needed"
        cell["params"]["barrier"]["epsilon"] = 0.2
    cells = runner.campaign_from_manifest(manifest).cells
    assert {c.params.mpc.q2_solve for c in cells} == {"when_needed"}
    assert {c.level for c in cells} == {Level.of((1.0, 0.5), epsilon=0.2)}  # the level follows the parameters


def test_a_recorded_retired_field_at_its_built_in_value_is_accepted():
    manifest = _manifest({"mpc": {"controller": "mpcdc"}})
    for cell in manifest["cells"]:
        cell["params"]["mpc"].update({"ipm_central_attempt": "mpcdc", "infeasibility": "phase1_mpcdc",
                                      "ipm_after_hard_attempt": "lower_mu", "kkt_factorization": "lu"})
    assert [c.params for c in runner.campaign_from_manifest(manifest).cells] == [
        c.params for c in campaign_from_dict(manifest["campaign"]["raw"]).cells]


def test_a_run_made_before_a_field_was_introduced_is_rebuilt_with_what_it_ran():
    manifest = _manifest()
    for cell in manifest["cells"]:
        for name in ("front_accel_onset_range_s", "front_accel_duration_range_s"):
            del cell["params"]["scenario"][name]
    assert [c.params for c in runner.campaign_from_manifest(manifest).cells] == [
        c.params for c in campaign_from_dict(manifest["campaign"]["raw"]).cells]
    assert {c.params.scenario.front_accel_onset_range_s for c in runner.campaign_from_manifest(manifest).cells} == {()}


@pytest.mark.parametrize(("change", "match"), [
    (lambda mpc: mpc.update(ipm_central_attempt="all"),
     r"cell 'all': the run set mpc.ipm_central_attempt = 'all', an option since deleted \(only 'mpcdc' remains\)"),
    (lambda mpc: mpc.update(ipm_restoration=False), "the run set mpc.ipm_restoration = False, an option since deleted"),
    (lambda mpc: mpc.pop("q2_solve"), "the recorded parameters lack mpc.q2_solve, which this code needs"),
    (lambda mpc: mpc.update(colour="red"), "the recorded parameters have mpc.colour, which this code does not know"),
])
def test_a_run_this_code_cannot_rebuild_is_refused_in_one_line(change, match):
    manifest = _manifest()
    for cell in manifest["cells"]:
        change(cell["params"]["mpc"])
    with pytest.raises(CampaignError, match=match) as err:
        runner.campaign_from_manifest(manifest)
    assert "\n" not in str(err.value)


def test_replaying_a_folder_that_names_a_deleted_option_is_one_line_and_exit_2(tmp_path, capsys):
    from mcverify import cli

    run_dir = tmp_path / "old"
    run_dir.mkdir()
    manifest = _manifest()
    for cell in manifest["cells"]:
        cell["params"]["mpc"]["kkt_factorization"] = "ldlt"
    files.write_json_atomic(run_dir / store.MANIFEST, manifest)
    assert cli.main(["replay", str(run_dir), "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mpc.kkt_factorization = 'ldlt', an option since deleted" in err[0], err
