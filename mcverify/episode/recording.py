"""What a recorded episode leaves behind: its full-resolution trajectory and its plan snapshots.

An :class:`EpisodeRecording` travels from the rollout through the executors (it pickles: plain
numpy arrays, no solver objects) to the runner, which writes it under ``trajectories/``, and to
``mcverify replay``. Its two tables, as parquet files (:meth:`EpisodeRecording.to_columns`):

``episode-NNNNNN.parquet``: one row per integration sub-step (n rows), every column (n,) float64
unless noted:

* ``t_s`` (s); the ego ``ego_x_m``, ``ego_y_m`` (m), ``ego_psi_rad`` (rad), ``ego_speed_mps`` (m/s);
  the front vehicle ``front_x_m``, ``front_y_m`` (m), ``front_speed_mps`` (m/s); the opposing one
  ``opp_x_m``, ``opp_y_m`` (m), ``opp_speed_mps`` (m/s, positive towards the ego; NaN without one);
* the applied input ``alpha_mps2`` (m/s^2), ``beta_rad`` (rad), held over the control period;
* safety: ``h_front``, ``dist_front_m``, ``gap_front_m`` (m), ``collision_front`` (0/1),
  ``h_opp`` (m), ``gap_opp_m`` (m), ``collision_opp`` (0/1);
* the control step's decision: ``active_problem`` (0 none, else :class:`~mcverify.control.decision.Source`),
  ``mode`` (:class:`~mcverify.control.decision.Mode`, -1 none), ``opp_detected`` (0/1),
  ``q1_solved``, ``q2_solved`` (0/1, NaN not solved), ``q1_time_s``, ``q2_time_s`` (the plans'
  total time T, s; NaN unless solved), ``table_one_row`` (-1 not consulted), ``both_certified``
  (0/1: neither problem solved and both failures certificates of infeasibility, Theorem 5's
  certified counter-example; NaN without a decision), ``q1_margin``, ``q2_margin`` (each problem's
  signed room, :func:`mcverify.control.margins.problem_margin`: >= 0 solved, < 0 failed; NaN not
  solved or no decision; the step's Theorem 5 margin is computed from them by
  :func:`mcverify.analysis.robustness.theorem5_step_margin`);
* the measurements: ``meas_front_x_m``, ``meas_front_y_m`` (m), ``meas_front_speed_mps`` (m/s),
  ``meas_opp_x_m`` (m), ``meas_opp_speed_mps`` (m/s).

``episode-NNNNNN-plans.parquet``: one row per node of every solved plan kept (every
``mcverify.episode.recorder.PLAN_SNAPSHOT_PERIOD_S``; m rows): ``t_s`` (s, when it was solved),
``problem`` (string, "Q1" or "Q2"), ``node`` (int64), ``t_node_s`` (s), ``x_m``, ``y_m`` (m),
``speed_mps`` (m/s), ``opp_x_m`` (m, veh_o's predicted position; NaN without one). Written whenever
the rollout recorded the episode, with no columns if no plan was kept.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

#: Column name -> 1-D array (all of one length): one parquet table.
Columns = Mapping[str, np.ndarray]

#: File-name suffixes of the two tables (``episode-NNNNNN<suffix>.parquet``).
TRAJECTORY_SUFFIX = ""
PLANS_SUFFIX = "-plans"


@dataclass(frozen=True)
class EpisodeRecording:
    """One recorded episode: ``trajectory`` (per sub-step) and ``plans`` (per plan node), see the
    module docstring for their columns. ``plans`` is None when the episode function records no plans
    (the tests' synthetic episodes); an empty mapping when it does but kept none."""

    trajectory: Columns
    plans: Columns | None = None

    def to_columns(self) -> dict[str, Columns]:
        """File-name suffix -> the columns of that parquet file (plans only when recorded)."""
        files: dict[str, Columns] = {TRAJECTORY_SUFFIX: self.trajectory}
        if self.plans is not None:
            files[PLANS_SUFFIX] = self.plans
        return files

    @classmethod
    def from_columns(cls, files: Mapping[str, Columns]) -> EpisodeRecording:
        """The inverse of :meth:`to_columns` (e.g. of tables read back from ``trajectories/``)."""
        return cls(files[TRAJECTORY_SUFFIX], files.get(PLANS_SUFFIX))
