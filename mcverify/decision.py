"""Algorithm 1 (alg.framework) for the dual TO-CBF-MPC: which problem drives the ego this step.

Without opposing traffic the paper's loop iterates Q1 until it converges; when Q1 cannot be solved
(e.g. the front vehicle accelerates away, Theorem thm.one_in_two_feasibility) the ego abandons the
overtake for good and follows Q2 back behind the front vehicle. When neither problem has a
solution the controller falls back to braking towards its own lane, and the step is counted.
"""

from __future__ import annotations

from enum import IntEnum


class Mode(IntEnum):
    """What the ego is doing: overtaking (Q1 loop) or going back (Q2 loop)."""

    OVERTAKE = 0
    GO_BACK = 1


class Source(IntEnum):
    """Which plan the applied input came from in one control step."""

    Q1 = 1
    Q2 = 2
    FALLBACK = 3


def decide(mode: Mode, q1_ok: bool, q2_ok: bool) -> tuple[Mode, Source]:
    """Next mode and the source of this step's input (Algorithm 1, no opposing vehicle).

    - overtaking and Q1 solved: apply Q1;
    - overtaking, Q1 unsolvable, Q2 solved: break out of the Q1 loop (the overtake is abandoned
      for good) and apply Q2;
    - going back: apply Q2 while it solves;
    - otherwise: fall back (neither applicable problem solved).
    """
    if mode is Mode.OVERTAKE:
        if q1_ok:
            return Mode.OVERTAKE, Source.Q1
        if q2_ok:
            return Mode.GO_BACK, Source.Q2
        return Mode.OVERTAKE, Source.FALLBACK
    if q2_ok:
        return Mode.GO_BACK, Source.Q2
    return Mode.GO_BACK, Source.FALLBACK
