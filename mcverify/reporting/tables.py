"""Tables as data, rendered three ways: Markdown, LaTeX (booktabs) and HTML.

A :class:`Table` holds plain text cells (Unicode: ε, α_f, ≤, −, ...); each renderer escapes them
for its format, so one table definition gives the report's Markdown, the paper's LaTeX and the
HTML page, with identical numbers. The number formatters here (:func:`fmt_rate`, :func:`fmt_num`,
...) are the only place the reports turn numbers into text, so every table rounds the same way.
"""

from __future__ import annotations

import html
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Section:
    """A row that spans the table and starts a block (e.g. "Scenario A" of the paper's Table IV)."""

    title: str


@dataclass(frozen=True)
class Table:
    """``key``: file stem and LaTeX label (``tab:<key>``); ``title``: caption; ``columns``: header
    texts; ``rows``: lists of cell texts (one per column) or :class:`Section` rows; ``notes``:
    sentences printed under the table."""

    key: str
    title: str
    columns: Sequence[str]
    rows: Sequence[Sequence[str] | Section]
    notes: Sequence[str] = field(default_factory=tuple)
    #: One of "l"/"r" per column; default: the first column left, the others right (numbers).
    align: str = ""

    def __post_init__(self) -> None:
        if self.align and (len(self.align) != len(self.columns) or set(self.align) - {"l", "r"}):
            raise ValueError(f"table {self.key!r}: align {self.align!r} must give l or r for each column")
        for row in self.rows:
            if not isinstance(row, Section) and len(row) != len(self.columns):
                raise ValueError(f"table {self.key!r}: row {list(row)!r} has {len(row)} cells, "
                                 f"expected {len(self.columns)}")


# ------------------------------------------------------------------------------------ formatting

DASH = "–"  # what a missing value prints as


def is_missing(x: Any) -> bool:
    return x is None or (isinstance(x, float) and not math.isfinite(x))


def fmt_num(x: Any, digits: int = 2, *, signed: bool = False) -> str:
    """``x`` with ``digits`` decimals (``signed``: always a sign), or :data:`DASH`.

    A non-zero value that would round to zero keeps its sign and two significant digits
    (-0.000228 is "-0.00023", not "+0.000": a robustness just below zero is a violation)."""
    if is_missing(x):
        return DASH
    v = float(x)
    if v == 0.0:
        v = 0.0  # no "-0.00"
    elif round(v, digits) == 0.0:
        text = f"{v:.2g}" if "e" not in f"{v:.2g}" else f"{v:.1e}"
        return text if v < 0 or not signed else "+" + text
    return f"{v:+.{digits}f}" if signed else f"{v:.{digits}f}"


def fmt_p(x: Any) -> str:
    """A probability: 3 decimals, but 2 significant digits below 0.01 (so a bound of 0.001 from
    3,000 episodes does not print as 0.001 rounded from 0.000998) and 4 decimals above 0.99."""
    if is_missing(x):
        return DASH
    x = float(x)
    if x in (0.0, 1.0):
        return f"{x:.0f}"
    if x < 0.01:
        return f"{x:.2g}"
    if x > 0.99:
        return f"{x:.4f}"
    return f"{x:.3f}"


def method_name(method: str) -> str:
    """How a rate interval method is named in rendered text."""
    return {"clopper-pearson": "exact Clopper-Pearson", "wilson": "Wilson score",
            "confidence-sequence": "anytime-valid (beta-binomial confidence sequence)"}.get(method, method)


def bound_name(method: str) -> str:
    """How the bound that ``0/n (≤ u)`` and ``n/n (≥ l)`` show is named: the exact one-sided bound of a
    fixed-count run, or, for an estimate's anytime-valid interval, that interval's own end."""
    if method == "confidence-sequence":
        return "the anytime-valid interval's end as a one-sided"
    return "the exact one-sided"


def fmt_rate(r: Mapping[str, Any] | None) -> str:
    """A rate as ``k/n [low, high]``; with no event ``0/n (≤ u)`` and with only events ``n/n (≥ l)``,
    u and l the one-sided bounds at the same level (:func:`bound_name`); :data:`DASH` for an empty cell."""
    if not r or not r.get("n"):
        return DASH
    k, n = r["k"], r["n"]
    if k == 0:
        return f"0/{n} (≤ {fmt_p(r['upper_one_sided'])})"
    if k == n:
        return f"{n}/{n} (≥ {fmt_p(r['lower_one_sided'])})"
    return f"{k}/{n} [{fmt_p(r['low'])}, {fmt_p(r['high'])}]"


def fmt_mean_ci(v: Mapping[str, Any] | None, digits: int = 2) -> str:
    """``mean [low, high]`` of a value summary (bootstrap interval), or :data:`DASH`."""
    if not v or is_missing(v.get("mean")):
        return DASH
    if is_missing(v.get("mean_low")):
        return fmt_num(v["mean"], digits)
    return f"{fmt_num(v['mean'], digits)} [{fmt_num(v['mean_low'], digits)}, {fmt_num(v['mean_high'], digits)}]"


def fmt_rel(ours: Any, ref: Any) -> str:
    """Relative gap (ours − ref)/|ref| as a signed percentage, or :data:`DASH`."""
    if is_missing(ours) or is_missing(ref) or float(ref) == 0.0:
        return DASH
    return f"{(float(ours) - float(ref)) / abs(float(ref)):+.0%}"


# -------------------------------------------------------------------------------------- Markdown


#: What an empty table shows when it has no notes of its own.
NO_ROWS = "Nothing to list."


def to_markdown(t: Table, *, heading: str = "###") -> str:
    """GitHub-flavoured Markdown: a heading with the title, the table, the notes as a list."""
    esc = _md_escape
    lines = [f"{heading} {t.title}", ""] if heading else []
    if not t.rows:  # a header over nothing reads like a rendering fault: say so in words
        return "\n".join(lines + [f"- {n}" for n in t.notes or [NO_ROWS]])
    lines.append("| " + " | ".join(esc(c) for c in t.columns) + " |")
    lines.append("|" + "|".join(":---" if a == "l" else "---:" for a in _align(t)) + "|")
    for row in t.rows:
        if isinstance(row, Section):
            cells = [f"**{esc(row.title)}**"] + [""] * (len(t.columns) - 1)
        else:
            cells = [esc(c) for c in row]
        lines.append("| " + " | ".join(cells) + " |")
    if t.notes:
        lines.append("")
        lines.extend(f"- {n}" for n in t.notes)
    return "\n".join(lines)


def _align(t: Table) -> str:
    return t.align or "l" + "r" * (len(t.columns) - 1)


def _md_escape(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


# ----------------------------------------------------------------------------------------- LaTeX

#: Unicode characters the reports use, as LaTeX math (merged with neighbouring math).
_LATEX_MATH = {
    "ε": r"\varepsilon", "α": r"\alpha", "β": r"\beta", "λ": r"\lambda", "φ": r"\varphi",
    "κ": r"\kappa", "Δ": r"\Delta", "≤": r"\le", "≥": r"\ge", "∈": r"\in", "−": "-",
    "×": r"\times", "±": r"\pm", "·": r"\cdot", "₀": "_0", "₁": "_1", "₂": "_2", "²": "^2",
    "∞": r"\infty", "→": r"\to", "<": "<", ">": ">", "≈": r"\approx",
}
#: Characters that need a text-mode escape.
_LATEX_TEXT = {
    "\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
    "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}", "|": r"\textbar{}",
    "–": "--", "—": "---", "…": r"\ldots{}", "\n": " ",
}


def latex_escape(text: str) -> str:
    """Plain text to LaTeX: specials escaped, Greek letters and relations as inline math (one
    ``$...$`` per run of them, so ``λ₀`` becomes ``$\\lambda_0$``)."""
    parts: list[tuple[bool, str]] = []
    for ch in str(text):
        if ch in _LATEX_MATH:
            piece, math_mode = _LATEX_MATH[ch], True
        else:
            piece, math_mode = _LATEX_TEXT.get(ch, ch), False
        if parts and parts[-1][0] == math_mode:
            parts[-1] = (math_mode, parts[-1][1] + piece)
        else:
            parts.append((math_mode, piece))
    out = "".join(f"${p}$" if m else p for m, p in parts)
    # a hyphen that starts a number is a minus sign (not a word's hyphen, as in "VL-CBF")
    return re.sub(r"(?<![\w.$])-(?=\d)", "$-$", out)


def to_latex(t: Table) -> str:
    """A ``table`` float with a booktabs ``tabular`` (needs ``\\usepackage{booktabs}``)."""
    ncol = len(t.columns)
    spec = _align(t)
    out = [
        f"% {latex_escape(t.title)} -- generated by mcverify report; needs \\usepackage{{booktabs}}",
        r"\begin{table}[htbp]",
        r"  \centering",
        f"  \\caption{{{latex_escape(t.title)}}}",
        f"  \\label{{tab:{t.key}}}",
        r"  \small",
        f"  \\begin{{tabular}}{{{spec}}}",
        r"    \toprule",
        "    " + " & ".join(_latex_cell(c) for c in t.columns) + r" \\",
        r"    \midrule",
    ]
    for i, row in enumerate(t.rows):
        if isinstance(row, Section):
            if i > 0:
                out.append(r"    \midrule")
            out.append(f"    \\multicolumn{{{ncol}}}{{l}}{{\\emph{{{latex_escape(row.title)}}}}} \\\\")
        else:
            out.append("    " + " & ".join(_latex_cell(c) for c in row) + r" \\")
    out += [r"    \bottomrule", r"  \end{tabular}"]
    if t.notes:
        out.append(r"  \par\smallskip")
        out.append("  {\\footnotesize " + " ".join(latex_escape(n) for n in t.notes) + "}")
    out.append(r"\end{table}")
    return "\n".join(out)


def _latex_cell(text: str) -> str:
    cell = latex_escape(text)
    # "\\" followed by "[" would read the bracket as the row-spacing argument of "\\"
    return "{}" + cell if cell.startswith("[") else cell


# ------------------------------------------------------------------------------------------ HTML


#: Counts that mean unsafe episodes when k > 0 (by column name, or by a pivot table's key).
_UNSAFE_EVENTS = ("collision", "ellipse violated", "ellipse_violation")
_COUNT = re.compile(r"^\s*(\d+)/(\d+)")


def unsafe_count(table_key: str, column: str, text: str) -> bool:
    """Whether a ``k/n`` cell counts unsafe episodes (the report highlights it): a safe count
    below n, or a collision / ellipse-violation count above 0."""
    m = _COUNT.match(str(text))
    if m is None:
        return False
    k, n = int(m.group(1)), int(m.group(2))
    pivot = table_key[len("pivot-"):] if table_key.startswith("pivot-") else None
    if column == "safe" or pivot == "safe":
        return k < n
    return k > 0 and (column.startswith(_UNSAFE_EVENTS) or (pivot is not None and pivot.startswith(_UNSAFE_EVENTS)))


#: Tables with more columns than this get a smaller type in HTML (class "wide"), to fit 1400 px.
WIDE_COLUMNS = 12
_NAME_JOINT = re.compile(r"([._/](?=[A-Za-z])|=(?=[A-Za-z0-9-]))")


def _breakable(text: str) -> str:
    """Text that may wrap inside long names (``opposing.spawn_gap_m``, ``Infeasible_Problem_Detected``),
    paths (``run/generations/g000``) and settings (``candidate=c02``): a ``<wbr>`` after each ``.``,
    ``_`` or ``/`` followed by a letter, and after each ``=`` (never inside a number such as 0.3, or a count
    such as 8/8)."""
    return _NAME_JOINT.sub(r"\1<wbr>", text)


def inline_html(text: str) -> str:
    """``text`` escaped for HTML, with Markdown's inline code (```x```) as ``<code>x</code>``."""
    parts = html.escape(text).split("`")
    if len(parts) % 2 == 0:  # an unpaired backtick: leave the text as written
        return html.escape(text)
    return "".join(f"<code>{p}</code>" if k % 2 else p for k, p in enumerate(parts))


def to_html(t: Table) -> str:
    """An HTML ``<table>`` with a caption and the notes in a following paragraph."""
    esc = html.escape
    if not t.rows:
        notes = "".join(f"<li>{inline_html(n)}</li>" for n in t.notes or [NO_ROWS])
        return f'<p class="table-title" id="tab-{esc(t.key)}">{esc(t.title)}</p>\n<ul class="notes">{notes}</ul>'
    wide = ' class="wide"' if len(t.columns) > WIDE_COLUMNS else ""
    out = [f'<table id="tab-{esc(t.key)}"{wide}>', f"<caption>{esc(t.title)}</caption>", "<thead><tr>"]
    out.append("".join(f"<th>{_breakable(esc(c))}</th>" for c in t.columns) + "</tr></thead>")
    out.append("<tbody>")
    for row in t.rows:
        if isinstance(row, Section):
            out.append(f'<tr class="section"><th colspan="{len(t.columns)}">{esc(row.title)}</th></tr>')
        else:
            flags = [unsafe_count(t.key, col, c) for col, c in zip(t.columns[1:], row[1:], strict=False)]
            head = (f'<th scope="row" class="unsafe">⚠ {esc(row[0])}</th>' if any(flags)
                    else f'<th scope="row">{esc(row[0])}</th>')
            cells = [head] + [
                f'<td class="unsafe">{esc(c)}</td>' if bad else f"<td>{_breakable(esc(c))}</td>"
                for bad, c in zip(flags, row[1:], strict=False)
            ]
            out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</tbody></table>")
    if t.notes:
        out.append('<ul class="notes">' + "".join(f"<li>{inline_html(n)}</li>" for n in t.notes) + "</ul>")
    return "\n".join(out)
