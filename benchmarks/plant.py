"""``python -m benchmarks.plant``: how the JAX side of an episode scales with the batch, on CPU and GPU.

The JAX side is the plant (kinematic bicycle and veh_f / veh_o under RK4 sub-steps), the Sec. VI-A
perception noise and every safety check (VL-CBF h_ef and h_eo, footprint gaps) at every sub-step.
In the engine the control comes from the CasADi solver on the host, so the plant is stepped one
control period at a time in fixed groups of :data:`mcverify.sim.plant.LANES` episodes (the width
that keeps an episode's numbers independent of its chunk). Here the solver is replaced by a
stand-in control law written in JAX (lane keeping at veh_f's *measured* speed, so the noise reaches
the loop), a whole episode becomes one ``lax.scan`` and a batch one ``vmap``: the throughput ceiling
of the JAX side per backend and batch size, to be set against the solver's cost per control step.

Only :mod:`mcverify.sim`, :mod:`mcverify.model` and the campaign files are used (no CasADi), so the
bench runs on a GPU machine that has JAX but not the solver stack. Results are plain dicts (JSON):
``--include`` merges runs from several machines into one section of ``results/BENCHMARKS.md``.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import section
from mcverify import files, provenance, sim  # noqa: F401 - configures JAX (float64, CPU ISA) before any array exists
from mcverify.campaign.spec import load_campaign
from mcverify.cell import Cell
from mcverify.cli.options import int_list, positive_int
from mcverify.errors import UserError
from mcverify.sim import plant as plant_mod
from mcverify.sim.plant import Plant, PlantParams, SafetyTrace

#: Markers of the generated section in results/BENCHMARKS.md.
BEGIN, END = section.markers("plant")
DEFAULT_CAMPAIGN = Path("campaigns/table4.toml")
#: Batch sizes per platform when none are given: a CPU is saturated by a few thousand episodes (and
#: 32,768 full rollouts take minutes there), a GPU only by about 10^5.
DEFAULT_BATCHES = {"cpu": (8, 64, 512, 4096), "gpu": (8, 64, 512, 4096, 32768, 262144)}
#: Control steps per timed rollout when none are given (5 s at 50 Hz): the figures are per episode-step.
DEFAULT_STEPS = 250

#: Gains of the stand-in law (1/s), as in :mod:`mcverify.control.lane_keeping`.
K_Y, K_V, V_FLOOR_MPS = 1.0, 1.0, 1.0


def control_params(cell: Cell) -> tuple[jax.Array, ...]:
    """(ego_lane_y_m, heading_max_rad, slip_max_rad, accel_min_mps2, accel_max_mps2) as JAX scalars."""
    p = cell.params
    f = lambda v: jnp.asarray(v, dtype=float)  # noqa: E731
    return (f(p.road.ego_lane_y_m), f(p.ego.heading_max_rad), f(p.ego.slip_max_rad),
            f(p.ego.accel_min_mps2), f(p.ego.accel_max_mps2))


def stand_in_control(ego: jax.Array, front_meas: jax.Array, cp: tuple[jax.Array, ...]) -> jax.Array:
    """u = (alpha m/s^2, beta rad) for one episode: keep the ego lane, match veh_f's measured speed.

    ego (4,) [x, y, psi, v]; front_meas (3,) [x, y, v] as measured (noisy).
    """
    lane_y_m, heading_max, slip_max, accel_min, accel_max = cp
    offset_m = ego[1] - lane_y_m
    psi_ref = -jnp.arctan(K_Y * offset_m / jnp.maximum(ego[3], V_FLOOR_MPS))
    psi_ref = jnp.clip(psi_ref, -heading_max / 2, heading_max / 2)
    beta = jnp.clip(psi_ref - ego[2], -slip_max, slip_max)
    alpha = jnp.clip(K_V * (front_meas[2] - ego[3]), accel_min, accel_max)
    return jnp.stack([alpha, beta])


def closed_loop_step(plant: Plant, trace: SafetyTrace, key: jax.Array, step: jax.Array, pp: PlantParams,
                     cp: tuple[jax.Array, ...], substeps: int) -> tuple[Plant, SafetyTrace]:
    """One control period of one episode: measure, control, advance (every check at every sub-step)."""
    front_meas, _ = plant_mod.observe(plant, key, step, pp)
    u = stand_in_control(plant.ego, front_meas, cp)
    plant, trace, _ = plant_mod.advance(plant, trace, u, jnp.asarray(True), pp, substeps)
    return plant, trace


@functools.lru_cache(maxsize=16)
def batched_rollout(substeps: int, steps: int):
    """jit(vmap(episode)): (plants (B,...), keys (B, 2), pp, cp) -> final SafetyTrace (B,...)."""

    def episode(plant: Plant, key: jax.Array, pp: PlantParams, cp) -> SafetyTrace:
        trace = plant_mod.initial_trace(plant, pp)

        def body(carry, step):
            pl, tr = carry
            return closed_loop_step(pl, tr, key, step, pp, cp, substeps), None

        (_, trace), _ = jax.lax.scan(body, (plant, trace), jnp.arange(steps))
        return trace

    return jax.jit(jax.vmap(episode, in_axes=(0, 0, None, None)))


def initial_batch(cell: Cell, seed: int, batch: int) -> tuple[Plant, jax.Array]:
    """``batch`` episodes of the cell's start: alpha_f drawn in its range, one noise key per episode."""
    s = cell.params.scenario
    rng = np.random.default_rng(seed)
    if s.front_accel_range_mps2:
        lo, hi = s.front_accel_range_mps2
        accels = lo + (hi - lo) * (1.0 - rng.random(batch))  # (lo, hi]
    else:
        accels = np.full(batch, s.front_accel_mps2)
    keys = jax.vmap(lambda e: jax.random.fold_in(jax.random.PRNGKey(seed), e))(jnp.arange(batch))
    return plant_mod.initial_plant(cell.params, accels.tolist()), keys


def steps_of(cell: Cell) -> int:
    """Control steps of a full-length episode of the cell (``sim.max_time_s`` / ``control_period_s``)."""
    sim_p = cell.params.sim
    return int(round(sim_p.max_time_s / sim_p.control_period_s))


def device_label(device: jax.Device) -> str:
    if device.platform == "cpu":
        return f"CPU ({provenance.cpu_model()}, {os.cpu_count()} cores)"
    return f"{device.platform.upper()} ({getattr(device, 'device_kind', '?')})"


def measure_batch(cell: Cell, seed: int, batch: int, steps: int, repeats: int, device: jax.Device) -> dict[str, Any]:
    """Compile once, then time ``repeats`` full rollouts of ``batch`` episodes on ``device``."""
    fn = batched_rollout(cell.params.sim.substeps, steps)
    with jax.default_device(device):
        plants, keys = initial_batch(cell, seed, batch)
        pp, cp = plant_mod.plant_params(cell.params), control_params(cell)
        plants, keys, pp, cp = jax.device_put((plants, keys, pp, cp), device)
        t0 = time.perf_counter()
        trace = jax.block_until_ready(fn(plants, keys, pp, cp))
        first_s = time.perf_counter() - t0
        walls = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            trace = jax.block_until_ready(fn(plants, keys, pp, cp))
            walls.append(time.perf_counter() - t0)
    wall_s = float(np.median(walls))
    episode_steps = batch * steps
    min_h = np.asarray(trace.min_h_front)
    return {
        "batch": batch, "steps": steps, "substeps": cell.params.sim.substeps, "repeats": repeats,
        "first_call_s": first_s, "wall_s": wall_s,
        "episode_steps_per_s": episode_steps / wall_s, "us_per_episode_step": 1e6 * wall_s / episode_steps,
        "episodes_per_s": batch / wall_s,
        # a fingerprint of the physics, so runs on different backends can be compared
        "mean_min_h_ef": float(np.mean(min_h)), "finite": bool(np.all(np.isfinite(min_h))),
    }


#: JAX backend names ``--platforms`` accepts.
KNOWN_PLATFORMS = ("cpu", "gpu", "cuda", "rocm", "tpu")


def available_devices(platforms: Sequence[str], progress=None) -> list[jax.Device]:
    """The first device of each named backend present here; an absent one is said (``progress``) and skipped."""
    out = []
    for name in platforms:
        try:
            out.append(jax.devices(name)[0])
        except RuntimeError:
            if progress:
                progress(f"  {name}: no such JAX backend on this machine, skipped")
    return out


def run(campaign_path: Path = DEFAULT_CAMPAIGN, batches: Sequence[int] | None = None, steps: int | None = None,
        repeats: int = 3, platforms: Sequence[str] = ("cpu", "gpu"), seed: int = 0,
        progress=print) -> list[dict[str, Any]]:
    """One result dict per device present: its label, versions and one row per batch size
    (``batches`` None: :data:`DEFAULT_BATCHES` of the platform; ``steps`` None: :data:`DEFAULT_STEPS`,
    at most the cell's episode length)."""
    campaign = load_campaign(campaign_path)
    cell = campaign.cells[0]
    n_steps = steps or min(DEFAULT_STEPS, steps_of(cell))
    results = []
    for device in available_devices(platforms, progress):
        rows = []
        for b in batches or DEFAULT_BATCHES.get(device.platform, DEFAULT_BATCHES["gpu"]):
            row = measure_batch(cell, seed, b, n_steps, repeats, device)
            rows.append(row)
            if progress:
                progress(f"  {device.platform} batch {b}: {row['wall_s']:.3f} s per rollout, "
                         f"{row['us_per_episode_step']:.2f} us per episode-step "
                         f"(first call {row['first_call_s']:.1f} s)")
        results.append({
            "device": device_label(device), "platform": device.platform, "jax": jax.__version__,
            "python": platform.python_version(), "campaign": str(campaign_path), "cell": cell.name,
            "date": time.strftime("%Y-%m-%d"), "rows": rows,
        })
    return results


def markdown(results: Sequence[dict[str, Any]], command: str) -> str:
    lines = [BEGIN, "", "## GPU scaling: the JAX side alone (`benchmarks.plant`)", "",
             section.provenance_line(command) + " Machines of included runs: their headings below.", "",
             "One episode is one `lax.scan` over its control steps, a batch one `vmap`: plant, Sec. VI-A noise and "
             "every safety check at every RK4 sub-step, with a stand-in control law in JAX (lane keeping at veh_f's "
             "measured speed) instead of the solver. Wall time of a whole batch after the compiling call (median of "
             "the repeats). The engine itself steps the plant in groups of 8 between solver calls on the host, so "
             "these figures bound what the JAX side can give, not what a closed-loop episode costs.", ""]
    for res in results:
        r0 = res["rows"][0] if res["rows"] else {}
        lines += [f"### {res['device']}, JAX {res['jax']}, {res['date']}", "",
                  f"Campaign `{res['campaign']}`, cell `{res['cell']}`: {r0.get('steps', '?')} control steps of "
                  f"{r0.get('substeps', '?')} sub-steps per episode.", "",
                  "| batch (episodes) | wall s per batch | episode-steps per s | µs per episode-step | episodes per s "
                  "| first call s (compile + run) | mean min h_ef |",
                  "|---:|---:|---:|---:|---:|---:|---:|"]
        for r in res["rows"]:
            lines.append(f"| {r['batch']} | {r['wall_s']:.4g} | {r['episode_steps_per_s']:.3g} | "
                         f"{r['us_per_episode_step']:.3g} | {r['episodes_per_s']:.4g} | {r['first_call_s']:.3g} | "
                         f"{r['mean_min_h_ef']:.6f} |")
        lines.append("")
    lines += [END, ""]
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    p = section.parser("plant", "The JAX side alone (plant, noise, safety checks) per batch size, on CPU and on a "
                                "GPU where one is present.")
    p.add_argument("--campaign", type=Path, default=Path(DEFAULT_CAMPAIGN),
                   help="campaign whose first cell is simulated (default campaigns/table4.toml)")
    p.add_argument("--batches", type=int_list, default=None,
                   help="comma-separated batch sizes (default: CPU 8,64,512,4096; GPU up to 262144)")
    p.add_argument("--steps", type=positive_int, default=None,
                   help="control steps per timed rollout (default 250, at most the cell's episode)")
    p.add_argument("--repeats", type=positive_int, default=3, help="timed rollouts per batch (default 3)")
    p.add_argument("--platforms", default="cpu,gpu", help="JAX backends to measure where present (default cpu,gpu)")
    p.add_argument("--include", type=Path, action="append", default=[], metavar="JSON",
                   help="results of this benchmark from another machine (its --json file), shown beside this run's")
    p.add_argument("--only-include", action="store_true",
                   help="measure nothing here: write the section from the --include files alone")
    p.add_argument("--json", type=Path, default=None, help="also write this run's results as JSON")
    section.add_output_options(p)
    return p


def _included(paths: Sequence[Path]) -> list[dict[str, Any]]:
    included: list[dict[str, Any]] = []
    for path in paths:
        try:
            included += json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            raise UserError(f"--include {path}: not a benchmarks.plant JSON file ({err})") from None
    return included


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        args = _parser().parse_args(argv)
        included = _included(args.include)
        if args.only_include and not included:
            raise UserError("--only-include needs at least one --include JSON file")
        platforms = [p.strip() for p in args.platforms.split(",") if p.strip()]
        unknown = [p for p in platforms if p not in KNOWN_PLATFORMS]
        if unknown or not platforms:
            raise UserError(f"--platforms {args.platforms!r}: unknown backend {', '.join(unknown) or '(none given)'}; "
                            f"known: {', '.join(KNOWN_PLATFORMS)}")
        results = [] if args.only_include else run(
            args.campaign, args.batches, args.steps, args.repeats, platforms,
            progress=lambda line: print(line, file=sys.stderr))
        if not args.only_include and not results:
            raise UserError(f"--platforms {args.platforms}: none of these JAX backends is on this machine; nothing "
                            f"was measured and {args.write} was left as it was")
        if args.json:
            files.atomic_write_bytes(args.json, json.dumps(results, indent=1).encode())
        text = markdown(included + results, section.command("plant", argv))
        section.publish("plant", text, args)
        return 0

    return section.run_main("plant", body)


if __name__ == "__main__":
    sys.exit(main())
