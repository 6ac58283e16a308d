"""T3's counterexample that IPOPT confirms, written as a one-episode run folder with this code.

    python studies/t3-ellipse-graze/write_counterexample.py OUT_DIR
    mcverify replay OUT_DIR 0                    # bit for bit
    mcverify replay OUT_DIR 0 --backend ipopt    # the same error, IPOPT at every step

The error schedule (``schedule.csv``: the non-zero per-step units, bang-bang on veh_f's x, y and v from
4.6 to 6.2 s) was found by a beam ranked by the margin ladder (a score since deleted, docs/decisions.md) on
``campaigns/adversary_t3_beam.toml`` (VL-CBF at eps = 0, twice the paper's noise bounds), seed 2.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

from mcverify import store
from mcverify.analysis.robustness import robustness
from mcverify.campaign.spec import load_campaign
from mcverify.falsify import adversary
from mcverify.sim.schedule import CHANNELS, ErrorSchedule

HERE = Path(__file__).resolve().parent
CAMPAIGN = HERE.parents[1] / "campaigns" / "adversary_t3_beam.toml"
EPISODE_STEPS = 1250  # the campaign's 25 s at 50 Hz


def units() -> np.ndarray:
    """The schedule's units, (steps, channels), zero where ``schedule.csv`` names none."""
    out = np.zeros((EPISODE_STEPS, len(CHANNELS)))
    with open(HERE / "schedule.csv", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            out[int(row["step"]), CHANNELS.index(row["channel"])] = float(row["unit"])
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python studies/t3-ellipse-graze/write_counterexample.py OUT_DIR", file=sys.stderr)
        return 2
    out = Path(argv[0])
    if out.exists():
        print(f"{out} exists; give a new folder", file=sys.stderr)
        return 2
    adversary.run_folder(load_campaign(CAMPAIGN), {0: ErrorSchedule.of(units(), 1.0, 0.0)}, out)
    row = store.read_episodes(out).to_pylist()[0]
    print(f"{out}: {row['outcome']}, lowest h_ef {robustness(row, 'ellipse'):.4f}, steps with neither Q1 nor Q2 "
          f"solved {row['both_infeasible_steps']} ({row['both_certified_infeasible_steps']} certified by IPOPT), "
          f"held-plan confirmations {row['hold_confirm_solves']} ({row['hold_confirm_solved']} found a plan)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
