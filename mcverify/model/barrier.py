"""The VL-CBF barriers of the ego: the safety ellipse to the front vehicle and h_eo to the opposing one."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Barrier:
    """Varying-level CBF to the front vehicle (eq.VL-CBF, Theorem thm.VL-CBF_levelset).

    h_ef(x_e, t) = ((x_e - x_f)/a)^2 + ((y_e - y_f)/b)^2 - 1 is the ellipse of fig.relative_CBF in the
    standard form (the paper's beta_1 = 1/a^2, beta_2 = 1/b^2, beta_3 = 1 up to a common scale).

    The default axes are the smallest-area ellipse through the corners (+-L, +-W) of the Minkowski sum of two
    aligned footprints: a = sqrt(2) L, b = sqrt(2) W (with the ego c.g. outside it, they cannot touch). The level:
    :class:`mcverify.levels.Level` (``epsilon`` or ``lambda0``, with ``lambdas_m``).

    Opposing vehicle (eq.two_way_value_function_e): h_eo = x_o - x_e - (v_e - v_o)^2 / (2 a_l) (m), a_l =
    ``decel_max_mps2``, Lambda_eo = [-kappa~_eo(opp_epsilon_m), opp_lambdas_m...] (h in metres, lambda_1 in 1/s).
    The paper gives neither: a_l is the ego's braking limit, the level 1 m keeps a metre of stopping margin, and
    the linear kappa~ (m = 1) keeps the constraint well scaled when h_eo is tens of metres.
    """

    ellipse_a_m: float = math.sqrt(2.0) * 4.885
    """Longitudinal semi-axis of the safety ellipse h_ef. Valid: > 0. Paper: not given (beta_1)."""
    ellipse_b_m: float = math.sqrt(2.0) * 1.840
    """Lateral semi-axis of the safety ellipse. Valid: > 0. Paper: not given (beta_2)."""
    lambdas_m: tuple[float, ...] = (1.0, 0.5)
    """(lambda_1, ..., lambda_m) of kappa~(h) = sum lambda_i h^(2i-1). Valid: all > 0, 1-3 of them. Paper: order 2."""
    epsilon: float | None = 0.3
    """The level epsilon of the VL-CBF (lambda_0 = -kappa~(epsilon)); set this or lambda0. Valid: >= 0. Paper: 0.3."""
    lambda0: float | None = None
    """The level parameter lambda_0 directly; set this or epsilon. Valid: <= 0."""
    decel_max_mps2: float = 6.0
    """a_l of h_eo, the ego's assumed braking when meeting veh_o. Valid: > 0. Paper: not given."""
    opp_lambdas_m: tuple[float, ...] = (1.0,)
    """lambda_i of the ego's kappa~_eo on h_eo (h in metres, lambda_1 in 1/s). Valid: all > 0."""
    opp_epsilon_m: float = 1.0
    """Level of h_eo (metres of stopping margin). Valid: >= 0. Paper: not given."""

    @property
    def order_m(self) -> int:
        return len(self.lambdas_m)
