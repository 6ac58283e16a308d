"""The public API: run campaigns, replay, report and compare from Python (a notebook, a script).

Everything here is importable as ``mcverify.<name>``. Nothing heavy is imported until a function
is called, so ``import mcverify`` neither configures JAX nor loads CasADi. A script that calls
:func:`run` needs no ``if __name__ == "__main__":`` guard: worker processes never re-import the
caller's script.

Example::

    import mcverify
    run = mcverify.run("campaigns/smoke.toml", episodes=4)
    run.cells(as_pandas=True)          # one row per cell: rates, intervals, distances
    run.episodes()                     # pyarrow table, one row per episode
    mcverify.replay(run.path, episode_id=0)
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mcverify import store
from mcverify.errors import RunError

if TYPE_CHECKING:
    import pyarrow as pa

    from mcverify.campaign.replay import ReplayResult
    from mcverify.campaign.spec import Campaign

PathLike = str | os.PathLike


@dataclass(frozen=True)
class Run:
    """A run folder: its manifest, episodes and (once reported) per-cell statistics."""

    path: Path

    @property
    def manifest(self) -> dict[str, Any]:
        return store.read_manifest(self.path)

    @property
    def report_path(self) -> Path:
        return self.path / "report.md"

    @property
    def finished(self) -> bool:
        return "finished_utc" in self.manifest

    def episodes(self, *, as_pandas: bool = False) -> pa.Table | Any:
        """One row per episode (the columns of ``episodes.parquet``), as pyarrow or pandas."""
        return _as(store.read_episodes(self.path), as_pandas)

    def cells(self, *, as_pandas: bool = False) -> pa.Table | Any:
        """One row per cell (``cells.parquet``: rates with intervals, distances, times)."""
        import pyarrow.parquet as pq

        path = self.path / "cells.parquet"
        if not path.is_file():
            raise RunError(f"{self.path} has no cells.parquet yet: finish the run or call mcverify.report()")
        return _as(pq.read_table(path), as_pandas)

    def summary(self) -> dict[str, Any]:
        """The run's ``summary.json`` (per-cell statistics and the report's settings)."""
        return store.read_json(self.path / "summary.json")


def open_run(run_dir: PathLike) -> Run:
    """The run folder ``run_dir`` (a :class:`RunError` if it is not one)."""
    path = Path(run_dir)
    store.read_manifest(path)  # one clear line if this is not a run folder
    return Run(path)


def load_campaign(path: PathLike, *, episodes: int | None = None, seed: int | None = None,
                  settings: Sequence[str] = ()) -> Campaign:
    """Read and validate a campaign file (:class:`~mcverify.errors.CampaignError` on bad input);
    ``settings`` are ``SECTION.FIELD=VALUE`` overrides as for ``mcverify run --set``."""
    from mcverify.campaign.spec import load_campaign as _load

    return _load(path, episodes=episodes, seed=seed, settings=list(settings))


def run(campaign: Campaign | PathLike, out: PathLike | None = None, *, episodes: int | None = None,
        seed: int | None = None, settings: Sequence[str] = (), executor: str = "local",
        workers: int | None = None, address: str | None = None, chunk_size: int | None = None,
        progress: bool = True) -> Run:
    """Run a campaign (a :class:`Campaign` or a campaign file) into a new run folder and report it.

    ``out`` is the new run folder itself (as ``mcverify run --run-dir``); by default a fresh
    ``<results>/<name>-<timestamp>`` folder, where ``<results>`` is ``$MCVERIFY_RESULTS`` or else
    ``results`` under the current directory (as ``mcverify run`` without ``--out``).
    """
    from mcverify.campaign import executors, run_folders, runner

    if not hasattr(campaign, "cells"):
        campaign = load_campaign(campaign, episodes=episodes, seed=seed, settings=settings)
    elif episodes is not None or seed is not None or settings:
        raise RunError("episodes, seed and settings apply to a campaign file; set them on the Campaign instead")
    run_dir = Path(out) if out is not None else run_folders.default_run_dir(campaign)
    runner.run(campaign, run_dir, executor=executors.make_executor(executor, workers=workers, address=address),
               chunk_size=chunk_size or runner.DEFAULT_CHUNK_SIZE, progress=progress)
    return Run(run_dir)


def resume(run_dir: PathLike, *, executor: str = "local", workers: int | None = None,
           address: str | None = None, progress: bool = True) -> Run:
    """Finish an interrupted run: only the chunks that are not done are run; a complete run is
    returned as it is (the ``--resume`` rule: nothing to run is no error)."""
    from mcverify.campaign import executors, runner

    if Run(Path(run_dir)).finished:
        return Run(Path(run_dir))
    runner.resume(Path(run_dir), executor=executors.make_executor(executor, workers=workers, address=address),
                  progress=progress)
    return Run(Path(run_dir))


def replay(run_dir: PathLike, episode_id: int, out_dir: PathLike | None = None, *,
           cell: str | None = None) -> ReplayResult:
    """Re-simulate one stored episode; raises ``ReplayMismatch`` if any stored metric differs. In an
    importance-sampling or splitting estimate folder ``episode_id`` is a final draw's ``cell_episode``
    or a failing particle's place in ``failing_particles``, and ``cell`` names its cell where the
    folder estimates several (:mod:`mcverify.estimate.replay`)."""
    from mcverify.campaign.replay import replay as _replay
    from mcverify.estimate.replay import estimate_method, replay_draw, replay_particle, replay_sample

    if isinstance(episode_id, bool) or not isinstance(episode_id, numbers.Integral) or episode_id < 0:
        raise RunError(f"the episode id must be an integer >= 0, not {episode_id!r}")
    episode_id = int(episode_id)
    out = Path(out_dir) if out_dir is not None else None
    method = estimate_method(Path(run_dir))
    if method:
        fn = {"splitting": replay_particle, "subset": replay_sample}.get(method, replay_draw)
        return fn(Path(run_dir), episode_id, out, cell)
    if cell is not None:
        raise RunError(f"--cell is for estimate folders (importance sampling, splitting); {run_dir} is not one "
                       "(a run folder's episode ids already name the cell)")
    return _replay(Path(run_dir), episode_id, out)


def report(run_dir: PathLike, *, level: float | None = None, method: str | None = None) -> Path:
    """Regenerate every report file of a run folder from stored data; returns ``report.md``. level /
    method: the rates' interval of a fixed-count run (default 0.95, exact Clopper-Pearson); an estimate
    folder's rates keep its estimator's anytime-valid interval (another method or level is refused)."""
    from mcverify.reporting import run_report

    return run_report.write(Path(run_dir), level=level, method=method)


def compare(run_a: PathLike, run_b: PathLike, *, level: float = 0.95,
            pairs: Sequence[tuple[str, str]] | None = None) -> Mapping[str, Any]:
    """Per-cell differences between two runs with intervals (paired when they share episode keys)."""
    from mcverify.reporting import compare as _compare

    return _compare.compare_runs(_compare.load_run(Path(run_a)), _compare.load_run(Path(run_b)),
                                 level=level, pairs=list(pairs) if pairs else None)


def _as(table: pa.Table, as_pandas: bool) -> pa.Table | Any:
    if not as_pandas:
        return table
    try:
        return table.to_pandas()
    except ImportError:
        raise RunError("pandas is not installed: pip install 'mcverify[pandas]' (or use the pyarrow table)") from None
