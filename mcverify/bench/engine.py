"""``mcverify bench``: the engine against the naive reference loop, measured in one run.

Both sides run the same paired episodes of one campaign cell (default: the paper's Table IV,
Scenario B, VL-CBF eps = 0.3 - a human-driven opposing vehicle, both problems every step, noise on)
with the same control period, horizon and integration:

* naive: :mod:`mcverify.bench.naive` - a Python loop over episodes and steps, CasADi Opti + IPOPT;
* engine: :func:`mcverify.episode.rollout.run_episodes` with the cell's solver backend (or ``--backend``).

Reported: episodes per CPU-minute of each side (``time.process_time`` of this process, so worker
counts flatter neither side) and their ratio, peak resident memory, and the agreement of the paired
episodes (safety verdict, outcome, minimum distances, overtaking time;
:func:`mcverify.bench.agreement.agreement`). The row is appended to
``results/BENCHMARKS.md`` with the command and the machine.

The engine's CPU is split by phase (:class:`mcverify.episode.rollout.PhaseClock`): the solver (summed from
the episodes' solve times), the rest of the host controller, and the JAX plant; the plant's
host-device transfers are timed apart by :func:`plant_transfer_ms` on the same batch. There are no
host callbacks: the solver runs on the host between two jitted calls, not inside XLA.
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import resource
import shlex
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import jax
import numpy as np

from mcverify import provenance
from mcverify.bench.agreement import agreement
from mcverify.bench.naive import run_naive
from mcverify.campaign import executors
from mcverify.campaign.spec import load_campaign
from mcverify.cell import Cell
from mcverify.episode.rollout import PhaseClock, episode_key, run_episodes
from mcverify.sim.plant import LaneGroups, initial_plant

DEFAULT_CAMPAIGN = "campaigns/table4_fixed_start.toml"
DEFAULT_CELL = "scenario=B,method=VL-CBF eps=0.3"
BENCHMARKS_MD = Path("results/BENCHMARKS.md")
#: Columns compared between paired episodes (besides the safety verdict).
PAIRED_VALUES = ("min_dist_front_m", "min_gap_opp_m", "overtake_time_s")


@dataclasses.dataclass
class SideResult:
    name: str
    rows: list[dict]
    cpu_s: float
    wall_s: float
    phases: dict[str, float] = dataclasses.field(default_factory=dict)

    @property
    def episodes_per_cpu_min(self) -> float:
        return 60.0 * len(self.rows) / self.cpu_s if self.cpu_s > 0 else math.nan

    @property
    def solves(self) -> int:
        return sum(r["solves"] for r in self.rows)

    @property
    def cpu_ms_per_solve(self) -> float:
        return 1e3 * self.cpu_s / self.solves if self.solves else math.nan


def _timed(name: str, fn) -> SideResult:
    cpu0, wall0 = time.process_time(), time.perf_counter()
    rows = fn()
    return SideResult(name, rows, time.process_time() - cpu0, time.perf_counter() - wall0)


def engine_phases(rows: list[dict], clock: PhaseClock, total_cpu_s: float) -> dict[str, float]:
    """CPU seconds per phase of the engine's loop; planner + plant + other = ``total_cpu_s``.

    planner: the host controllers (the solves, warm starts, Algorithm 1, Table I); plant: JAX
    observe/advance with their transfers; other: scenario draws, bookkeeping, rows. solver_wall:
    the solves' own clock (``solves * solve_time_mean_s``), wall time: on an idle machine it is
    the solver's share of the planner phase, on a loaded one it can exceed it.
    """
    planner = clock.cpu_s.get("planner", 0.0)
    plant = clock.cpu_s.get("plant", 0.0)
    return {
        "planner": planner,
        "plant": plant,
        "other": max(total_cpu_s - planner - plant, 0.0),
        "solver_wall": sum(r["solves"] * r["solve_time_mean_s"] for r in rows if r["solves"]),
        "control_steps": float(clock.calls.get("planner", 0)),
    }


def plant_transfer_ms(cell: Cell, batch: int, seed: int, reps: int = 200) -> dict[str, float]:
    """CPU ms per control step of a ``batch``-episode chunk: the jitted plant (observe + advance,
    waited for; the controls' copy to the device included) against the device-to-host copies the
    loop makes of its results (measurements, ego states, safety trace). Steps with zero control
    from the campaign's start; the cost does not depend on the state."""
    p = cell.params
    keys = jax.numpy.stack([episode_key(seed, cell.index, e) for e in range(batch)])
    world = LaneGroups(initial_plant(p, [0.0] * batch), keys, p)
    u, active = np.zeros((batch, 2)), np.ones(batch, dtype=bool)
    world.advance(u, active), world.observe(0)  # compiled outside the clock
    compute = transfer = 0.0
    for step in range(reps):
        t0 = time.process_time()
        obs = world.observe_on_device(step)
        subs = world.advance(u, active)
        jax.block_until_ready((obs, subs, world.plants, world.traces))
        t1 = time.process_time()
        [np.asarray(a) for group in obs for a in group], world.ego(), world.trace()
        transfer += time.process_time() - t1
        compute += t1 - t0
    return {"compute_ms": 1e3 * compute / reps, "transfer_ms": 1e3 * transfer / reps, "batch": float(batch)}


def pick_cell(campaign_path: str, cell_name: str, backend: str | None) -> tuple[Cell, int, bool]:
    camp = load_campaign(campaign_path)
    cell = camp.cell(cell_name)
    if backend is not None:
        from mcverify.campaign.spec import apply_overrides

        cell = dataclasses.replace(cell, params=apply_overrides(cell.params, {"mpc.backend": backend}, "--backend"))
    return cell, camp.seed, camp.common_random_numbers


def machine() -> str:
    """One line naming the machine for a benchmark row."""
    return f"{provenance.cpu_model()}, {os.cpu_count()} logical cores, Python {platform.python_version()}"


def run(
    *,
    campaign: str = DEFAULT_CAMPAIGN,
    cell_name: str = DEFAULT_CELL,
    naive_episodes: int = 1,
    engine_episodes: int = 4,
    backend: str | None = None,
    write: bool = True,
    progress=print,
) -> dict[str, Any]:
    """Run both sides and return the figures (and append them to results/BENCHMARKS.md)."""
    if naive_episodes < 1 or engine_episodes < naive_episodes:
        raise ValueError("need naive_episodes >= 1 and engine_episodes >= naive_episodes (the naive ones are paired)")
    cell, seed, crn = pick_cell(campaign, cell_name, backend)
    ids = list(range(engine_episodes))
    progress(f"bench: {campaign} [{cell.name}], backend {cell.params.mpc.backend}; "
             f"engine {engine_episodes} episodes, naive {naive_episodes} (paired: the first {naive_episodes})")
    # One-off costs, outside both clocks and reported apart: loading (or compiling) the solver kernels
    # and XLA's compilation of the plant - a one-step episode triggers both, once per process.
    cpu0 = time.process_time()
    planner = executors.solver_for(cell.params)
    sim = dataclasses.replace(cell.params.sim, max_time_s=cell.params.sim.control_period_s)
    warm_cell = dataclasses.replace(cell, params=dataclasses.replace(cell.params, sim=sim))
    run_episodes(warm_cell, [0], seed, executors.solver_for(warm_cell.params), common_random_numbers=crn)
    setup_cpu_s = time.process_time() - cpu0
    progress(f"  one-off set-up (kernel load, XLA compile of the plant): {setup_cpu_s:.1f} CPU-s, not counted")
    clock = PhaseClock()
    engine = _timed("engine", lambda: run_episodes(cell, ids, seed, planner, common_random_numbers=crn,
                                                   clock=clock).rows)
    engine.phases = engine_phases(engine.rows, clock, engine.cpu_s)
    progress(f"  engine: {engine.cpu_s:.1f} CPU-s, {engine.episodes_per_cpu_min:.3g} episodes per CPU-minute")
    transfer = plant_transfer_ms(cell, engine_episodes, seed)
    naive = _timed("naive", lambda: run_naive(cell, ids[:naive_episodes], seed, common_random_numbers=crn))
    progress(f"  naive:  {naive.cpu_s:.1f} CPU-s, {naive.episodes_per_cpu_min:.3g} episodes per CPU-minute")
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    result = {
        "campaign": campaign,
        "cell": cell.name,
        "backend": cell.params.mpc.backend,
        "engine": engine,
        "naive": naive,
        "ratio": engine.episodes_per_cpu_min / naive.episodes_per_cpu_min,
        "peak_rss_mb": peak_mb,
        "setup_cpu_s": setup_cpu_s,
        "plant_transfer": transfer,
        "agreement": agreement(naive.rows, engine.rows, key="cell_episode", values=PAIRED_VALUES),
        "machine": machine(),
        "command": "mcverify " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["bench"]
        else "mcverify bench",
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d"),
    }
    if write:
        append_markdown(result)
    return result


def render(result: dict[str, Any]) -> str:
    e, n, ag = result["engine"], result["naive"], result["agreement"]
    lines = [
        f"bench on {result['machine']}",
        f"  cell: {result['campaign']} [{result['cell']}], engine backend {result['backend']}",
        f"  naive : {len(n.rows)} episodes, {n.cpu_s:.1f} CPU-s, {n.cpu_ms_per_solve:.1f} CPU-ms per solve, "
        f"{n.episodes_per_cpu_min:.3g} episodes per CPU-minute",
        f"  engine: {len(e.rows)} episodes, {e.cpu_s:.1f} CPU-s, {e.cpu_ms_per_solve:.1f} CPU-ms per solve, "
        f"{e.episodes_per_cpu_min:.3g} episodes per CPU-minute",
        f"  engine / naive: {result['ratio']:.1f}x episodes per CPU-minute",
        f"  peak memory: {result['peak_rss_mb']:.0f} MB; one-off set-up {result['setup_cpu_s']:.1f} CPU-s "
        "(kernel load, XLA compile; counted on neither side)",
        *phase_lines(e, result.get("plant_transfer")),
        f"  agreement on {ag['paired']} paired episodes: safety verdict {ag['safe_agree']}/{ag['paired']}, outcome "
        f"{ag['outcome_agree']}/{ag['paired']}; largest differences: "
        + ", ".join(f"{c} {ag[f'{c}_absdiff_max']:.3g}" for c in PAIRED_VALUES),
    ]
    unsafe = [d["cell_episode"] for d in ag["disagreements"] if d["safe_ref"] != d["safe_new"]]
    if unsafe:
        lines.append(f"  safety verdicts differ for episodes {unsafe}")
    return "\n".join(lines)


def phase_lines(engine: SideResult, transfer: dict[str, float] | None) -> list[str]:
    """Where the engine's CPU went, per episode and per control step of the batch."""
    ph = engine.phases
    if not ph or not engine.rows:
        return []
    n, steps = len(engine.rows), max(ph["control_steps"], 1.0)
    parts = ", ".join(f"{k} {ph[k] / n:.2f} s ({100 * ph[k] / engine.cpu_s:.0f}%)"
                      for k in ("planner", "plant", "other"))
    lines = [f"  engine CPU per episode: {parts}; the solves' own clock: {ph['solver_wall'] / n:.2f} s wall "
             "(the solver's share of the planner on an idle machine)",
             f"  JAX plant: {1e3 * ph['plant'] / steps:.2f} CPU-ms per control step of the {n}-episode batch "
             "(observe + advance, transfers included); no host callbacks (the solver runs between jitted calls)"]
    if transfer:
        lines.append(f"  of which device-to-host copies: {transfer['transfer_ms']:.3f} ms against "
                     f"{transfer['compute_ms']:.3f} ms of dispatch and XLA compute per control step "
                     f"(isolated, {int(transfer['batch'])} episodes, 200 steps)")
    return lines


def append_markdown(result: dict[str, Any], path: Path = BENCHMARKS_MD) -> None:
    e, n, ag = result["engine"], result["naive"], result["agreement"]
    header = (
        "| date | command | machine | cell | backend | naive ep/CPU-min | engine ep/CPU-min | ratio | "
        "naive CPU-ms/solve | engine CPU-ms/solve | peak MB | paired safety agreement |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    row = (
        f"| {result['date']} | `{result['command']}` | {result['machine']} | {result['cell']} | {result['backend']} | "
        f"{n.episodes_per_cpu_min:.3g} | {e.episodes_per_cpu_min:.3g} | {result['ratio']:.1f}x | "
        f"{n.cpu_ms_per_solve:.1f} | {e.cpu_ms_per_solve:.1f} | {result['peak_rss_mb']:.0f} | "
        f"{ag['safe_agree']}/{ag['paired']} |\n"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    marker = "## mcverify bench (engine vs naive reference)\n\n"
    if marker not in text:
        text = text.rstrip("\n") + "\n\n" + marker + header
    # insert after the last row of this section's table (other sections may follow it)
    start = text.index(marker) + len(marker)
    end = text.find("\n\n", start)
    end = len(text) if end < 0 else end + 1
    path.write_text(text[:end] + row + text[end:])
