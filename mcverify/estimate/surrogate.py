"""A structure-matched surrogate of a noise-driven closed-loop failure, with an exact probability.

Why it exists: the rare-event estimators must show their coverage on a problem built like the
closed loop's noise-driven failures before any closed-loop claim (issue 50). The random walk of
:mod:`mcverify.estimate.synthetic` accumulates its event over many steps, which flatters splitting;
here, as in the closed loop, a few perception-noise draws at one instant decide the event.

The input is one vector x of independent standard normals, the layout the closed loop will use:

- ``x[0]``: the initial gap unit, g0 = gap_low + (gap_high - gap_low) Phi(x[0]);
- ``x[1]``: the closing-speed unit, its class k by Phi(x[1]) against the cumulative ``class_probs``;
- ``x[2 + t * channels + c]``: the noise unit of control step t (clock "time"; the "decision" clock
  re-keys them, :meth:`Surrogate.noise_units`), channel c, used as the uniform unit e = 2 Phi(x) - 1
  in [-1, 1] that :func:`mcverify.sim.noise.unit_draws` gives the closed loop.

The gap closes deterministically, gap(t) = g0 - speed_k dt t, and the decision instant tau is the
first step with gap(tau) <= ``decision_gap_m``. Only channel 0 at steps tau, tau + 1, tau + 2 matters
(the measured position of the front vehicle); every other unit is irrelevant. The event has three
routes, with tails a, b, c that grow with a severity s(tau, k) = speed_factor[k] (1 + tau / 100):

- jump: e_tau >= 1 - 2a (one draw beyond a far tail);
- sustained offset: e_tau, e_tau+1, e_tau+2 all >= 1 - 2b (three draws beyond a milder tail);
- away then towards: e_tau <= -1 + 2c and e_tau+1 >= 1 - 2c;

with a = share_jump kappa s, b = (share_sustained kappa s)^(1/3), c = (share_away kappa s)^(1/2), so
each route carries about its share of p. ``kappa`` is solved so that the exact p equals the target.
After the decision the episode runs ``depth_steps`` deterministic steps (the scenario sets the depth).

The performance function is a robustness, graded in the noise units as a distance is in metres:
g = depth(k) * min(r_jump, r_sustained, r_away), each r the margin (in units of the noise bound) by
which its route misses, e.g. r_jump = (1 - 2a) - e_tau; the event is g <= 0. It is continuous in
the noise units and piecewise continuous in the scenario units (tau steps, as in the closed loop).

Exact p: given tau and k the three routes' union has a closed form in (a, b, c) (conditioning on the
first draw); tau given k takes finitely many values with exactly known masses (g0 is uniform), so
p = sum_k P(k) sum_t P(tau = t | k) q(a, b, c at s(t, k)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import optimize
from scipy.special import ndtr, ndtri

#: The scenario units at the front of the input vector (initial gap, closing-speed class).
SCENARIO_UNITS = 2
#: How the noise units are keyed to control steps (see :meth:`Surrogate.noise_units`).
CLOCKS = ("time", "decision")
#: The units of the routes' margins (see :meth:`Surrogate.margins`).
MARGINS = ("bound", "probit")


def union_probability(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """P(jump or sustained or away-then-towards) for independent uniforms u0, u1, u2 on [0, 1]:
    J = {u0 > 1 - a}, S = {u0, u1, u2 > 1 - b}, A = {u0 < c, u1 > 1 - c}. Conditioning on u0 outside J,
    P(S or A | u0) = [u0 > 1-b] b^2 + [u0 < c] c - [both] min(b, c) b; integrated over u0."""
    a, b, c = (np.clip(np.asarray(v, dtype=float), 0.0, 1.0) for v in (a, b, c))
    not_jump_top = 1.0 - a
    sustained = np.maximum(0.0, b - a)  # |(1 - b, 1 - a]|
    away = np.minimum(c, not_jump_top)  # |[0, c) within [0, 1 - a]|
    both = np.maximum(0.0, np.minimum(c, not_jump_top) - (1.0 - b))
    return a + sustained * b * b + away * c - both * np.minimum(b, c) * b


@dataclass(frozen=True)
class Surrogate:
    """The surrogate problem (see the module docstring); build a calibrated one with :meth:`at`."""

    kappa: float = 1e-4
    horizon_steps: int = 300
    channels: int = 1
    clock: str = "time"  # which noise unit a step uses: "time" (unit t at step t) or "decision" (see noise_units)
    margin: str = "bound"  # the routes' margins in units of the noise bound ("bound") or of the normal units ("probit")
    dt_s: float = 0.1
    gap_low_m: float = 20.0
    gap_high_m: float = 80.0
    decision_gap_m: float = 10.0
    speeds_mps: tuple[float, ...] = (4.0, 6.0, 9.0)
    class_probs: tuple[float, ...] = (0.5, 0.3, 0.2)
    speed_factor: tuple[float, ...] = (0.5, 1.0, 2.0)
    depth_m: tuple[float, ...] = (1.0, 2.0, 4.0)  # metres per unit of noise-bound margin, per class
    depth_steps: int = 40
    shares: tuple[float, float, float] = (0.4, 0.35, 0.25)  # jump, sustained, away-then-towards
    _cum: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (len(self.speeds_mps) == len(self.class_probs) == len(self.speed_factor) == len(self.depth_m)):
            raise ValueError("speeds, class probabilities, speed factors and depths need one entry per class")
        if self.clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, got {self.clock!r}")
        if self.margin not in MARGINS:
            raise ValueError(f"margin must be one of {MARGINS}, got {self.margin!r}")
        if abs(sum(self.class_probs) - 1.0) > 1e-12 or min(self.class_probs) <= 0:
            raise ValueError(f"class probabilities must be positive and sum to 1, got {self.class_probs}")
        if self.max_tau() + 3 + self.depth_steps > self.horizon_steps:
            raise ValueError("the horizon must hold the latest decision, its three draws and the depth")
        object.__setattr__(self, "_cum", np.cumsum(self.class_probs)[:-1])

    @classmethod
    def at(cls, p: float, **options) -> Surrogate:
        """The surrogate whose exact event probability is ``p`` (kappa solved in log space)."""
        if not 0.0 < p < 0.05:
            raise ValueError(f"the surrogate is built for rare events: need 0 < p < 0.05, got {p}")
        base = cls(**options)
        root = optimize.brentq(lambda lk: math.log(replace(base, kappa=math.exp(lk)).exact_p()) - math.log(p),
                               math.log(p) - 10.0, math.log(p) + 5.0, xtol=1e-14, rtol=1e-14)
        return replace(base, kappa=math.exp(root))

    @property
    def dimension(self) -> int:
        """Length of the input vector: the scenario units, then ``channels`` noise units per step."""
        return SCENARIO_UNITS + self.horizon_steps * self.channels

    def max_tau(self) -> int:
        return int(math.ceil((self.gap_high_m - self.decision_gap_m) / (min(self.speeds_mps) * self.dt_s)))

    # -- the scenario: class, decision instant, severity --------------------------------------------

    def scenario(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(class index, decision step tau) of each row of ``x`` (n, dimension)."""
        k = np.searchsorted(self._cum, ndtr(x[:, 1]), side="right")
        g0 = self.gap_low_m + (self.gap_high_m - self.gap_low_m) * ndtr(x[:, 0])
        step_m = np.asarray(self.speeds_mps)[k] * self.dt_s
        tau = np.maximum(0, np.ceil((g0 - self.decision_gap_m) / step_m)).astype(np.int64)
        return k, tau

    def tails(self, tau: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The routes' tails (a, b, c) at decision step ``tau`` in class ``k``."""
        severity = self.kappa * np.asarray(self.speed_factor)[k] * (1.0 + np.asarray(tau) / 100.0)
        jump, sustained, away = self.shares
        return jump * severity, np.cbrt(sustained * severity), np.sqrt(away * severity)

    # -- the performance function and its cost ------------------------------------------------------

    def noise_units(self, x: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """(n, 3) channel-0 normal units at steps tau, tau + 1, tau + 2 (the closed loop uses 2 Phi(x) - 1).

        With clock "time" step t uses noise unit t, as the closed loop draws its noise today; with
        clock "decision" step t uses unit (t - tau) mod horizon, so the decisive draws are always
        units 0, 1, 2 whatever the scenario. Both have the same law (the units are i.i.d. and the
        re-keying is a permutation fixed by the scenario units), hence the same p; they differ in
        how a Markov chain over x sees the problem: under "time" a change of the scenario that moves
        tau hands the decision to other, unconditioned units."""
        offset = tau[:, None] if self.clock == "time" else np.zeros_like(tau)[:, None]
        cols = SCENARIO_UNITS + (offset + np.arange(3)[None, :]) * self.channels
        return np.take_along_axis(x, cols, axis=1)

    def margins(self, z: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
        """(n,) min over the routes of the margin by which each misses, for decisive normal units z (n, 3).

        "bound": in units of the noise bound, e = 2 Phi(z) - 1, as a distance in metres is linear in
        the measured error (r_jump = (1 - 2a) - e_tau, ...); "probit": in the normal units themselves
        (r_jump = Phi^-1(1 - a) - z_tau, ...). Same event, different grading: under "bound" the near
        misses of the sustained and away routes look far in g next to the jump route's."""
        if self.margin == "bound":
            e = 2.0 * ndtr(z) - 1.0
            r_jump = (1.0 - 2.0 * a) - e[:, 0]
            r_sustained = (1.0 - 2.0 * b) - e.min(axis=1)
            r_away = np.maximum(e[:, 0] - (-1.0 + 2.0 * c), (1.0 - 2.0 * c) - e[:, 1])
        else:
            t_a, t_b, t_c = -ndtri(a), -ndtri(b), -ndtri(c)
            r_jump = t_a - z[:, 0]
            r_sustained = t_b - z.min(axis=1)
            r_away = np.maximum(z[:, 0] + t_c, t_c - z[:, 1])
        return np.minimum(np.minimum(r_jump, r_sustained), r_away)

    def performance(self, x: np.ndarray) -> np.ndarray:
        """(n,) robustness g of the rows of ``x`` (n, dimension): the event is g <= 0."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        if x.shape[1] != self.dimension:
            raise ValueError(f"inputs need {self.dimension} units per row, got {x.shape[1]}")
        k, tau = self.scenario(x)
        a, b, c = self.tails(tau, k)
        return np.asarray(self.depth_m)[k] * self.margins(self.noise_units(x, tau), a, b, c)

    def routes(self, x: np.ndarray) -> np.ndarray:
        """(n, 3) bool: which routes (jump, sustained, away then towards) the rows of ``x`` take."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        k, tau = self.scenario(x)
        a, b, c = self.tails(tau, k)
        u = ndtr(self.noise_units(x, tau))
        return np.stack([u[:, 0] >= 1.0 - a, np.all(u >= (1.0 - b)[:, None], axis=1),
                         (u[:, 0] <= c) & (u[:, 1] >= 1.0 - c)], axis=1)

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(robustness, control steps) of the rows of ``x``: the interface of subset simulation."""
        return self.performance(x), self.steps(x)

    def steps(self, x: np.ndarray) -> np.ndarray:
        """(n,) control steps an evaluation simulates: up to the decision, its three draws, the depth."""
        _, tau = self.scenario(np.atleast_2d(x))
        return np.minimum(self.horizon_steps, tau + 3 + self.depth_steps)

    # -- exact quantities ---------------------------------------------------------------------------

    def tau_masses(self) -> tuple[np.ndarray, np.ndarray]:
        """(steps t, masses P(k) P(tau = t | k)) as (classes, steps) arrays: g0 is uniform, so each
        mass is the share of [gap_low, gap_high] in (decision + (t - 1) d, decision + t d]."""
        t = np.arange(self.max_tau() + 1)
        span = self.gap_high_m - self.gap_low_m
        masses = []
        for speed, prob in zip(self.speeds_mps, self.class_probs, strict=True):
            d = speed * self.dt_s
            lo = np.maximum(self.gap_low_m, self.decision_gap_m + (t - 1) * d)
            hi = np.minimum(self.gap_high_m, self.decision_gap_m + t * d)
            masses.append(prob * np.maximum(0.0, hi - lo) / span)
        return t, np.array(masses)

    def exact_p(self) -> float:
        """The event probability, summed exactly over the class and the decision instant."""
        t, masses = self.tau_masses()
        k = np.repeat(np.arange(len(self.class_probs))[:, None], t.size, axis=1)
        a, b, c = self.tails(np.broadcast_to(t, k.shape), k)
        return float(np.sum(masses * union_probability(a, b, c)))

    def route_probabilities(self) -> dict[str, float]:
        """Each route's own probability (they overlap a little: jump and sustained share u0)."""
        t, masses = self.tau_masses()
        k = np.repeat(np.arange(len(self.class_probs))[:, None], t.size, axis=1)
        a, b, c = self.tails(np.broadcast_to(t, k.shape), k)
        return {"jump": float(np.sum(masses * a)), "sustained": float(np.sum(masses * b**3)),
                "away_then_towards": float(np.sum(masses * c * c))}

    def mean_steps(self) -> float:
        """The expected control steps of one evaluation (the crude Monte Carlo episode's cost)."""
        t, masses = self.tau_masses()
        return float(np.sum(masses * np.minimum(self.horizon_steps, t + 3 + self.depth_steps)))

    def crude(self, episodes: int, rng: np.random.Generator, batch: int = 20_000) -> int:
        """Events among ``episodes`` crude Monte Carlo draws (a check of :meth:`exact_p`)."""
        hits = 0
        for start in range(0, episodes, batch):
            m = min(batch, episodes - start)
            hits += int(np.sum(self.performance(rng.standard_normal((m, self.dimension))) <= 0.0))
        return hits


# -- the surrogate as a branching process, for adaptive multilevel splitting ---------------------------


@dataclass(frozen=True)
class SurrogatePath:
    """One episode (or branch) of :class:`SplittingProcess`: its whole input vector, the running
    danger score after each control step from step 0, and the steps this simulation ran."""

    x: np.ndarray
    scores: np.ndarray
    steps: int

    def snapshot(self, step: int) -> tuple[int, np.ndarray]:
        return step, self.x

    def replay_record(self) -> dict[str, list[float]]:
        return {"x": self.x.tolist()}


@dataclass(frozen=True)
class SplittingProcess:
    """The surrogate as a :class:`mcverify.estimate.splitting.BranchingProcess`: the danger score after
    step t is minus the robustness with the decisive draws not yet made counted as neutral (e = 0),
    its running maximum the path's score; it reaches 0 exactly on the event (only the jump route can
    be complete before the last decisive draw, and then it is the event). A branch from the snapshot
    after step t keeps every unit used up to t (the scenario units among them) and draws the later
    ones afresh from (``seed``, branch id): the closed loop's time-restart splitting."""

    surrogate: Surrogate
    seed: int = 0

    def _step_of_units(self, tau: int) -> np.ndarray:
        """The control step at which each noise unit (per step, all channels together) is used."""
        t = np.arange(self.surrogate.horizon_steps)
        return t if self.surrogate.clock == "time" else (t + tau) % self.surrogate.horizon_steps

    def run(self, start, branch_id: int, stop_level: float) -> SurrogatePath:
        s = self.surrogate
        fresh = np.random.default_rng([self.seed, branch_id]).standard_normal(s.dimension)
        if start is None:
            after, x = -1, fresh
        else:
            after, parent = start
            _, tau = s.scenario(parent[None, :])
            later = np.repeat(self._step_of_units(int(tau[0])) > after, s.channels)
            x = parent.copy()
            x[SCENARIO_UNITS:][later] = fresh[SCENARIO_UNITS:][later]
        k, tau = s.scenario(x[None, :])
        a, b, c = s.tails(tau, k)
        z = s.noise_units(x[None, :], tau)[0]
        end = int(min(s.horizon_steps, tau[0] + 3 + s.depth_steps))
        t = np.arange(end)
        seen = (t[:, None] >= tau[0] + np.arange(3)[None, :])  # (steps, 3): decisive draw j made by step t
        partial = np.where(seen, z[None, :], 0.0)  # a draw not yet made counts as e = 0 (z = 0)
        danger = -np.asarray(s.depth_m)[k[0]] * s.margins(partial, a, b, c)
        scores = np.maximum.accumulate(danger)
        hit = np.flatnonzero(scores >= stop_level)
        stop = int(hit[0]) + 1 if hit.size else end  # the failure set is absorbing for the estimate
        return SurrogatePath(x, scores[:stop], stop - (after + 1))
