"""The infeasibility-policy benchmark's report (mcverify.bench.infeasibility): figures from the runs
and the replay land in one generated section of BENCHMARKS.md, replaced on the next run."""

from __future__ import annotations

from mcverify import store
from mcverify.bench import infeasibility as inf
from mcverify.bench.agreement import agreement
from mcverify.bench.engine import PAIRED_VALUES, SideResult
from mcverify.bench.solve_classes import SolveClass


def _row(e, safe=True, outcome="overtook", audits=0, disagreements=0):
    return {"episode_id": e, "cell": "c", "safe": safe, "outcome": outcome, "min_dist_front_m": 1.0,
            "min_gap_opp_m": 5.0, "overtake_time_s": 6.0, "infeasibility_audits": audits,
            "infeasibility_audit_disagreements": disagreements}


def _side(name, rows, cpu):
    s = SideResult(name, rows, cpu, cpu)
    s.classes.add(SolveClass.CONVERGED, cpu / 2)
    s.classes.add(SolveClass.CERTIFIED_INFEASIBLE, cpu / 2)
    return s


def test_section_holds_both_measurements_and_is_replaced(tmp_path):
    ref, new = [_row(0), _row(1)], [_row(0, audits=2, disagreements=1), _row(1, safe=False, outcome="went_back")]
    paired = {"variant": "phase1", "runs": {"default": _side("engine", ref, 10.0), "phase1": _side("engine", new, 4.0)},
              "agreement": agreement(ref, new, key="episode_id", values=PAIRED_VALUES),
              "per_cell": {"c": {"paired": 2, "safe_agree": 1, "outcome_agree": 1}},
              "audits": {"infeasibility_audits": 2, "infeasibility_audit_disagreements": 1}}
    replay = {"solves": 100, "cpu_s": 3.0, "phase1_ms": {"certified": 65.0},
              "table": {"certified": {"solves": 5, "infeasible": 2, "feasible": 1, "undecided": 2,
                                      "warm_only_infeasible": 0, "resto_converged": 1, "warm_started": 4,
                                      "central_converged": 3}}}
    text = inf.markdown(paired, replay, "python -m mcverify.bench.infeasibility --episodes 1")
    begin, end = inf.marks("phase1")
    assert text.startswith(begin) and text.rstrip().endswith(end) and begin != inf.marks("replay")[0]
    assert "| default | 2 | 5.00 | 2.50 (0.5) |" in text and "| phase1 | 2 | 2.00 |" in text
    assert "safety verdicts 1/2" in text and "Audits by IPOPT: 2, disagreements 1" in text
    assert "- differs: c episode 1: safe True -> False, outcome overtook -> went_back" in text
    assert "| certified | 5 | 2 | 1 | 2 | 0 | 1 | 3 (4) | 65 |" in text
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("# Benchmarks\n\nkept\n")
    store.replace_section(path, text, begin, end)
    store.replace_section(path, inf.markdown(paired, None, "again"), begin, end)
    store.replace_section(path, inf.markdown(None, replay, "replayed"), *inf.marks("replay"))
    out = path.read_text()
    assert out.count(begin) == 1 and "kept" in out and "`again`" in out and "`replayed`" in out
    assert out.count("| certified | 5 |") == 1  # the first write's replay table was replaced


def test_the_cells_can_be_drawn_with_another_campaign_seed():
    """``--seed``: the same cells with the campaign seed replaced (episodes a recording has not seen)."""
    from mcverify.bench.engine import DEFAULT_CAMPAIGN, pick_cells

    cells, seed, _ = pick_cells(DEFAULT_CAMPAIGN, "all", None)
    other, other_seed, _ = pick_cells(DEFAULT_CAMPAIGN, "all", None, overrides={"mpc.ipm_central_attempt": "mpcdc"},
                                      seed=seed + 1)
    assert other_seed == seed + 1 and [c.name for c in other] == [c.name for c in cells]
    assert all(c.params.mpc.ipm_central_attempt == "mpcdc" for c in other)
    assert "central_mpcdc" in inf.VARIANTS and inf.VARIANTS["central_all"] == {"mpc.ipm_central_attempt": "all"}


def test_a_variant_paired_with_another_variant_gets_its_own_section():
    """``--base``: the central attempt for every controller measured on top of MPC-DC's only, not against
    the defaults."""
    ref, new = [_row(0)], [_row(0)]
    paired = {"variant": "central_all", "base": "central_mpcdc",
              "runs": {"central_mpcdc": _side("engine", ref, 10.0), "central_all": _side("engine", new, 4.0)},
              "agreement": agreement(ref, new, key="episode_id", values=PAIRED_VALUES),
              "per_cell": {"c": {"paired": 1, "safe_agree": 1, "outcome_agree": 1}},
              "audits": {"infeasibility_audits": 0, "infeasibility_audit_disagreements": 0}}
    text = inf.markdown(paired, None, "cmd")
    assert inf.section_key(paired) == "central_all over central_mpcdc"
    assert text.startswith(inf.marks("central_all over central_mpcdc")[0])
    assert "central_all against central_mpcdc" in text and "| central_mpcdc | 1 | 10.00 |" in text
    assert inf.section_key({"variant": "phase1"}) == "phase1"


def test_a_variant_cannot_be_its_own_base():
    import pytest

    with pytest.raises(ValueError, match="both"):
        inf.compare_policies("x.toml", "all", 1, "central_all", base="central_all")
