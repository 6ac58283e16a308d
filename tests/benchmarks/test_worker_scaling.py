"""benchmarks.worker_scaling: its section, its worker counts and its one-line mistakes (the timed
run itself is the benchmark, not a test)."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks import worker_scaling as ws
from mcverify import files
from mcverify.campaign.spec import load_campaign
from mcverify.errors import UserError


def test_the_section_states_command_commit_machine_and_one_line_per_worker_count(tmp_path: Path) -> None:
    camp = load_campaign("campaigns/table4.toml", episodes=1)
    points = [ws.Point(1, 8, 120.0, True), ws.Point(2, 8, 75.0, True), ws.Point(4, 8, 60.0, False)]
    text = ws.render(points, camp, 8, "python -m benchmarks.worker_scaling --episodes 1")
    assert text.startswith(ws.BEGIN) and text.rstrip().endswith(ws.END)
    assert "Command: `python -m benchmarks.worker_scaling --episodes 1`; commit `" in text
    assert "logical cores" in text and "campaigns/table4.toml" in text
    assert "| 1 | 8 | 120.0 | 4.00 | 1.00x | 100% | identical |" in text
    assert "| 2 | 8 | 75.0 | 6.40 | 1.60x | 80% | identical |" in text
    assert "| 4 | 8 | 60.0 | 8.00 | 2.00x | 50% | DIFFERENT |" in text
    page = tmp_path / "BENCHMARKS.md"
    page.write_text("# Benchmarks\n\nkept\n")
    files.replace_section(page, text, ws.BEGIN, ws.END)
    files.replace_section(page, text.replace("120.0", "121.0"), ws.BEGIN, ws.END)  # rewritten, not appended
    assert page.read_text().count(ws.BEGIN) == 1 and "121.0" in page.read_text() and "kept" in page.read_text()


def test_default_worker_counts_double_up_to_the_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ws.executors, "default_workers", lambda: 12)
    assert ws._worker_counts(None) == [1, 2, 4, 8, 12]
    assert ws._worker_counts("3,1") == [3, 1]
    with pytest.raises(UserError, match="must be >= 1"):
        ws._worker_counts("0,2")


@pytest.mark.parametrize("argv", [["--workers", "a"], ["--episodes", "0"], ["--campaign", "missing.toml"],
                                  ["--episodes", "x"]])
def test_a_mistake_is_one_line_and_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert ws.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("benchmarks.worker_scaling: error: ") and err.count("\n") == 1
