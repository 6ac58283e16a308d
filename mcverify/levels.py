"""VL-CBF levels in plain Python floats (no JAX): kappa~, its inverse, and lambda_0 <-> epsilon.

kappa~(h) = sum_{i=1..m} lambda_i h^(2i-1) (paper def.VL-CBF) is odd and strictly increasing when
every lambda_i >= 0 and one is > 0. A campaign may set the level epsilon (then lambda_0 =
-kappa~(epsilon), proof of thm.VL-CBF_levelset) or lambda_0 directly (then epsilon =
kappa~^-1(-lambda_0)). Used by campaign validation and the plant's parameter packing; it imports
nothing numeric so that loading a campaign never configures JAX.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

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
