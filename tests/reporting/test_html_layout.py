"""report.html fits a 1400 px window: every table inside a scroll box, cells that wrap, and - where a
headless Chromium is installed - no table wider than its box when the page is actually laid out.
Unsafe counts are highlighted."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
import synthetic

from mcverify.reporting import run_report
from mcverify.reporting.tables import unsafe_count

RAW = {"campaign": {"name": "wide", "seed": 3, "episodes": 30},
       "grid": {"barrier.epsilon": [0.0, 0.1, 0.3, 0.5], "noise.scale": [1.0, 2.0]}}

# Appended to a copy of the page: writes, for every table, whether it is wider than its scroll box.
_PROBE = """<script>
const out = [...document.querySelectorAll('div.scroll')].map(d =>
  d.querySelector('table').id + ':' + (d.scrollWidth > d.clientWidth + 1 ? 'OVERFLOW' : 'fits') + ':' + d.scrollWidth);
document.body.setAttribute('data-probe', out.join(' '));
</script>"""


@pytest.fixture(scope="module")
def page(tmp_path_factory) -> Path:
    run = synthetic.make_run(tmp_path_factory.mktemp("html") / "run", RAW, trajectories=False,
                             probs=lambda c: {"unsafe": 0.3 if c.epsilon < 0.05 else 0.0, "overtook": 0.6,
                                              "went_back": 0.3, "error": 0.0})
    run_report.write(run)
    return run / "report.html"


def test_every_table_sits_in_a_scroll_box_and_cells_wrap(page: Path):
    text = page.read_text()
    tables = re.findall(r'<div class="scroll"><table id="tab-([^"]+)"(?: class="wide")?>', text)
    assert len(tables) == text.count("<table ") > 3
    css = text.split("<style>", 1)[1].split("</style>", 1)[0]
    assert re.search(r"\btd \{[^}]*white-space: normal", css), "data cells must be allowed to wrap"
    assert ".scroll { overflow-x: auto; }" in css


def test_unsafe_counts_are_highlighted(page: Path):
    text = page.read_text()
    highlighted = re.findall(r'<td class="unsafe">([^<]*)</td>', text)
    assert highlighted and all(re.match(r"\d+/\d+", h) for h in highlighted)
    assert unsafe_count("outcomes", "safe", "21/30 [0.506, 0.853]")
    assert not unsafe_count("outcomes", "safe", "30/30 (≥ 0.905)")
    assert unsafe_count("outcomes", "collision veh_f", "1/30 [0.001, 0.17]")
    assert not unsafe_count("outcomes", "collision veh_f", "0/30 (≤ 0.095)")
    assert unsafe_count("pivot-safe", "scale = 1", "29/30 [0.8, 1]")
    assert not unsafe_count("pivot-overtook", "scale = 1", "3/30 [0.02, 0.2]")
    assert not unsafe_count("outcomes", "overtook", "3/30 [0.02, 0.2]")


def test_no_table_overflows_at_1400_px_in_a_real_browser(page: Path, tmp_path: Path):
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        pytest.skip("no headless Chromium here (Debian: apt-get install chromium)")
    probe = tmp_path / "probe.html"
    probe.write_text(page.read_text().replace("</body>", _PROBE + "</body>"))
    dom = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1400,2000",
                          "--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=120).stdout
    found = re.search(r'data-probe="([^"]*)"', dom)
    assert found, dom[-500:]
    results = found.group(1).split()
    assert len(results) > 3
    assert [r for r in results if "OVERFLOW" in r] == []


def test_report_writes_publication_formats_byte_stable(tmp_path: Path, capsys):
    from mcverify import cli

    run = synthetic.make_run(tmp_path / "run", {"campaign": {"name": "f", "seed": 1, "episodes": 6},
                                                "grid": {"barrier.epsilon": [0.1, 0.3]}}, trajectories=False)
    assert cli.main(["report", str(run), "--format", "svg", "--format", "pdf", "--format", "png", "--dpi", "200"]) == 0
    figs = run / "figures"
    pngs = sorted(p.stem for p in figs.glob("*.png") if not p.stem.endswith("-200dpi"))
    assert pngs and sorted(p.stem for p in figs.glob("*.svg")) == pngs == sorted(p.stem for p in figs.glob("*.pdf"))
    assert sorted(p.stem for p in figs.glob("*-200dpi.png")) == [f"{s}-200dpi" for s in pngs]
    first = {p.name: p.read_bytes() for p in figs.iterdir()}
    assert cli.main(["report", str(run), "--format", "svg", "--format", "pdf", "--format", "png", "--dpi", "200"]) == 0
    assert {p.name: p.read_bytes() for p in figs.iterdir()} == first, "the same data give the same bytes"
    assert cli.main(["report", str(run)]) == 0
    assert sorted(p.stem for p in figs.iterdir()) == pngs, "a plain report removes the extra files"
    assert cli.main(["report", str(run), "--dpi", "300"]) == 2
    capsys.readouterr()
