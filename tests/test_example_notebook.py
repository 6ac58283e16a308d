"""docs/example_notebook.py runs as a new user would run it (slow: two real campaigns, a replay and a
comparison, about four minutes on 2 busy cores)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_the_example_notebook_runs_and_prints_what_it_promises(tmp_path):
    pytest.importorskip("pandas")
    env = {**os.environ, "MCVERIFY_RESULTS": str(tmp_path)}
    done = subprocess.run([sys.executable, "docs/example_notebook.py"], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=1200)
    assert done.returncode == 0, done.stderr[-2000:]
    out = done.stdout
    assert "run folder:" in out and "unsafe episode(s)" in out and "replayed:" in out
    assert "scenario.front_speed_kmh" in out and "..." not in out.split("unsafe episode(s)")[0]  # whole tables
    assert out.count("paired safe-rate difference") == 2  # one line per cell
    runs = sorted(p.name for p in tmp_path.iterdir())
    assert len(runs) == 2 and all(r.startswith("smoke-") for r in runs)
    assert list((tmp_path / runs[0] / "replay").glob("episode-*.png"))
