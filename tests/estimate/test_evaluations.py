"""The kept evaluations of an importance-sampling cell: exact round trip, inputs checked, a torn
last line (a kill mid-append) cut off."""

from __future__ import annotations

import math

from mcverify.estimate.evaluations import EvaluationCache, cache_file


def test_rows_come_back_exactly_only_for_the_same_inputs(tmp_path):
    path = cache_file(tmp_path, 3)
    assert path.name == "evaluated_cell003.jsonl"
    rows = [{"cell_episode": 8, "min_h_front": 0.1 + 0.2, "steps": 83, "outcome": "overtake", "collision_front": False,
             "switched_to_q2_at_s": math.nan, "noise_tilt_sums": [1e-300, -0.0], "unit_cpu_s": 0.5},
            {"cell_episode": 9, "min_h_front": -math.inf, "steps": 1, "outcome": "error", "collision_front": None,
             "switched_to_q2_at_s": 2.3, "noise_tilt_sums": None, "unit_cpu_s": 0.5}]
    values = {8: (1.25, 2.0), 9: (1.0 / 3.0, 7.0)}
    tilt = {"theta": (0.0, 4.0), "gap_max_m": 4.1}
    EvaluationCache(path).add(rows, values, tilt)
    again = EvaluationCache(path)
    assert len(again) == 2
    got = again.rows([8, 9], values, tilt)
    assert repr(got) == repr(rows)  # repr: NaN compares unequal to itself
    assert again.rows([8, 9], {**values, 9: (1.0 / 3.0, 7.000000000000001)}, tilt) is None
    assert again.rows([8, 9], values, None) is None  # another noise tilt
    assert again.rows([8, 9, 10], {**values, 10: (0.0, 0.0)}, tilt) is None  # 10 was never evaluated


def test_a_line_cut_short_by_a_kill_is_cut_off(tmp_path):
    path = cache_file(tmp_path, 0)
    EvaluationCache(path).add([{"cell_episode": 0, "x": 1.5}], {0: (0.5,)}, None)
    with open(path, "a") as fh:
        fh.write('{"episode": 1, "values": [0.7], "tilt": null, "ro')
    kept = EvaluationCache(path)
    assert len(kept) == 1 and kept.rows([0], {0: (0.5,)}, None) == [{"cell_episode": 0, "x": 1.5}]
    kept.add([{"cell_episode": 1, "x": 2.5}], {1: (0.7,)}, None)  # starts a line of its own
    assert EvaluationCache(path).rows([0, 1], {0: (0.5,), 1: (0.7,)}, None) == [{"cell_episode": 0, "x": 1.5},
                                                                               {"cell_episode": 1, "x": 2.5}]
    kept.remove()
    assert not path.exists()


def test_a_damaged_line_inside_the_file_is_one_clear_error(tmp_path):
    import pytest  # noqa: PLC0415

    from mcverify.errors import RunError  # noqa: PLC0415

    path = cache_file(tmp_path, 0)
    EvaluationCache(path).add([{"cell_episode": 0, "x": 1.5}], {0: (0.5,)}, None)
    path.write_text("{oops\n" + path.read_text())
    with pytest.raises(RunError, match=r"evaluated_cell000.jsonl line 1 is damaged .*delete the file"):
        EvaluationCache(path)
    path.write_text('{"episode": 0, "values": [0.5], "tilt": null}\n')  # no row
    with pytest.raises(RunError, match="line 1 is damaged"):
        EvaluationCache(path)
