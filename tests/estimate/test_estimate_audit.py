"""The target event an estimate folder's audit compares (mcverify.estimate.audit); the audit itself runs
end to end in test_cli_importance.py (and, slow, test_subset_run.py)."""

import pytest

from mcverify.estimate.audit import target_event


@pytest.mark.parametrize(("row", "target", "event"), [
    ({"collision_front": False, "collision_opp": True}, "collision", True),
    ({"collision_front": False, "collision_opp": False}, "collision", False),
    ({"collision_front": False}, "collision", False),  # a missing flag reads as no event
    ({"ellipse_violation": True}, "ellipse", True),
    ({"safe": False}, "unsafe", True),
    ({"safe": True}, "unsafe", False),
    ({}, "unsafe", False),  # a row without the flag shows no event
    ({"invariance_breach": True}, "invariance", True),
])
def test_the_target_event_of_a_row(row, target, event):
    assert target_event(row, target) is event
