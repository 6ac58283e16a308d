"""benchmarks.stratified on the tiny campaign: chunks kept and resumed, the same files whatever the workers,
the section's bound from the kept counts, a bad input one line (exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks import stratified
from mcverify.estimate import strata

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"
SETTINGS = ["scenario.front_accel_range_mps2=[0.5, 2.0]"]
STRATA = """
[[stratum]]
name = "slow burst, y high"
episodes = 12
draws = { front_accel_mps2 = [0.5, 1.0] }
units = [{ step = 4, channel = "front_y", range = [0.5, 1.0] }]
"""


def _one_cell(tmp_path: Path) -> Path:
    """The tiny campaign without its grid: one cell, veh_f at 25 km/h."""
    text = FIXTURE.read_text().split("[grid]")[0] + "\n[model.scenario]\nfront_speed_kmh = 25\n"
    path = tmp_path / "one.toml"
    path.write_text(text)
    return path


def _args(tmp_path: Path, out: str, *extra: str) -> list[str]:
    path = tmp_path / "strata.toml"
    path.write_text(STRATA)
    sets = [a for s in SETTINGS for a in ("--set", s)]
    return [str(_one_cell(tmp_path)), "--strata", str(path), *sets, "--target", "collision", "--seed", "3",
            "--out-dir", str(tmp_path / out), "--write", str(tmp_path / "BENCH.md"), *extra]


@pytest.mark.slow
def test_a_run_keeps_its_chunks_resumes_and_writes_its_bound(tmp_path, capsys):
    assert stratified.main(_args(tmp_path, "a", "--replay")) == 0
    chunks = sorted((tmp_path / "a" / "stratum-00").glob("chunk-*.npz"))
    assert [c.name for c in chunks] == ["chunk-0000.npz", "chunk-0001.npz"]  # 10 + 2 episodes
    g = np.concatenate([np.load(c)["g"] for c in chunks])
    assert g.size == 12
    page = (tmp_path / "BENCH.md").read_text()
    p_region = (0.5 / 1.5) * 0.25
    bound = strata.lower_bound([strata.StratumCount("s", p_region, int((g <= 0).sum()), 12)])
    assert f"P(collision) >= {bound.lower:.3g}" in page
    assert f"{int((g <= 0).sum())} / 12" in page
    kept = json.loads((tmp_path / "a" / stratified.BOUND).read_text())  # what benchmarks.continuation reads
    assert kept["lower"] == bound.lower and kept["episodes"] == 12 and kept["target"] == "collision"
    assert kept["params"]["scenario"]["front_accel_range_mps2"] == [0.5, 2.0]
    capsys.readouterr()
    assert stratified.main(_args(tmp_path, "a", "--no-write")) == 0  # resumed: nothing left to run
    assert "2 of 2 chunks kept" in capsys.readouterr().out
    # two workers write the same chunks as one
    assert stratified.main(_args(tmp_path, "b", "--workers", "2", "--no-write")) == 0
    for c in chunks:
        other = np.load(tmp_path / "b" / "stratum-00" / c.name)
        assert np.array_equal(np.load(c)["g"], other["g"])


def test_a_box_the_cell_cannot_hold_is_one_line_before_anything_runs(tmp_path, capsys):
    args = _args(tmp_path, "c")
    (tmp_path / "strata.toml").write_text(STRATA.replace("step = 4", "step = 40"))
    code = stratified.main(args)
    err = capsys.readouterr().err
    assert code == 2 and "outside the episode's control steps 0 to 9" in err and err.count("\n") == 1
    assert not (tmp_path / "c").exists()
