"""``mcverify replay ESTIMATE_DIR EPISODE [--cell NAME]``: re-simulate one final draw of an
importance-sampling estimate (a failing draw is a counterexample of the target event) and check it
against the values its folder kept.

A final draw is fixed by the campaign seed, the cell, its episode id (``cell_episode`` in
``samples_cellNNN.parquet``), its scenario values (the ``sample_*`` columns) and the noise tilt the
final draws came from (``noise_tilt`` of the cell in ``estimate.json``, none when the noise stayed
nominal), exactly as :func:`mcverify.estimate.importance_run.scenario_unit` ran it. The replay
compares every row value the file kept (:data:`~mcverify.estimate.importance_run.SAMPLE_COLUMNS`
and the scenario values) bit for bit and writes the trajectory and plot as a run's replay does.
Only the final draws are kept; the episodes of the cross-entropy iterations are not replayable from
the folder.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from mcverify import store
from mcverify.campaign import executors
from mcverify.campaign.replay import ReplayResult, checked, write_recording
from mcverify.campaign.runner import campaign_from_manifest
from mcverify.episode.rollout import run_episodes
from mcverify.errors import RunError
from mcverify.estimate import folder
from mcverify.estimate.importance_run import samples_file
from mcverify.sim.noise import NoiseTilt


def is_importance_folder(path: Path) -> bool:
    """Whether ``path`` is an importance-sampling estimate folder (its manifest says so, also before
    its first cell is finished)."""
    try:
        manifest = store.read_json(Path(path) / store.MANIFEST)
        return (manifest.get("estimate") or {}).get("method") == "importance"
    except (RunError, AttributeError):
        return False


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
        raise RunError(f"{est_dir}: no cell is estimated yet, so no draw is kept "
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
