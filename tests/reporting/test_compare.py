"""mcverify.reporting.compare: paired (shared episode keys) or unpaired comparisons of two runs' cells."""

from __future__ import annotations

import json

import numpy as np
import pytest
import synthetic

from mcverify import cli
from mcverify.analysis import stats
from mcverify.errors import RunError
from mcverify.reporting import compare

BASE = {
    "campaign": {"name": "c", "seed": 11, "episodes": 40},
    "grid": {"barrier.epsilon": [0.1, 0.3]},
}


def _raw(*, seed=11, crn=False, grid=None, name="c"):
    return {"campaign": {"name": name, "seed": seed, "episodes": 40, "common_random_numbers": crn},
            "grid": grid or {"barrier.epsilon": [0.1, 0.3]}}


def _run(tmp_path, name, raw, unsafe=0.2, error=0.0):
    return synthetic.make_run(tmp_path / name, raw, trajectories=False,
                              probs=lambda c: {"unsafe": unsafe, "overtook": 0.6, "went_back": 0.3, "error": error})


def test_same_seed_and_cell_index_is_paired_mcnemar(tmp_path):
    a = compare.load_run(_run(tmp_path, "a", _raw(), unsafe=0.3))
    b = compare.load_run(_run(tmp_path, "b", _raw(), unsafe=0.1))
    res = compare.compare_runs(a, b)
    assert [c["cell_a"] for c in res["comparisons"]] == ["epsilon=0.1", "epsilon=0.3"]
    c = res["comparisons"][0]
    assert c["paired"] and c["pairs"] == 40 and "cell index 0" in c["reason"]
    # the paired test on the very episode pairs
    ta, tb = a.rows("epsilon=0.1"), b.rows("epsilon=0.1")
    expected = stats.compare_paired(np.array(ta.column("safe").to_pylist()), np.array(tb.column("safe").to_pylist()))
    r = c["rates"]["safe"]
    assert r["test"] == "mcnemar-exact" and r["p_value"] == expected["p_value"]
    assert (r["low"], r["high"], r["diff"]) == (expected["low"], expected["high"], expected["diff"])
    # the synthetic source shares its uniforms across runs with the same keys: B is never less safe
    assert r["only_a"] == 0 and r["only_b"] > 0
    assert c["values"]["min_dist_front_m"]["paired"]


def test_common_random_numbers_pair_across_cell_indices(tmp_path):
    a = compare.load_run(_run(tmp_path, "a", _raw(crn=True)))
    b = compare.load_run(_run(tmp_path, "b", _raw(crn=True, grid={"barrier.epsilon": [0.3, 0.1]})))
    c = compare.compare_runs(a, b)["comparisons"][0]  # epsilon=0.1 is cell 0 in A and cell 1 in B
    assert c["paired"] and "common random numbers" in c["reason"]


@pytest.mark.parametrize(
    "raw_b, why",
    [
        (_raw(seed=12), "different seeds (11 and 12)"),
        (_raw(crn=True), "one run uses common random numbers and the other does not"),
        (_raw(grid={"barrier.epsilon": [0.3, 0.1]}), "the cell indices differ (0 and 1)"),
    ],
)
def test_unpaired_cases_say_why(tmp_path, raw_b, why):
    a = compare.load_run(_run(tmp_path, "a", _raw()))
    b = compare.load_run(_run(tmp_path, "b", raw_b))
    res = compare.compare_runs(a, b)
    c = next(x for x in res["comparisons"] if x["cell_a"] == "epsilon=0.1")
    assert not c["paired"] and why in c["reason"]
    r = c["rates"]["safe"]
    assert r["test"] == "score"
    assert r["p_value"] == stats.compare_unpaired(r["k_a"], r["n_a"], r["k_b"], r["n_b"])["p_value"]
    assert "unpaired: score test" in compare.render_markdown(res)


def test_unmatched_cells_are_listed_and_pairs_can_be_given(tmp_path):
    a = compare.load_run(_run(tmp_path, "a", _raw()))
    b = compare.load_run(_run(tmp_path, "b", _raw(grid={"barrier.epsilon": [0.1, 0.5]})))
    res = compare.compare_runs(a, b)
    assert [c["cell_a"] for c in res["comparisons"]] == ["epsilon=0.1"]
    assert (res["only_in_a"], res["only_in_b"]) == (["epsilon=0.3"], ["epsilon=0.5"])
    md = compare.render_markdown(res)
    assert "**only in A, not compared**: epsilon=0.3" in md and "**only in B, not compared**: epsilon=0.5" in md
    # two cells of one run, with common random numbers: paired
    one = compare.load_run(_run(tmp_path, "one", _raw(crn=True)))
    res = compare.compare_runs(one, one, pairs=[("epsilon=0.1", "epsilon=0.3")])
    assert res["comparisons"][0]["paired"] and res["explicit_pairs"]
    assert "epsilon=0.1 vs epsilon=0.3" in compare.render_markdown(res)
    with pytest.raises(RunError, match="run B .* has no cell 'epsilon=0.7'"):
        compare.compare_runs(one, one, pairs=[("epsilon=0.1", "epsilon=0.7")])


def test_error_episodes_are_left_out_of_pairs(tmp_path):
    a = compare.load_run(_run(tmp_path, "a", _raw(), error=0.25))
    b = compare.load_run(_run(tmp_path, "b", _raw()))
    c = compare.compare_runs(a, b)["comparisons"][0]
    assert c["paired"] and c["errors"]["a"] > 0
    assert c["pairs"] == 40 - c["errors"]["a"]
    assert f"{c['errors']['a']} episode(s) ran in one cell only" in c["reason"]
    assert c["rates"]["safe"]["n"] == c["pairs"]


def test_cli_compare_prints_and_writes(tmp_path, capsys):
    a, b = _run(tmp_path, "a", _raw()), _run(tmp_path, "b", _raw(seed=5))
    assert cli.main(["compare", str(a), str(b), "--out", str(tmp_path / "cmp"), "--level", "0.9"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("# mcverify compare: a vs b") and "A − B [90% CI]" in out
    assert str(tmp_path) not in out
    data = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert data["level"] == 0.9 and not data["comparisons"][0]["paired"]
    assert r"\toprule" in (tmp_path / "cmp" / "compare.tex").read_text()
    assert (tmp_path / "cmp" / "compare.md").read_text().rstrip("\n") == out.rstrip("\n")


@pytest.mark.parametrize("extra, message", [
    (["--pair", "epsilon=0.1", "nope"], "has no cell 'nope'"),
    (["{missing}"], "run folder not found"),
])
def test_cli_compare_bad_input(tmp_path, capsys, extra, message):
    a = _run(tmp_path, "a", _raw())
    args = ["compare", str(a)]
    args += [str(a)] + extra if extra[0].startswith("--") else [e.format(missing=tmp_path / "x") for e in extra]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_cli_compare_with_no_matching_cell_is_one_line_exit_2(tmp_path, capsys):
    a = _run(tmp_path, "a", _raw())
    b = _run(tmp_path, "b", _raw(grid={"barrier.epsilon": [0.2, 0.4]}))
    assert cli.main(["compare", str(a), str(b)]) == 2
    captured = capsys.readouterr()
    lines = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("mcverify: error: no cell of ")
    assert "epsilon=0.1; epsilon=0.3" in lines[0] and "--pair CELL_A CELL_B" in lines[0]
    assert captured.out == ""


def test_the_model_fields_that_differ_are_listed(tmp_path):
    a = compare.load_run(_run(tmp_path, "a", _raw()))
    b = compare.load_run(_run(tmp_path, "b", {**_raw(), "model": {"noise": {"scale": 2.0}}}))
    res = compare.compare_runs(a, b)
    assert [c["model_differences"] for c in res["comparisons"]] == [[{"field": "noise.scale", "a": 1.0, "b": 2.0}]] * 2
    text = compare.render_markdown(res)
    assert "- **model**: 1 field(s) differ (`noise.scale`;" in text
    assert "### Model fields that differ" in text and "| noise.scale | 1 | 2 |" in text
    # two cells of one run: the grid field differs, per pair
    res = compare.compare_runs(a, a, pairs=[("epsilon=0.1", "epsilon=0.3"), ("epsilon=0.3", "epsilon=0.3")])
    assert res["comparisons"][0]["model_differences"][0] == {"field": "barrier.epsilon", "a": 0.1, "b": 0.3}
    assert res["comparisons"][1]["model_differences"] == []
    text = compare.render_markdown(res)
    assert "epsilon=0.3: none" in text and "epsilon=0.1 vs epsilon=0.3: " in text
    assert "- **model**: the same" not in text
    assert "- **model**: the same in every compared cell pair" in compare.render_markdown(compare.compare_runs(a, a))
