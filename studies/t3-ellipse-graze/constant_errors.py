"""Structured errors at the bound on T3's scenario: constant and alternating units on veh_f's channels over
windows of the adversary's 4.6-6.2 s, one episode each; prints the lowest h_ef of each.

    python studies/t3-ellipse-graze/constant_errors.py

A schedule is ``FROM-TO:X:Y:V[/FROM-TO:X:Y:V...]``: control steps [FROM, TO) at 50 Hz and a unit per channel
(veh_f's measured x, y, v): a number in [-1, 1] (times twice the paper's bound), or ``a`` / ``b`` for a unit
that alternates +1, -1 (``a``) or -1, +1 (``b``) from step to step. Other schedules can be given as arguments.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from mcverify.analysis.robustness import robustness
from mcverify.campaign.spec import load_campaign
from mcverify.falsify import adversary
from mcverify.sim.schedule import CHANNELS, ErrorSchedule

CAMPAIGN = Path(__file__).resolve().parents[2] / "campaigns" / "adversary_t3_beam.toml"
EPISODE_STEPS = 1250  # the campaign's 25 s at 50 Hz
SCHEDULES = (
    "0-0:0:0:0",  # no error
    "230-310:-1:0:-1", "230-310:-1:-1:-1", "230-310:-1:1:-1", "230-310:-1:-1:0", "230-310:0:-1:-1",
    "230-310:0:-1:0", "230-310:1:-1:-1", "230-310:1:0:1", "270-300:-1:0:-1", "286-294:-1:0:-1",
    "230-310:-1:a:-1", "230-310:-1:b:-1", "230-265:0:a:0/265-300:-1:-1:-1", "230-265:-1:a:-1/265-300:-1:-1:-1",
)


def _unit(token: str, step: int) -> float:
    if token in ("a", "b"):
        return (1.0 if step % 2 == 0 else -1.0) * (1.0 if token == "a" else -1.0)
    return float(token)


def schedule(text: str) -> ErrorSchedule:
    units = np.zeros((EPISODE_STEPS, len(CHANNELS)))
    for segment in text.split("/"):
        window, *tokens = segment.split(":")
        first, last = (int(k) for k in window.split("-"))
        for step in range(first, last):
            for channel, token in zip(("front_x", "front_y", "front_v"), tokens, strict=True):
                units[step, CHANNELS.index(channel)] = _unit(token, step)
    return ErrorSchedule.of(units, 1.0, 0.0)


def main(argv: list[str]) -> int:
    campaign = load_campaign(CAMPAIGN)
    cell = campaign.cells[0]
    print("| schedule | lowest h_ef | outcome | steps with neither Q1 nor Q2 solved | CPU-s |\n|---|---|---|---|---|")
    for text in argv or SCHEDULES:
        start = time.process_time()
        row = adversary.evaluate(cell, [schedule(text)], seed=campaign.seed, episode_ids=[0]).rows[0]
        print(f"| `{text}` | {robustness(row, 'ellipse'):.4f} | {row['outcome']} | {row['both_infeasible_steps']} | "
              f"{time.process_time() - start:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
