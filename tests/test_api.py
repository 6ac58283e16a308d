"""The public API from a notebook or a script: no side effects at import, no main guard needed,
runs readable as pyarrow or pandas tables."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import mcverify
from mcverify.errors import RunError

REPO = Path(__file__).resolve().parents[1]


def test_the_api_names_stay_functions_after_every_layer_is_imported() -> None:
    import importlib
    import pkgutil

    for info in pkgutil.walk_packages(mcverify.__path__, "mcverify."):
        if not info.name.endswith(".__main__"):
            importlib.import_module(info.name)
    for name in ("load_campaign", "run", "resume", "open_run", "replay", "report", "compare"):
        assert callable(getattr(mcverify, name)) and not isinstance(getattr(mcverify, name), type(os)), name
    assert set(mcverify.__all__) <= set(dir(mcverify))


def test_open_run_of_a_folder_that_is_no_run_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(RunError, match="manifest"):
        mcverify.open_run(tmp_path)


@pytest.mark.slow  # a subprocess that starts two JAX/CasADi workers; about 20 s
def test_a_script_without_a_main_guard_runs_a_campaign_on_worker_processes(tmp_path: Path) -> None:
    """Spawned workers must not re-import the caller's script (it would run the campaign again)."""
    script = tmp_path / "study.py"
    script.write_text(textwrap.dedent(f"""
        import mcverify
        run = mcverify.run({str(REPO / "tests" / "fixtures" / "tiny.toml")!r}, {str(tmp_path / "run")!r},
                           episodes=1, workers=2, chunk_size=1, progress=False)
        episodes = run.episodes(as_pandas=True)
        cells = run.cells()
        print("ROWS", len(episodes), cells.num_rows, sorted(episodes["cell_index"]))
    """))
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    out = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, env=env,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.count("ROWS") == 1, out.stdout  # the script ran once, not once per worker
    assert "ROWS 2 2 [0, 1]" in out.stdout


def test_resume_of_a_complete_run_returns_it_running_nothing(tmp_path: Path) -> None:
    """The --resume rule of the command line holds in the API: a complete folder is no error."""
    import synthetic_episodes as synth

    from mcverify.campaign import executors, runner
    from mcverify.campaign.spec import campaign_from_dict

    raw = {"campaign": {"name": "r", "seed": 1, "episodes": 2}}
    runner.run(campaign_from_dict(raw), tmp_path / "run", executor=executors.SerialExecutor(), progress=False,
               episode_fn=synth.episodes)
    ledger = (tmp_path / "run" / "chunks.jsonl").read_bytes()
    run = mcverify.resume(tmp_path / "run", executor="serial", progress=False)
    assert run.finished and (tmp_path / "run" / "chunks.jsonl").read_bytes() == ledger
