"""The crude Monte Carlo reference of ``python -m benchmarks.validation``: the episodes of one cell's crude
folders (``mcverify estimate --method mc`` folders, or ``mcverify run`` folders with a target), each folder's
gap-free prefix in the pre-assigned order and the folders one after another, and p = k / n with its fixed-n
Clopper-Pearson interval (n was set by the clock or the budget, not by the outcomes)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mcverify import store
from mcverify.analysis.columns import Columns, floats
from mcverify.analysis.estimates import ordered_prefix, target_events
from mcverify.analysis.intervals import proportion_interval
from mcverify.errors import RunError
from mcverify.reporting.compare import flat_params


@dataclass(frozen=True)
class Reference:
    """The crude reference: k events of ``target`` in the first n episodes of ``cell``, p = k / n with
    its Clopper-Pearson interval, and the mean control steps of an episode."""

    run_dirs: tuple[str, ...]
    campaign: str
    cell: str
    target: str
    n: int
    k: int
    p: float
    low: float
    high: float
    errors: int
    mean_episode_steps: float
    seeds: tuple[int, ...] = ()  # the folders' campaign seeds: an estimator run with one would replay its episodes
    params: dict[str, Any] = field(default_factory=dict)  # the cell's model, flattened (dotted keys)


@dataclass(frozen=True)
class CrudeSequence:
    """The reference's episodes in order: whether each showed ``target``, its control steps, the errors left out,
    and the first folder's manifest (the cell's)."""

    manifest: dict[str, Any]
    target: str
    events: np.ndarray
    steps: np.ndarray
    errors: int
    seeds: tuple[int, ...]


def manifest_of(run_dir: Path) -> dict[str, Any]:
    """A run or estimate folder's manifest (one line if ``run_dir`` is neither)."""
    if not (Path(run_dir) / store.MANIFEST).exists():
        raise RunError(f"{run_dir} is not a run or estimate folder (no {store.MANIFEST})")
    return store.read_manifest(Path(run_dir))


def reference(run_dirs: Path | Sequence[Path], level: float = 0.95, target: str | None = None) -> Reference:
    """The reference of crude Monte Carlo folders of one cell (see the module docstring)."""
    dirs = as_dirs(run_dirs)
    return reference_of(dirs, reference_sequence(dirs, target), level)


def as_dirs(run_dirs: Path | Sequence[Path]) -> list[Path]:
    """One folder or several, as a list."""
    return [Path(run_dirs)] if isinstance(run_dirs, str | Path) else [Path(d) for d in run_dirs]


def reference_of(dirs: Sequence[Path], seq: CrudeSequence, level: float) -> Reference:
    """The reference of the folders ``dirs`` whose episodes are ``seq``."""
    n, k = int(seq.events.size), int(seq.events.sum())
    ci = proportion_interval(k, n, level)
    cell = seq.manifest["cells"][0]
    return Reference(tuple(str(d) for d in dirs), seq.manifest["campaign"]["name"], cell["name"], seq.target, n, k,
                     k / n, ci.low, ci.high, seq.errors, float(np.mean(seq.steps)), seq.seeds,
                     flat_params(cell.get("params", {})))


def reference_sequence(run_dirs: Path | Sequence[Path], target: str | None = None) -> CrudeSequence:
    """The valid episodes of each crude folder's gap-free prefix, in their pre-assigned order, folder after folder.
    ``target`` is required for run folders; an estimate folder's is its own. The folders must hold one cell, the
    same in each, with the same target and distinct seeds."""
    dirs = as_dirs(run_dirs)
    parts = [_folder_sequence(d, target) for d in dirs]
    first = parts[0]
    for d, part in zip(dirs[1:], parts[1:], strict=True):
        if part.manifest["campaign"]["name"] != first.manifest["campaign"]["name"] or part.target != first.target:
            raise RunError(f"{d} counts {part.target!r} of {part.manifest['campaign']['name']!r}; {dirs[0]} counts "
                           f"{first.target!r} of {first.manifest['campaign']['name']!r}")
        mine, theirs = (flat_params(x.manifest["cells"][0].get("params", {})) for x in (part, first))
        if mine != theirs:
            differ = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))
            raise RunError(f"{d} holds another cell than {dirs[0]} (they differ in {', '.join(differ[:3])})")
    seeds = tuple(seed for part in parts for seed in part.seeds)
    if len(set(seeds)) != len(seeds):
        raise RunError("two reference folders have the same seed: the same episodes; give one of them")
    return CrudeSequence(first.manifest, first.target, np.concatenate([p.events for p in parts]),
                         np.concatenate([p.steps for p in parts]), sum(p.errors for p in parts), seeds)


def _folder_sequence(run_dir: Path, target: str | None) -> CrudeSequence:
    manifest = manifest_of(run_dir)
    target = _reference_target(run_dir, manifest.get("estimate"), target)
    if len(manifest["cells"]) != 1:
        raise RunError(f"{run_dir} has {len(manifest['cells'])} cells; the reference must have one")
    tables = []
    for rec in store.read_ledger(Path(run_dir)).values():
        chunk = store.Chunk(rec.cell_index, tuple(range(rec.first_episode, rec.last_episode + 1)))
        if store.verify_chunk(Path(run_dir), chunk, rec):
            tables.append(store.read_chunk(Path(run_dir), chunk))
    if not tables:
        raise RunError(f"{run_dir} holds no finished episode")
    cols = Columns.from_table(pa.concat_tables(tables, promote_options="default"))
    cols = cols.take(np.argsort(floats(cols, "cell_episode"), kind="stable"))
    m = ordered_prefix(floats(cols, "cell_episode").astype(np.int64))
    event, valid = target_events(cols, target)
    event, valid = event[:m], valid[:m]
    steps = floats(cols, "steps")[:m][valid]
    return CrudeSequence(manifest, target, event[valid], steps, int(m - valid.sum()),
                         (int(manifest["campaign"]["seed"]),))


def _reference_target(run_dir: Path, spec: dict[str, Any] | None, target: str | None) -> str:
    """The event a reference counts: a crude estimate's own target, or ``target`` for a run folder."""
    if spec is None:
        if target is None:
            raise RunError(f"{run_dir} is a run folder (mcverify run): give --target to say which event it counts")
        return target
    if spec.get("method") != "mc":
        raise RunError(f"{run_dir} is a {spec.get('method')} estimate; the reference must be crude Monte Carlo "
                       "(mcverify estimate --method mc, or a mcverify run folder)")
    if target is not None and target != spec["target"]:
        raise RunError(f"{run_dir} estimates {spec['target']!r}; --target {target} asks for another event")
    return str(spec["target"])
