"""benchmarks.confirmation: which episodes it re-simulates, the per-cell table it builds from the stored
rows and the re-simulated ones, the reference audits set beside them, and its one-line mistakes."""

from __future__ import annotations

from benchmarks import confirmation


def _row(e: int, cell: int, back: str = "", collided: bool = False) -> dict:
    return {"episode_id": e, "cell_index": cell, "went_back_q1_failure": back, "outcome": "went_back" if back else
            "overtook", "safe": not collided, "collision_front": collided, "collision_opp": False}


STORED = [_row(0, 0), _row(1, 0, "presumed_infeasible", collided=True), _row(2, 0, "certified_infeasible"),
          _row(3, 1), _row(4, 1, "presumed_infeasible")]
AFTER = {1: {**_row(1, 0), "q1_confirm_solves": 2, "min_h_front": 0.3},
         4: {**_row(4, 1, "certified_infeasible", collided=True), "q1_confirm_solves": 1, "min_h_front": -0.1}}


def test_only_turn_backs_on_a_presumed_verdict_are_re_simulated():
    assert confirmation.targets(STORED) == [1, 4]
    assert confirmation.spread([5, 6, 7, 8, 9, 10], 2) == [5, 8] and confirmation.spread([5], 0) == []


def test_the_table_counts_before_and_after_per_cell():
    rows = confirmation.cell_rows(STORED, AFTER, ["a", "b"])
    # cell a: 3 episodes, 1 re-simulated, it overtakes now, 2 confirmations, collisions 1 -> 0
    assert rows[0] == ["a", "3", "1", "1", "0", "2", "1/3 = 0.33 [0.0084, 0.91]", "0/3 (≤ 0.63)", "0/3 (≤ 0.63)"]
    # cell b: the re-simulated episode still turns back (on a full verdict) and now collides
    assert rows[1][:6] == ["b", "2", "1", "0", "1", "1"] and rows[1][6].startswith("0/2")
    assert rows[1][7].startswith("1/2") and rows[1][8].startswith("1/2")


def test_audits_are_set_beside_the_re_simulated_episodes():
    audits = {"1": {"outcome": "went_back", "safe": False, "reference_outcome": "overtook", "reference_safe": True},
              "4": {"outcome": "went_back", "safe": True, "reference_outcome": "went_back", "reference_safe": True},
              "9": {"outcome": "went_back", "safe": False, "reference_outcome": "overtook", "reference_safe": True}}
    lines = confirmation.audit_lines(audits, AFTER)
    assert len(lines) == 2  # episode 9 was not re-simulated
    assert lines[0].startswith("episode 1:") and lines[0].endswith("agrees with the reference")
    assert lines[1].endswith("differs from the reference")


def test_mistakes_are_one_line(tmp_path, capsys):
    assert confirmation.main([str(tmp_path / "nowhere")]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "run folder not found" in err[0]
