"""The recorded-solve benchmark of issue 18, point 3 (mcverify.bench.warm_attempts) on a short recording: the
numbers it reports are consistent with the recording."""

from __future__ import annotations

import pytest

from mcverify.bench import recorded_ipm as R
from mcverify.bench import warm_attempts
from mcverify.campaign.spec import campaign_from_dict


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    raw = {"campaign": {"name": "rec", "seed": 3, "episodes": 1},
           "model": {"sim": {"max_time_s": 0.2}, "noise": {"kind": "paper"}}}
    rec = R.record_engine([campaign_from_dict(raw).cells[0]], 3, [0])
    path = tmp_path_factory.mktemp("rec") / "rec.pkl"
    R.save(rec, path)
    return str(path), rec


def test_warm_attempt_report_counts_the_recording(recording):
    path, rec = recording
    rules = warm_attempts.skip_rules([path])
    warm = [s for s in rec.solves if s.warm is not None]
    assert rules["warm_started"] == len(warm) == sum(rules["warm1_status"].values())
    assert rules["warm1_failed"] == sum(not s.attempts[0].endswith(":Converged") for s in warm)
    for rule in ("prev_cold", "prev_not_warm1"):
        fires = rules["rules"].get(f"{rule}:fires", 0)
        assert fires == rules["rules"].get(f"{rule}:saves", 0) + rules["rules"].get(f"{rule}:would_change", 0)
    costs = warm_attempts.attempt_costs([path])
    assert sum(v for k, v in costs["count"].items() if k.startswith("attempt1:")) == len(warm)
    assert costs["count"].get("attempt1:ok", 0) == len(warm) - rules["warm1_failed"]
    assert sum(costs["cpu_share"].values()) == pytest.approx(1.0)
