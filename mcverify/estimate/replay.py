"""``mcverify replay ESTIMATE_DIR K [--cell NAME]``: re-simulate a counterexample an estimator found
and check it against what its folder kept.

**Importance sampling**: K is a final draw's episode id (``cell_episode`` in
``samples_cellNNN.parquet``; a failing draw is a counterexample of the target). A draw is fixed by the
campaign seed, the cell, its id, its scenario values (the ``sample_*`` columns) and the noise tilt the
final draws came from (``noise_tilt`` of the cell in ``estimate.json``, none when the noise stayed
nominal), exactly as :func:`mcverify.estimate.importance_run.scenario_unit` ran it; every value the
file kept (:data:`~mcverify.estimate.importance_run.SAMPLE_COLUMNS` and the scenario values) is
compared bit for bit. The cross-entropy iterations' episodes are not kept.

**Splitting**: K is the place of a particle in the cell's ``failing_particles`` (every particle at
the failure level at the end of an uncapped AMS run, in run order). A particle is its fresh episode
with the noise branches of its lineage, which ``noise.branch_after_steps`` / ``noise.branch_ids``
re-simulate from step 0 as an ordinary episode; the check is its running score after its last step,
bit for bit (a particle ended there, at the failure level: the rest of the replayed episode is
simulated on, as any episode).

Either writes the trajectory and plot as a run's replay does.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from mcverify import store
from mcverify.campaign import executors
from mcverify.campaign.replay import ReplayMismatch, ReplayResult, checked, write_recording
from mcverify.campaign.runner import campaign_from_manifest
from mcverify.campaign.spec import apply_overrides
from mcverify.episode.rollout import run_episodes
from mcverify.episode.snapshot import Branching
from mcverify.errors import RunError
from mcverify.estimate import folder
from mcverify.estimate.closed_loop import score_of
from mcverify.estimate.importance_run import samples_file
from mcverify.sim.noise import NoiseTilt


def estimate_method(path: Path) -> str | None:
    """``importance`` or ``splitting`` for such an estimate folder (its manifest says so, also before its
    first cell is finished); None for anything else."""
    try:
        manifest = store.read_json(Path(path) / store.MANIFEST)
        method = (manifest.get("estimate") or {}).get("method")
    except (RunError, AttributeError):
        return None
    return method if method in ("importance", "splitting") else None


def replay_counterexample(est_dir: Path, k: int, out_dir: Path | None = None,
                          cell_name: str | None = None) -> ReplayResult:
    """Replay draw or particle ``k`` of an importance-sampling or splitting estimate folder."""
    if estimate_method(est_dir) == "splitting":
        return replay_particle(est_dir, k, out_dir, cell_name)
    return replay_draw(est_dir, k, out_dir, cell_name)


def replay_draw(est_dir: Path, episode_id: int, out_dir: Path | None = None,
                cell_name: str | None = None) -> ReplayResult:
    """Re-simulate final draw ``episode_id`` of cell ``cell_name`` (may be left out when one cell is
    estimated) and check it; the trajectory and plot go to ``out_dir`` (default ESTIMATE_DIR/replay)."""
    est_dir = Path(est_dir)
    result = _cell_result(est_dir, cell_name)
    stored = _stored_draw(est_dir, result, episode_id)
    campaign = campaign_from_manifest(store.read_manifest(est_dir))
    cell = campaign.cells[result["cell_index"]]
    scenario = {name: stored[f"sample_{name}"] for name in result["parameters"]}
    tilt = result.get("noise_tilt")
    replayed = run_episodes(cell, [episode_id], campaign.seed, executors.solver_for(cell.params),
                            scenarios={episode_id: scenario}, record=True,
                            noise_tilt=None if tilt is None else NoiseTilt(**{**tilt, "theta": tuple(tilt["theta"])}))
    row = replayed.rows[0]
    stem = f"cell{result['cell_index']:03d}-episode-{episode_id:06d}"
    traj, plot = write_recording(replayed.recordings[episode_id], cell, row,
                                 Path(out_dir) if out_dir else est_dir / "replay", stem)
    # the folder keeps a few of a row's values: the others are not "newer than the run"
    return dataclasses.replace(checked(episode_id, stored, row, traj, plot), not_stored=())


def _cell_result(est_dir: Path, cell_name: str | None) -> dict[str, Any]:
    done = est_dir / folder.ESTIMATE
    cells = store.read_json(done).get("cells", []) if done.is_file() else []
    if not cells:
        raise RunError(f"{est_dir}: no cell is estimated yet: nothing to replay "
                       f"(mcverify estimate --resume {est_dir})")
    names = [c["cell"] for c in cells]
    if cell_name is None:
        if len(cells) > 1:
            raise RunError(f"{est_dir} holds {len(cells)} estimated cells ({', '.join(names)}): give --cell NAME")
        return cells[0]
    if cell_name not in names:
        raise RunError(f"{est_dir}: no estimated cell {cell_name!r}; cells: {', '.join(names)}")
    return cells[names.index(cell_name)]


def _stored_draw(est_dir: Path, result: dict[str, Any], episode_id: int) -> dict[str, Any]:
    path = samples_file(est_dir, result["cell_index"])
    if not path.is_file():
        raise RunError(f"{est_dir}: cell {result['cell']} keeps no final draws ({path.name} is missing)")
    rows = pq.read_table(path).to_pylist()
    by_id = {int(r["cell_episode"]): r for r in rows if r.get("cell_episode") is not None}
    if episode_id not in by_id:
        lo, hi = (min(by_id), max(by_id)) if by_id else (0, -1)
        raise RunError(f"{est_dir}: episode {episode_id} of cell {result['cell']} is not a kept final draw; "
                       f"the final draws are episodes {lo} to {hi} (the cross-entropy iterations' are not kept)")
    return by_id[episode_id]


def replay_particle(est_dir: Path, k: int, out_dir: Path | None = None,
                    cell_name: str | None = None) -> ReplayResult:
    """Re-simulate failing particle ``k`` of a splitting estimate's cell and check its running score;
    the trajectory and plot go to ``out_dir`` (default ESTIMATE_DIR/replay)."""
    est_dir = Path(est_dir)
    result = _cell_result(est_dir, cell_name)
    particles = result.get("failing_particles")
    if particles is None:
        raise RunError(f"{est_dir}: cell {result['cell']} was estimated before failing particles were kept "
                       "(no failing_particles in estimate.json)")
    if not particles:
        raise RunError(f"{est_dir}: no particle of cell {result['cell']} reached the failure level: nothing to replay")
    if k >= len(particles):
        raise RunError(f"{est_dir}: cell {result['cell']} has {len(particles)} failing particles (0 to "
                       f"{len(particles) - 1}), not {k}")
    particle = particles[k]
    manifest = store.read_manifest(est_dir)
    campaign = campaign_from_manifest(manifest)
    cell = campaign.cells[result["cell_index"]]
    lineage = {"noise.branch_after_steps": particle["branch_after_steps"], "noise.branch_ids": particle["branch_ids"]}
    cell = dataclasses.replace(cell, params=apply_overrides(cell.params, lineage, f"particle {k}"))
    planner = executors.solver_for(cell.params)
    episode = int(particle["episode_id"])
    score = manifest["estimate"]["score"]
    watch = Branching()
    run_episodes(cell, [episode], campaign.seed, planner, branching=watch)
    end = int(particle["end_step"])
    reached = max((score_of(v, score) for v in watch.views if v.step <= end), default=float("-inf"))
    replayed = run_episodes(cell, [episode], campaign.seed, planner, record=True)
    row = replayed.rows[0]
    stem = f"cell{result['cell_index']:03d}-particle-{k:04d}"
    traj, plot = write_recording(replayed.recordings[episode], cell, row,
                                 Path(out_dir) if out_dir else est_dir / "replay", stem)
    if np.float64(reached).tobytes() != np.float64(particle["score"]).tobytes():
        raise ReplayMismatch(f"particle {k} does not reproduce: its running {score} score after step {end} was "
                             f"{particle['score']!r}, replayed {reached!r}")
    return ReplayResult(k, traj, plot, row, ())
