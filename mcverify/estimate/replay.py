"""``mcverify replay ESTIMATE_DIR K [--cell NAME]``: re-simulate a counterexample an estimator found
and check it against what its folder kept.

**Importance sampling**: K is a final draw's episode id (``cell_episode`` in
``samples_cellNNN.parquet``; a failing draw is a counterexample of the target). A draw is fixed by the
campaign seed, the cell, its id, its scenario values (the ``sample_*`` columns) and the noise tilt the
final draws came from (``noise_tilt`` of the cell in ``estimate.json``, none when the noise stayed
nominal), exactly as :func:`mcverify.estimate.importance_run.scenario_unit` ran it; every value the
file kept (:data:`~mcverify.estimate.importance_files.SAMPLE_COLUMNS` and the scenario values) is
compared bit for bit, and so is its weight, recomputed from the fitted proposal (``proposal_a``,
``proposal_b``), the defensive share and the replayed noise ratio. The cross-entropy iterations'
episodes are not kept.

**Splitting**: K is the place of a particle in the cell's ``failing_particles`` (every particle at
the failure level at the end of an uncapped AMS run, in run order). A particle is its fresh episode
with the noise branches of its lineage, which ``noise.branch_after_steps`` / ``noise.branch_ids``
re-simulate from step 0 as an ordinary episode; the check is its running score after its last step,
bit for bit (a particle ended there, at the failure level: the rest of the replayed episode is
simulated on, as any episode).

A folder whose kept values cannot be read as written (a missing column or field, a wrong type, an
unreadable file) gives one :class:`~mcverify.errors.RunError` naming it, not a traceback.

**Subset simulation**: K is the place of a sample in the cell's ``failing_samples`` (every sample of
an uncapped run's last stage at or below the failure level, in run order). A sample is its whole
input vector, kept in the run's ``-failing.npz``; it is re-simulated as one episode
(:class:`~mcverify.estimate.input_vector.ClosedLoopProblem`) and its robustness compared bit for bit.

Each writes the trajectory and plot as a run's replay does.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mcverify import store
from mcverify.campaign import executors
from mcverify.campaign.audit import REFERENCE_BACKEND, reference_cell
from mcverify.campaign.overrides import apply_overrides
from mcverify.campaign.replay import ReplayMismatch, ReplayResult, checked, write_recording
from mcverify.campaign.runner import campaign_from_manifest
from mcverify.episode.rollout import run_episodes
from mcverify.episode.snapshot import Branching
from mcverify.errors import RunError, UserError
from mcverify.estimate import folder
from mcverify.estimate.closed_loop import score_of
from mcverify.estimate.importance import Proposal, log_defensive_weights
from mcverify.estimate.importance_files import samples_file
from mcverify.estimate.importance_run import scenario_nominal
from mcverify.requirements import PERFORMANCES
from mcverify.sim.tilt import NoiseTilt


def estimate_method(path: Path) -> str | None:
    """``importance``, ``splitting`` or ``subset`` for such an estimate folder (its manifest says so, also before its
    first cell is finished); None for anything else."""
    try:
        manifest = store.read_json(Path(path) / store.MANIFEST)
        method = (manifest.get("estimate") or {}).get("method")
    except (RunError, AttributeError):
        return None
    return method if method in ("importance", "splitting", "subset") else None


@contextlib.contextmanager
def _reading(est_dir: Path):
    """Turn what a damaged folder raises while its kept values are read into one clear error."""
    try:
        yield
    except UserError:
        raise  # already one clear line (RunError is a ValueError too)
    except (KeyError, TypeError, ValueError, IndexError, pa.ArrowException) as err:
        raise RunError(f"{est_dir}: its kept estimate is damaged ({type(err).__name__}: {err}); estimate the cell "
                       "again to replay it") from None


def replay_draw(est_dir: Path, episode_id: int, out_dir: Path | None = None,
                cell_name: str | None = None, *, reference: bool = False) -> ReplayResult:
    """Re-simulate final draw ``episode_id`` of cell ``cell_name`` (may be left out when one cell is
    estimated) and check it, its weight recomputed from the fitted proposal as well; the trajectory
    and plot go to ``out_dir`` (default ESTIMATE_DIR/replay). ``reference``: with the reference solver
    instead (:func:`mcverify.campaign.audit.reference_cell`), nothing checked: the audit's other side."""
    est_dir = Path(est_dir)
    manifest, campaign, result = _open(est_dir, cell_name)
    with _reading(est_dir):
        stored = _stored_draw(est_dir, result, episode_id)
        cell = _solver_of(campaign.cells[result["cell_index"]], reference)
        scenario = {name: float(stored[f"sample_{name}"]) for name in result["parameters"]}
        tilt = result.get("noise_tilt")
        noise_tilt = None if tilt is None else NoiseTilt.from_dict(tilt)
        log_weigh = _log_weights_of(cell, result, float(manifest["estimate"]["alpha"]))
    replayed = run_episodes(cell, [episode_id], campaign.seed, executors.solver_for(cell.params),
                            scenarios={episode_id: scenario}, record=True, noise_tilt=noise_tilt)
    row = replayed.rows[0]
    stem = f"cell{result['cell_index']:03d}-episode-{episode_id:06d}" + _suffix(reference)
    traj, plot = write_recording(replayed.recordings[episode_id], cell, row,
                                 Path(out_dir) if out_dir else est_dir / "replay", stem)
    if reference:
        return ReplayResult(episode_id, traj, plot, row, ())
    # the weight is no simulated value but the estimate's factor: recomputed from the proposal (the same
    # operations as the estimator's, so bit for bit) with the replayed noise ratio
    theta = np.array([[scenario[n] for n in result["parameters"]]], dtype=float)
    row = {**row, "weight": float(np.exp(log_weigh(theta) + (row.get("noise_log_lr") or 0.0))[0])}
    # the folder keeps a few of a row's values: the others are not "newer than the run"
    return dataclasses.replace(checked(episode_id, stored, row, traj, plot), not_stored=())


def _solver_of(cell, reference: bool):
    """``cell`` as estimated, or with the reference solver for an audit."""
    return reference_cell(cell) if reference else cell


def _suffix(reference: bool) -> str:
    return f"-{REFERENCE_BACKEND}" if reference else ""


def _log_weights_of(cell, result: dict[str, Any], alpha: float):
    """theta (m, d) -> the scenario part of the final draws' log weights, by the estimator's own function
    (:func:`mcverify.estimate.importance.log_defensive_weights`), with the cell's fitted proposal."""
    nominal = scenario_nominal(cell)
    a, b = (np.array([math.nan if v is None else v for v in result[k]], dtype=float)
            for k in ("proposal_a", "proposal_b"))
    # NaN: no cross-entropy iteration ran and the nominal has a normal coordinate, so the proposal is the nominal
    fitted = nominal if np.isnan(a).any() else Proposal(nominal.low, nominal.high, a, b)
    return lambda theta: log_defensive_weights(nominal, fitted, alpha, theta)


def _open(est_dir: Path, cell_name: str | None) -> tuple[dict[str, Any], Any, dict[str, Any]]:
    """(manifest, campaign, the cell's result) of an estimate folder."""
    manifest = store.read_manifest(est_dir)
    with _reading(est_dir):
        result = _cell_result(est_dir, cell_name)  # first: "nothing estimated yet" before the campaign is read
        return manifest, campaign_from_manifest(manifest), result


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
                    cell_name: str | None = None, *, reference: bool = False) -> ReplayResult:
    """Re-simulate failing particle ``k`` of a splitting estimate's cell and check its running score;
    the trajectory and plot go to ``out_dir`` (default ESTIMATE_DIR/replay). ``reference``: as
    :func:`replay_draw`'s."""
    est_dir = Path(est_dir)
    manifest, campaign, result = _open(est_dir, cell_name)
    with _reading(est_dir):
        particle = _failing_particle(est_dir, result, k)
        lineage = {"noise.branch_after_steps": particle["branch_after_steps"],
                   "noise.branch_ids": particle["branch_ids"]}
        cell = campaign.cells[result["cell_index"]]
        cell = _solver_of(dataclasses.replace(cell, params=apply_overrides(cell.params, lineage, f"particle {k}")),
                          reference)
        score = manifest["estimate"]["score"]
    planner = executors.solver_for(cell.params)
    episode, end = particle["episode_id"], particle["end_step"]
    watch = Branching()  # only watches: the step views give the running score
    replayed = run_episodes(cell, [episode], campaign.seed, planner, branching=watch, record=True)
    reached = max((score_of(v, score) for v in watch.views if v.step <= end), default=float("-inf"))
    row = replayed.rows[0]
    stem = f"cell{result['cell_index']:03d}-particle-{k:04d}" + _suffix(reference)
    traj, plot = write_recording(replayed.recordings[episode], cell, row,
                                 Path(out_dir) if out_dir else est_dir / "replay", stem)
    if not reference and np.float64(reached).tobytes() != np.float64(particle["score"]).tobytes():
        raise ReplayMismatch(f"particle {k} does not reproduce: its running {score} score after step {end} was "
                             f"{particle['score']!r}, replayed {reached!r}")
    return ReplayResult(k, traj, plot, row, ())


def _failing_particle(est_dir: Path, result: dict[str, Any], k: int) -> dict[str, Any]:
    """Failing particle ``k`` of a cell result, its fields checked (a damaged record is a RunError)."""
    particles = result.get("failing_particles")
    if particles is None:
        raise RunError(f"{est_dir}: cell {result['cell']} was estimated before failing particles were kept "
                       "(no failing_particles in estimate.json)")
    if not particles:
        raise RunError(f"{est_dir}: no particle of cell {result['cell']} reached the failure level: nothing to replay")
    if k >= len(particles):
        raise RunError(f"{est_dir}: cell {result['cell']} has {len(particles)} failing particles (0 to "
                       f"{len(particles) - 1}), not {k}")
    p = particles[k]
    steps, ids = p["branch_after_steps"], p["branch_ids"]
    whole = [p["episode_id"], p["end_step"], *steps, *ids]
    if (not all(isinstance(x, int) and not isinstance(x, bool) and x >= 0 for x in whole)
            or len(steps) != len(ids) or not isinstance(p["score"], (int, float))):
        raise ValueError(f"failing particle {k} is not (episode id, end step, branch steps and ids: integers >= 0, "
                         "as many ids as steps; a score)")
    return p


def replay_sample(est_dir: Path, k: int, out_dir: Path | None = None, cell_name: str | None = None, *,
                  reference: bool = False) -> ReplayResult:
    """Re-simulate failing sample ``k`` of a subset simulation estimate's cell and check its robustness;
    the trajectory and plot go to ``out_dir`` (default ESTIMATE_DIR/replay). ``reference``: as
    :func:`replay_draw`'s."""
    from mcverify.estimate import subset_run  # noqa: PLC0415 - only for subset folders

    est_dir = Path(est_dir)
    manifest, campaign, result = _open(est_dir, cell_name)
    with _reading(est_dir):
        samples = result.get("failing_samples") or []
        if not samples:
            raise RunError(f"{est_dir}: no sample of cell {result['cell']} reached the event: nothing to replay")
        if k >= len(samples):
            raise RunError(f"{est_dir}: cell {result['cell']} has {len(samples)} failing samples (0 to "
                           f"{len(samples) - 1}), not {k}")
        run_id, j = int(samples[k]["run"]), int(samples[k]["sample"])
        x, g = subset_run.failing_inputs(est_dir, result["cell_index"], run_id)
        cell = _solver_of(campaign.cells[result["cell_index"]], reference)
        target = manifest["estimate"]["target"]
        performance = manifest["estimate"].get("performance", PERFORMANCES[0])
    problem = subset_run.problem_for(cell, campaign.seed, target, performance)
    replayed = problem.simulate(x[j:j + 1], record=True)
    row = replayed.rows[0]
    stem = f"cell{result['cell_index']:03d}-sample-{k:04d}" + _suffix(reference)
    traj, plot = write_recording(replayed.recordings[0], cell, row, Path(out_dir) if out_dir else est_dir / "replay",
                                 stem)
    got = problem.performance(row)
    if not reference and np.float64(got).tobytes() != np.float64(g[j]).tobytes():
        raise ReplayMismatch(f"failing sample {k} does not reproduce: its {target} {performance} was {float(g[j])!r}, "
                             f"replayed {got!r}")
    return ReplayResult(k, traj, plot, row, ())
