"""The recorded-solve benchmarks of issue 18, point 3 (mcverify.bench.kkt_factorisation and
mcverify.bench.warm_attempts) on a short recording: the numbers they report are consistent with the
recording and with each other."""

from __future__ import annotations

import pytest

from mcverify.bench import kkt_factorisation, warm_attempts
from mcverify.bench import recorded_ipm as R
from mcverify.campaign.spec import campaign_from_dict


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    raw = {"campaign": {"name": "rec", "seed": 3, "episodes": 1},
           "model": {"sim": {"max_time_s": 0.2}, "noise": {"kind": "paper"}}}
    rec = R.record_engine([campaign_from_dict(raw).cells[0]], 3, [0])
    path = tmp_path_factory.mktemp("rec") / "rec.pkl"
    R.save(rec, path)
    return str(path), rec


def test_lu_against_ldlt_on_a_recording(recording):
    path, rec = recording
    out = kkt_factorisation.compare([path], "ldlt_curvature", progress=lambda *a, **k: None)
    n = len(rec.solves)
    assert out["solves"] == n and out["recorded_statuses_reproduced"] == n  # the LU side is the engine
    assert 0 <= out["same_statuses"] <= n and out["both_converged"] <= n
    assert out["factorisations_lu"] > 0 and out["factorisations_variant"] > 0
    assert 0.0 < out["ratio_max"] <= 1e-10  # every accepted LDL^T solve passed the residual check
    assert out["cpu_lu_s"] > 0 and out["cpu_variant_s"] > 0
    assert out["cpu_ratio_lu_over_variant"] == pytest.approx(out["cpu_lu_s"] / out["cpu_variant_s"])
    assert out["same_success"] >= out["both_converged"]
    one = kkt_factorisation.one_side([path], "lu")  # the profiling mode replays the same attempts
    assert one["solves"] == n
    assert (one["iterations"], one["factorisations"]) == (out["iterations_lu"], out["factorisations_lu"])


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
