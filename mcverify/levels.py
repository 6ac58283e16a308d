"""VL-CBF levels in plain Python floats (no JAX): kappa~, its inverse, lambda_0 <-> epsilon, and the
:class:`Level` of a cell.

kappa~(h) = sum_{i=1..m} lambda_i h^(2i-1) (paper def.VL-CBF) is odd and strictly increasing when
every lambda_i >= 0 and one is > 0. A campaign may set the level epsilon (then lambda_0 =
-kappa~(epsilon), proof of thm.VL-CBF_levelset) or lambda_0 directly (then epsilon =
kappa~^-1(-lambda_0)). It imports nothing numeric so that loading a campaign never configures JAX.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

#: Bisection steps of :func:`kappa_tilde_inverse`. The starting bracket [0, B] holds the root and
#: B <= 2 m |root|, so 64 halvings leave a relative width below 2m * 5.4e-20.
KAPPA_INVERSE_STEPS: int = 64



def _check_lambdas(lambdas_m: Sequence[float]) -> list[float]:
    lams = [float(v) for v in lambdas_m]
    if not lams:
        raise ValueError("lambdas_m must hold at least lambda_1 (m >= 1)")
    if any(not math.isfinite(v) or v < 0.0 for v in lams) or max(lams) <= 0.0:
        raise ValueError(f"lambdas_m must be finite, >= 0 and not all zero, got {tuple(lams)}")
    return lams


def kappa_tilde(lambdas_m: Sequence[float], h: float) -> float:
    """kappa~(h) = sum_{i=1..m} lambda_i h^(2i-1), Horner's rule in h^2."""
    lams = [float(v) for v in lambdas_m]
    h_sq = h * h
    acc = lams[-1]
    for lam in reversed(lams[:-1]):
        acc = lam + h_sq * acc
    return h * acc


def kappa_tilde_inverse(lambdas_m: Sequence[float], value: float) -> float:
    """The unique real h with kappa~(h) = value (bisection).

    Raises:
        ValueError: when a lambda_i is negative or non-finite, or all are zero.
    """
    lams = _check_lambdas(lambdas_m)
    target = abs(float(value))
    lo = 0.0
    hi = 2.0 * min((target / lam) ** (1.0 / (2 * i + 1)) for i, lam in enumerate(lams) if lam > 0.0)
    for _ in range(KAPPA_INVERSE_STEPS):
        mid = 0.5 * (lo + hi)
        if kappa_tilde(lams, mid) < target:
            lo = mid
        else:
            hi = mid
    return math.copysign(0.5 * (lo + hi), value) if value != 0.0 else 0.0


def lambda0_from_epsilon(lambdas_m: Sequence[float], epsilon: float) -> float:
    """lambda_0 = -kappa~(epsilon): the level parameter that makes {h >= epsilon} forward invariant."""
    return -kappa_tilde(_check_lambdas(lambdas_m), float(epsilon))


def epsilon_from_lambda0(lambdas_m: Sequence[float], lambda0: float) -> float:
    """The level epsilon = kappa~^-1(-lambda_0) enforced by a given lambda_0."""
    return kappa_tilde_inverse(lambdas_m, -float(lambda0))


@dataclass(frozen=True)
class Level:
    """The level of a cell's VL-CBF to veh_f, both ways: epsilon (the set {h >= epsilon} is kept forward
    invariant) and lambda0 = -kappa~(epsilon) (<= 0, the constant term of the barrier's Lambda). Resolved
    once per cell (:meth:`of_barrier`) and passed as it is to the planner, the solver and the MPC-DC margin."""

    epsilon: float
    lambda0: float

    @classmethod
    def of(cls, lambdas_m: Sequence[float], epsilon: float | None = None, lambda0: float | None = None) -> Level:
        """From the barrier's lambdas and exactly one of epsilon and lambda0 (the other is computed).

        Raises:
            ValueError: both or neither given, or lambdas_m unusable (:func:`kappa_tilde_inverse`);
            ArithmeticError: an overflow from an absurd level.
        """
        if (epsilon is None) == (lambda0 is None):
            raise ValueError("set exactly one of epsilon and lambda0")
        if epsilon is not None:
            return cls(float(epsilon), lambda0_from_epsilon(lambdas_m, float(epsilon)))
        return cls(epsilon_from_lambda0(lambdas_m, float(lambda0)), float(lambda0))

    @classmethod
    def of_barrier(cls, barrier) -> Level:
        """The level of a :class:`mcverify.model.Barrier` (its ``lambdas_m`` and ``epsilon`` or ``lambda0``)."""
        return cls.of(barrier.lambdas_m, epsilon=barrier.epsilon, lambda0=barrier.lambda0)
