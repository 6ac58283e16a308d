"""Run a campaign into a run folder: plan chunks, execute them, merge, summarise, report.

Finished chunks are written as they complete, so an interrupted run loses at most the chunks in
flight; ``resume`` re-plans from the manifest and runs only the chunks without a valid file.
"""

from __future__ import annotations

import dataclasses
import json
from datetime import datetime
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from mcverify import executors, report, store
from mcverify.campaign import Campaign, campaign_from_dict


def default_run_dir(campaign: Campaign, results_dir: Path = Path("results")) -> Path:
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    return results_dir / f"{campaign.name}-{stamp}"


def manifest_for(campaign: Campaign, chunk_size: int, kernels: dict[str, str]) -> dict[str, Any]:
    return {
        "format": 1,
        "campaign": {
            "name": campaign.name,
            "description": campaign.description,
            "source": campaign.source,
            "seed": campaign.seed,
            "episodes_per_cell": campaign.episodes_per_cell,
            "common_random_numbers": campaign.common_random_numbers,
            "grid": campaign.grid,
            "axes": campaign.axes,
            "reference": campaign.reference,
            "raw": campaign.raw,
        },
        "cells": [
            {
                "index": c.index,
                "name": c.name,
                "labels": c.labels,
                "controller": c.controller,
                "overrides": c.overrides,
                "episodes": c.episodes,
                "episode_offset": c.episode_offset,
                "epsilon": c.epsilon,
                "lambda0": c.lambda0,
                "params": dataclasses.asdict(c.params),
            }
            for c in campaign.cells
        ],
        "chunk_size": chunk_size,
        "kernels": kernels,
        "environment": store.environment_info(),
    }


def campaign_from_manifest(manifest: dict[str, Any]) -> Campaign:
    """Rebuild the exact campaign a run used (the file's content plus the CLI's overrides)."""
    camp = manifest["campaign"]
    return campaign_from_dict(
        camp["raw"], source=camp["source"], episodes=camp["episodes_per_cell"], seed=camp["seed"]
    )


def run(
    campaign: Campaign,
    run_dir: Path,
    *,
    workers: int = 1,
    chunk_size: int = 8,
    progress: bool = True,
) -> Path:
    """Run ``campaign`` into a new folder ``run_dir``; returns the report path."""
    run_dir = Path(run_dir)
    if (run_dir / store.MANIFEST).exists():
        raise store.RunError(f"{run_dir} already holds a run; choose another --out or use --resume")
    run_dir.mkdir(parents=True, exist_ok=True)
    # Build (or load) every cell's kernel here, once, before any worker starts: workers then
    # only load the cached shared object and never race to compile it.
    kernels = {c.name: executors.solver_for(c.params).kernel_hash for c in campaign.cells}
    manifest = manifest_for(campaign, chunk_size, kernels)
    store.write_json_atomic(run_dir / store.MANIFEST, manifest)
    return _execute(campaign, run_dir, chunk_size, workers, progress)


def resume(run_dir: Path, *, workers: int = 1, progress: bool = True) -> Path:
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise store.RunError(f"run folder not found: {run_dir}")
    manifest = store.read_json(run_dir / store.MANIFEST)
    campaign = campaign_from_manifest(manifest)
    return _execute(campaign, run_dir, int(manifest["chunk_size"]), workers, progress)


def _execute(campaign: Campaign, run_dir: Path, chunk_size: int, workers: int, progress: bool) -> Path:
    chunks = store.plan_chunks([c.episodes for c in campaign.cells], chunk_size)
    todo = [c for c in chunks if store.read_chunk(run_dir, c) is None]
    done_episodes = sum(len(c.episode_ids) for c in chunks) - sum(len(c.episode_ids) for c in todo)
    bar = tqdm(
        total=campaign.total_episodes,
        initial=done_episodes,
        unit="ep",
        desc=campaign.name,
        disable=not progress,
        dynamic_ncols=True,
    )

    def on_done(chunk: store.Chunk, rows: list[dict]) -> None:
        store.write_chunk(run_dir, chunk, rows)
        unsafe = sum(not r["safe"] for r in rows)
        bar.update(len(rows))
        if unsafe:
            bar.set_postfix_str(f"unsafe so far in this chunk: {unsafe}")

    with bar:
        executors.execute(campaign, todo, on_done, workers=workers)
    store.merge_chunks(run_dir, chunks)
    return report.write(run_dir)


def describe(campaign: Campaign) -> str:
    lines = [f"{campaign.name}: {len(campaign.cells)} cells x {campaign.episodes_per_cell} episodes"]
    for c in campaign.cells:
        lines.append(f"  [{c.index}] {c.name}  eps={c.epsilon:.3g} lambda0={c.lambda0:.4g}")
    return "\n".join(lines)


def dumps(obj: Any) -> str:
    return json.dumps(obj, indent=2, default=str)
