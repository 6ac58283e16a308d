"""Results do not depend on the caller's thread and XLA settings (issue 48 point 6).

Cluster schedulers run jobs with single-threaded settings; a scheduler's ``XLA_FLAGS`` once stopped
XLA from reading the ISA cap that :mod:`mcverify.sim` appended, and every Table IV episode changed
in its last bits. Each check runs the same computation in two fresh interpreters, one with the
default environment and one with the scheduler's, and compares every output bit for bit.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

#: What single-threaded cluster jobs set (the XLA part as schedulers' recipes write it).
SCHEDULER_ENV = {
    "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
    "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
}

# The JAX plant alone (observe, advance, every sub-step check) on a fixed input schedule, with veh_o
# placed mid-run: a SHA-256 over every output. With "unpinned" the pin is skipped, to show that
# the check can fail (the caller's flags reach XLA).
PLANT_SCRIPT = """
import hashlib, sys
import mcverify.provenance
if sys.argv[1:] == ["unpinned"]:
    mcverify.provenance.pin_xla_flags = lambda environ=None: ""
import jax, jax.numpy as jnp, numpy as np
from mcverify.campaign.spec import load_campaign
from mcverify.sim.lanes import LaneGroups
from mcverify.sim.plant import initial_plant
p = load_campaign("campaigns/table4.toml", episodes=1).cells[0].params
n = 8
keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.PRNGKey(3), i))(jnp.arange(n))
lanes = LaneGroups(initial_plant(p, [0.0] * n), keys, p)
digest, rng = hashlib.sha256(), np.random.default_rng(5)
for step in range(60):
    if step == 20:
        for b in range(n):
            lanes.place_opposing(b, 60.0 + 5 * b, -10.0)
    front, opp = lanes.observe(step)
    u = np.column_stack([rng.uniform(-1, 2, n), rng.uniform(-0.05, 0.1, n)])
    subs = lanes.advance(u, np.ones(n, dtype=bool))
    for a in (front, opp, lanes.ego(), *lanes.substeps_of(subs), *lanes.trace()):
        digest.update(np.ascontiguousarray(np.asarray(a)).tobytes())
print(digest.hexdigest())
"""

# One real closed-loop episode (Table IV, Scenario A, MPC-DC: the cheapest cell), its row as JSON
# with every float as its exact hex form.
EPISODE_SCRIPT = """
import json
from mcverify.campaign.spec import load_campaign
from mcverify.campaign.work import Work, run_work, simulate
c = load_campaign("campaigns/table4.toml", episodes=1)
out = run_work(Work(c.cells[0], (0,), c.seed, c.common_random_numbers, (), simulate))
assert out.error is None, out.error
print(json.dumps({k: v.hex() if isinstance(v, float) else v for k, v in out.rows[0].items()}))
"""


def _run(script: str, extra_env: dict[str, str], *args: str) -> str:
    env = {k: v for k, v in os.environ.items() if k not in SCHEDULER_ENV}
    env.update(extra_env)
    proc = subprocess.run([sys.executable, "-c", script, *args], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip().splitlines()[-1]


def _has_fma() -> bool:
    try:
        return " fma " in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


@pytest.fixture(scope="module")
def plant_by_default() -> str:
    return _run(PLANT_SCRIPT, {})


def test_the_plant_is_the_same_under_a_schedulers_settings(plant_by_default: str) -> None:
    assert _run(PLANT_SCRIPT, SCHEDULER_ENV) == plant_by_default


@pytest.mark.skipif(not _has_fma(), reason="without FMA3 the ISA cap changes nothing to detect")
def test_the_plant_check_sees_the_callers_flags_when_nothing_is_pinned(plant_by_default: str) -> None:
    """The check above can fail: with the pin skipped, FMA reaches the plant and bits change."""
    assert _run(PLANT_SCRIPT, SCHEDULER_ENV, "unpinned") != plant_by_default


@pytest.mark.slow
def test_one_episode_is_the_same_under_a_schedulers_settings() -> None:
    from mcverify.schema import TIMING_COLUMNS

    default = json.loads(_run(EPISODE_SCRIPT, {}))
    scheduled = json.loads(_run(EPISODE_SCRIPT, SCHEDULER_ENV))
    assert default.keys() == scheduled.keys()
    differ = {k: (default[k], scheduled[k]) for k in default if k not in TIMING_COLUMNS and default[k] != scheduled[k]}
    assert differ == {}


def test_the_manifest_records_the_pinned_flags_and_the_callers_threads(tmp_path, monkeypatch) -> None:
    import synthetic_episodes as synth

    from mcverify import provenance, store
    from mcverify.campaign import executors, runner
    from mcverify.campaign.spec import campaign_from_dict

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    camp = campaign_from_dict({"campaign": {"name": "synthetic", "seed": 5, "episodes": 2}})
    runner.run(camp, tmp_path / "run", executor=executors.SerialExecutor(), progress=False,
               episode_fn=synth.episodes, record_first=False)
    manifest = store.read_json(tmp_path / "run" / store.MANIFEST)
    assert manifest["code"]["xla_flags"] == provenance.pinned_xla_flags() == "--xla_cpu_max_isa=AVX"
    threads = manifest["environment"]["threads"]
    assert threads["OMP_NUM_THREADS"] == "1" and threads["usable_cores"] >= 1
