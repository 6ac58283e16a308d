"""The perception noise and its structured, bounded disturbances (:class:`Noise`)."""

from __future__ import annotations

from dataclasses import dataclass

#: Most piecewise-constant segments of one structured disturbance (:attr:`Noise.front_x_segments`).
MAX_SEGMENTS = 8
#: Most noise branches of one episode (:attr:`Noise.branch_after_steps`).
MAX_BRANCHES = 64


@dataclass(frozen=True)
class Noise:
    """Perception noise (paper Sec. VI-A), applied to what the planner measures of other vehicles.

    Position noise uniform in +-``pos_far_m`` (+-``pos_near_m`` when the footprint gap is below
    ``near_threshold_m``), speed noise uniform in +-``speed_rel`` of the true speed, all times ``scale``. The
    ego's own state is measured exactly (odometry); the paper's noise is on "the measured objects".

    Structured, bounded disturbances (what ``mcverify falsify`` searches over; all 0 by default,
    which leaves the paper's noise bit for bit as it was): each measured error is
    ``half_width * ((1 - structured_share) * u + structured_share * s(t))`` with ``u`` the uniform
    draw in [-1, 1] and ``s(t) = clip(bias + drift_per_s * t, -1, 1)`` per vehicle (front/opp) and
    quantity (x position, speed), t the episode time (s). So the error stays inside the declared
    bounds (the half-widths above) whatever the disturbance: a per-episode bias, a slow drift and the
    random part share the same budget. Biases in [-1, 1] (fractions of the half-width), drifts in
    1/s, the share in [0, 1]. Piecewise-constant offsets (``*_segments``, K <= :data:`MAX_SEGMENTS`
    values in [-1, 1] each): the episode duration ``sim.max_time_s`` is cut into K equal segments and
    the k-th value is added inside the clip during segment k, so ``s(t) = clip(bias + drift_per_s * t
    + offset_k(t), -1, 1)``; () (the default) adds nothing.

    veh_f's measured lateral position (y) has its own share, ``lateral_share`` (default 0, so the
    x/speed share never changes y): its error is ``half_width * ((1 - lateral_share) * u_y +
    lateral_share * s_y)`` with ``s_y = clip(front_y_bias + front_y_drift_per_s * t + offset_k(t) +
    gap_offset_j(gap), -1, 1)``, where the time offsets ``front_y_segments`` are as above and the
    *gap offsets* ``front_y_gap_segments`` cut veh_f's true footprint gap [0, front_y_gap_window_m]
    into J equal bands (band 0 the nearest) and add the j-th value while the gap is in band j, nothing
    beyond the window: a lateral error keyed to where the ego is, e.g. veh_f measured 1 m towards the
    ego exactly as the ego comes alongside, the pattern that makes Q1 infeasible there
    (docs/rare_events.md, "What decides an event at lower noise"). veh_o's lateral position is not
    measured (it is taken on its lane centre), so it has no lateral disturbance.
    """

    kind: str = "paper"
    """paper (the Sec. VI-A perception noise) or none."""
    pos_far_m: float = 0.5
    """Half-width of the uniform position noise when the footprint gap exceeds near_threshold_m. Valid: >= 0. Paper:
    0.5."""
    pos_near_m: float = 0.1
    """Half-width of the position noise when the gap is below near_threshold_m. Valid: >= 0. Paper: 0.1."""
    near_threshold_m: float = 2.0
    """Footprint gap that switches between the far and near noise. Valid: >= 0. Paper: 2."""
    speed_rel: float = 0.1
    """Half-width of the uniform speed noise, relative to the true speed. Valid: >= 0. Paper: 0.1 (10 %)."""
    scale: float = 1.0
    """Multiplies all three half-widths (sweeps of a stronger noise). Valid: >= 0. Paper: 1."""
    structured_share: float = 0.0
    """Share of each x-position and speed error taken by the structured disturbance. Valid: [0, 1]. Paper: 0 (none)."""
    front_x_bias: float = 0.0
    """Structured bias of veh_f's measured x, as a fraction of its half-width. Valid: [-1, 1]. Paper: 0."""
    front_x_drift_per_s: float = 0.0
    """Drift of veh_f's x disturbance (1/s; clipped to [-1, 1] with the bias). Valid: finite. Paper: 0."""
    front_v_bias: float = 0.0
    """Structured bias of veh_f's measured speed, as a fraction of its half-width. Valid: [-1, 1]. Paper: 0."""
    front_v_drift_per_s: float = 0.0
    """Drift of veh_f's speed disturbance (1/s). Valid: finite. Paper: 0."""
    opp_x_bias: float = 0.0
    """Structured bias of veh_o's measured x, as a fraction of its half-width. Valid: [-1, 1]. Paper: 0."""
    opp_x_drift_per_s: float = 0.0
    """Drift of veh_o's x disturbance (1/s). Valid: finite. Paper: 0."""
    opp_v_bias: float = 0.0
    """Structured bias of veh_o's measured speed, as a fraction of its half-width. Valid: [-1, 1]. Paper: 0."""
    opp_v_drift_per_s: float = 0.0
    """Drift of veh_o's speed disturbance (1/s). Valid: finite. Paper: 0."""
    front_x_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_f's x disturbance, one per equal segment of sim.max_time_s (added to bias +
    drift t before the clip). Valid: up to 8 values in [-1, 1]. Paper: () (none)."""
    front_v_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_f's speed disturbance (see front_x_segments). Valid: up to 8 values in [-1,
    1]. Paper: ()."""
    opp_x_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_o's x disturbance (see front_x_segments). Valid: up to 8 values in [-1, 1].
    Paper: ()."""
    opp_v_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_o's speed disturbance (see front_x_segments). Valid: up to 8 values in [-1,
    1]. Paper: ()."""
    lateral_share: float = 0.0
    """Share of veh_f's lateral (y) position error taken by its structured lateral disturbance. Valid: [0, 1]. Paper:
    0 (none)."""
    front_y_bias: float = 0.0
    """Structured bias of veh_f's measured y, as a fraction of its half-width (+ towards the opposing lane). Valid:
    [-1, 1]. Paper: 0."""
    front_y_drift_per_s: float = 0.0
    """Drift of veh_f's y disturbance (1/s). Valid: finite. Paper: 0."""
    front_y_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_f's y disturbance over time (see front_x_segments). Valid: up to 8 values in
    [-1, 1]. Paper: ()."""
    front_y_gap_segments: tuple[float, ...] = ()
    """Offsets of veh_f's y disturbance by veh_f's true footprint gap: J equal bands of [0, front_y_gap_window_m],
    band 0 the nearest; none beyond the window. Valid: up to 8 values in [-1, 1]. Paper: ()."""
    front_y_gap_window_m: float = 8.0
    """The footprint-gap window that front_y_gap_segments divides. Valid: > 0. Paper: (unused)."""
    key_seed: int = -1
    """Root of the episodes' noise: -1 draws it from (campaign seed, cell, episode id); a seed >= 0 from (key_seed,
    episode id) only, whatever the cell (a splitting search re-runs a parent's noise in a child's cell). Valid: -1 or
    0 to 2^31 - 1. Paper: -1."""
    branch_after_steps: tuple[float, ...] = ()
    """Noise branches (splitting falsification): after control step branch_after_steps[i] the per-step noise comes from
    branch branch_ids[i] of the episode key (as a snapshot branch of mcverify.episode.snapshot). Valid: up to 64
    increasing integer steps >= 0. Paper: () (none)."""
    branch_ids: tuple[float, ...] = ()
    """The branch id of each of branch_after_steps. Valid: as many integers in [0, 2^31) as branch_after_steps. Paper:
    ()."""
