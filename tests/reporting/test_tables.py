"""mcverify.reporting.tables: number formats and the Markdown / LaTeX / HTML renderers."""

from __future__ import annotations

import math
import re

import pytest

from mcverify.analysis import stats
from mcverify.reporting.tables import (
    Section,
    Table,
    fmt_mean_ci,
    fmt_num,
    fmt_p,
    fmt_rate,
    fmt_rel,
    inline_html,
    latex_escape,
    to_html,
    to_latex,
    to_markdown,
)


def test_number_formats():
    assert fmt_num(1.234) == "1.23" and fmt_num(-0.0) == "0.00" and fmt_num(math.nan) == "–"
    # near zero: the sign and two significant digits, never "+0.000" for a negative value
    assert fmt_num(-0.000228, 3, signed=True) == "-0.00023" and fmt_num(0.000228, 3, signed=True) == "+0.00023"
    assert fmt_num(-0.001) == "-0.001" and fmt_num(3e-9, 2) == "3.0e-09"
    assert fmt_num(0.5, signed=True) == "+0.50" and fmt_num(None) == "–"
    assert fmt_p(0.0) == "0" and fmt_p(1.0) == "1" and fmt_p(0.0950) == "0.095"
    assert fmt_p(0.000998) == "0.001" and fmt_p(0.00049) == "0.00049"  # small bounds keep two digits
    assert fmt_p(0.99871) == "0.9987"
    assert fmt_rel(5.0, 4.0) == "+25%" and fmt_rel(1.0, 0.0) == "–"
    assert fmt_mean_ci({"mean": 1.0, "mean_low": 0.9, "mean_high": 1.2}) == "1.00 [0.90, 1.20]"
    assert fmt_mean_ci({"mean": 1.0, "mean_low": math.nan, "mean_high": math.nan}) == "1.00"


def test_rate_formats_use_one_sided_bounds_at_the_edges():
    assert fmt_rate(stats.rate_summary(0, 30)) == "0/30 (≤ 0.095)"
    assert fmt_rate(stats.rate_summary(30, 30)) == "30/30 (≥ 0.905)"
    assert fmt_rate(stats.rate_summary(3, 30)) == "3/30 [0.021, 0.265]"
    assert fmt_rate(stats.rate_summary(0, 0)) == "–" and fmt_rate(None) == "–"


def _table() -> Table:
    return Table(
        "demo", "Rates per λ₀ & α_f (50%)",
        ["cell", "safe", "min h_ef"],
        [Section("Scenario A"), ["ε = 0.3 | x", "[0.1, 0.2]", "−0.5"], ["a_b#c", "3/30", "≤ 0.1"]],
        ["note with $ and ~"],
    )


def test_rows_must_match_the_header():
    with pytest.raises(ValueError, match="has 2 cells, expected 3"):
        Table("bad", "t", ["a", "b", "c"], [["1", "2"]])
    with pytest.raises(ValueError, match="align"):
        Table("bad", "t", ["a", "b"], [["1", "2"]], align="lx")


def test_markdown():
    md = to_markdown(_table())
    lines = md.splitlines()
    assert lines[0] == "### Rates per λ₀ & α_f (50%)"
    assert lines[2] == "| cell | safe | min h_ef |" and lines[3] == "|:---|---:|---:|"
    assert "| ε = 0.3 \\| x | [0.1, 0.2] | −0.5 |" in lines  # a pipe in a cell is escaped
    assert "| **Scenario A** |  |  |" in lines
    assert lines[-1] == "- note with $ and ~"
    assert all(line.count("|") - line.count("\\|") == 4 for line in lines[2:-2] if line.startswith("|"))


def test_latex_escape():
    assert latex_escape("λ₀ = −0.31") == r"$\lambda_0$ = $-$0.31"
    assert latex_escape("α_f ∈ (1,3]") == r"$\alpha$\_f $\in$ (1,3]"
    assert latex_escape("50% & #1 $x ~ {y}") == r"50\% \& \#1 \$x \textasciitilde{} \{y\}"
    assert latex_escape("≤ 0.095") == r"$\le$ 0.095"
    assert latex_escape("–") == "--"
    assert latex_escape("VL-CBF -0.15 (-67%) [-0.1, +0.2] x-1") == r"VL-CBF $-$0.15 ($-$67\%) [$-$0.1, +0.2] x-1"
    assert latex_escape("≤ε") == r"$\le\varepsilon$"  # one math run


def test_latex_booktabs_structure():
    tex = to_latex(_table())
    assert tex.count(r"\begin{table}") == tex.count(r"\end{table}") == 1
    assert r"\begin{tabular}{lrr}" in tex and r"\label{tab:demo}" in tex
    assert tex.index(r"\toprule") < tex.index(r"\midrule") < tex.index(r"\bottomrule")
    assert r"\multicolumn{3}{l}{\emph{Scenario A}} \\" in tex
    body = tex[tex.index(r"\midrule"):tex.index(r"\bottomrule")]
    for line in body.splitlines():
        line = line.strip()
        if line.endswith(r"\\") and "multicolumn" not in line:
            assert len(re.findall(r"(?<!\\)&", line)) == 2, line  # three columns
    assert r"\\ [" not in tex and "{}[0.1, 0.2]" in tex  # a leading [ would be read as \\[...]
    depth = 0
    for ch in re.sub(r"\\[{}]", "", tex):
        depth += {"{": 1, "}": -1}.get(ch, 0)
        assert depth >= 0
    assert depth == 0
    assert tex.count("$") % 2 == 0 or r"\$" in tex


def test_html_escapes_and_marks_sections():
    h = to_html(_table())
    assert '<table id="tab-demo">' in h and "<caption>Rates per λ₀ &amp; α_f (50%)</caption>" in h
    assert '<tr class="section"><th colspan="3">Scenario A</th></tr>' in h
    assert "<td>[0.1, 0.2]</td>" in h and '<th scope="row">ε = 0.3 | x</th>' in h
    # a row with an unsafe count (safe 3/30 < 30) is marked, its count highlighted
    assert '<th scope="row" class="unsafe">⚠ a_b#c</th><td class="unsafe">3/30</td>' in h
    assert "<li>note with $ and ~</li>" in h
    # long names may wrap after . and _ (not inside numbers)
    t = Table("w", "t", ["a", "opposing.spawn_gap_m"], [["x", "fallback:Solve_Succeeded 0.3"]])
    h = to_html(t)
    assert "<th>opposing.<wbr>spawn_<wbr>gap_<wbr>m</th>" in h and "<td>fallback:Solve_<wbr>Succeeded 0.3</td>" in h
    # paths and settings wrap at / and = (a replay command, a cell), never inside a count or a number
    rows = [["2", "candidate=c02", "mcverify replay run/generations/g000 2"], ["3", "x=-0.25", "8/8 (≥ 0.688)"]]
    t = Table("w", "t", ["episode", "cell", "replay"], rows)
    h = to_html(t)
    assert "candidate=<wbr>c02" in h and "mcverify replay run/<wbr>generations/<wbr>g000 2" in h
    assert "x=<wbr>-0.25" in h and "<td>8/8 (≥ 0.688)</td>" in h


def test_inline_code_becomes_code_elements_and_the_rest_is_escaped():
    assert inline_html("replay: `mcverify replay <run> 3` & more") == (
        "replay: <code>mcverify replay &lt;run&gt; 3</code> &amp; more")
    assert inline_html("an unpaired ` stays") == "an unpaired ` stays"
    assert inline_html("") == ""


def test_an_empty_table_says_so_instead_of_drawing_a_header():
    empty = Table("cx", "Counterexamples (safe)", ["episode", "robustness"], [],
                  ["No episode violated the requirement."])
    md, h = to_markdown(empty), to_html(empty)
    assert "| episode" not in md and md.endswith("- No episode violated the requirement.")
    assert "<table" not in h and '<p class="table-title" id="tab-cx">Counterexamples (safe)</p>' in h
    assert "<li>No episode violated the requirement.</li>" in h
    assert "Nothing to list." in to_markdown(Table("t", "T", ["a"], [], []))
