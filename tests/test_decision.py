"""Algorithm 1 without opposing traffic: every branch."""

import pytest

from mcverify.decision import Mode, Source, decide


@pytest.mark.parametrize(
    "mode, q1_ok, q2_ok, expected",
    [
        (Mode.OVERTAKE, True, True, (Mode.OVERTAKE, Source.Q1)),
        (Mode.OVERTAKE, True, False, (Mode.OVERTAKE, Source.Q1)),
        (Mode.OVERTAKE, False, True, (Mode.GO_BACK, Source.Q2)),  # Q1 infeasible: break to the Q2 loop
        (Mode.OVERTAKE, False, False, (Mode.OVERTAKE, Source.FALLBACK)),
        (Mode.GO_BACK, True, True, (Mode.GO_BACK, Source.Q2)),  # an abandoned overtake is never resumed
        (Mode.GO_BACK, False, True, (Mode.GO_BACK, Source.Q2)),
        (Mode.GO_BACK, True, False, (Mode.GO_BACK, Source.FALLBACK)),
    ],
)
def test_decide(mode, q1_ok, q2_ok, expected):
    assert decide(mode, q1_ok, q2_ok) == expected
