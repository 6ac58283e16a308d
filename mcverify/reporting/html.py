"""report.html: one self-contained page (no script, no external file) with the run's facts, every
table, every figure embedded as a base64 PNG with its caption, and the definitions.

The page is a pure function of its inputs, so the same stored data give the same bytes.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from pathlib import Path

from mcverify.reporting.run_figures import FigureResult
from mcverify.reporting.tables import Table, inline_html, to_html

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 2em auto; max-width: 1360px;
       padding: 0 1em; color: #222; line-height: 1.4; }
h1 { font-size: 1.6em; } h2 { margin-top: 2em; border-bottom: 1px solid #ccc; } h3 { margin-top: 1.5em; }
dl.facts { display: grid; grid-template-columns: max-content 1fr; gap: 0.2em 1em; }
dl.facts dt { font-weight: bold; } dl.facts dd { margin: 0; }
table { border-collapse: collapse; margin: 1em 0 0.3em; font-size: 0.86em; font-variant-numeric: tabular-nums; }
caption { caption-side: top; text-align: left; font-weight: bold; padding-bottom: 0.4em; font-size: 1.1em; }
p.table-title { font-weight: bold; font-size: 1.1em; margin-bottom: 0.2em; }
th, td { padding: 0.25em 0.5em; border-bottom: 1px solid #e3e3e3; text-align: right; }
td { white-space: normal; overflow-wrap: break-word; min-width: 4.5em; }  /* wraps at spaces and <wbr>, not mid-word */
table.wide { font-size: 0.76em; } table.wide td { min-width: 3.6em; }  /* many columns: smaller, to fit */
table.wide th, table.wide td { padding: 0.2em 0.35em; }
tbody th { white-space: nowrap; }
td.unsafe, span.unsafe { background: #fbe3e1; color: #8a1c12; font-weight: 600; padding: 0 0.3em; }
tbody th.unsafe { color: #8a1c12; box-shadow: inset 3px 0 0 #c0392b; }
p.legend { font-size: 0.9em; }
thead th { border-bottom: 2px solid #555; vertical-align: bottom; white-space: normal; }
tbody th { text-align: left; font-weight: normal; }
tr.section th { text-align: left; font-style: italic; background: #f3f3f3; }
tbody tr:hover { background: #fafae8; }
tbody tr:hover td.unsafe { background: #f6cdc9; }
.scroll { overflow-x: auto; }
ul.notes { font-size: 0.85em; color: #444; margin-top: 0.2em; }
figure { margin: 1.5em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #333; margin-top: 0.4em; }
nav ul { columns: 2; }
code { font-size: 0.92em; background: #f3f3f3; padding: 0 0.2em; border-radius: 2px; }
"""


def render(
    run_dir: Path,
    facts: Sequence[tuple[str, str]],
    tables: Sequence[Table],
    figures: Sequence[FigureResult],
    definitions: Sequence[tuple[str, str]],
    *,
    title: str,
) -> str:
    """The page; figure files are read from ``run_dir`` and embedded."""
    esc = html.escape
    out = [
        "<!DOCTYPE html>",
        '<html lang="en">',
        "<head>",
        '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{esc(title)}</title>",
        f"<style>{_CSS}</style>",
        "</head>",
        "<body>",
        f"<h1>{esc(title)}</h1>",
        '<dl class="facts">',
    ]
    out += [f"<dt>{esc(k)}</dt><dd>{inline_html(v)}</dd>" for k, v in facts]
    out.append("</dl>")
    drawn = [f for f in figures if f.file]
    out.append("<nav><h2>Contents</h2><ul>")
    out += [f'<li><a href="#tab-{esc(t.key)}">{esc(t.title)}</a></li>' for t in tables]
    out += [f'<li><a href="#fig-{esc(f.key)}">{esc(f.title)}</a></li>' for f in drawn]
    out.append('<li><a href="#definitions">Definitions</a></li></ul></nav>')
    out.append("<h2>Tables</h2>")
    rendered = [to_html(t) for t in tables]
    if any('class="unsafe"' in r for r in rendered):
        out.append('<p class="legend"><span class="unsafe">k/n</span> counts unsafe episodes (safe below n, or a '
                   "collision or ellipse violation above 0); ⚠ marks a row with such a count.</p>")
    for r in rendered:
        out.append(f'<div class="scroll">{r}</div>')
    out.append("<h2>Figures</h2>")
    for f in drawn:
        data = base64.b64encode((Path(run_dir) / f.file).read_bytes()).decode("ascii")
        out.append(f'<figure id="fig-{esc(f.key)}"><h3>{esc(f.title)}</h3>'
                   f'<img alt="{esc(f.title)}" src="data:image/png;base64,{data}">'
                   f"<figcaption>{inline_html(f.caption)}</figcaption></figure>")
    skipped = [f for f in figures if not f.file]
    if skipped:
        items = "".join(f"<li>{esc(f.title)}: {inline_html(f.skipped)}</li>" for f in skipped)
        out.append(f"<p>Not drawn:</p><ul>{items}</ul>")
    out.append('<h2 id="definitions">Definitions</h2><dl>')
    out += [f"<dt><strong>{esc(k)}</strong></dt><dd>{inline_html(v)}.</dd>" for k, v in definitions]
    out += ["</dl>", "</body>", "</html>", ""]
    return "\n".join(out)
