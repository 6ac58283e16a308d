"""The figure of ``python -m benchmarks.continuation``: every estimate of the rare cell against the moved
parameter on a log axis, with crude Monte Carlo and the stratified lower bounds beside them (from
:mod:`benchmarks.continuation`'s records)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from benchmarks.continuation import Crude, Estimate, Stratified, order


def figure(points: Sequence[Estimate], crude: Mapping[float, Crude], parameter: str, path: Path,
           bounds: Mapping[float, Stratified] | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    kinds = list(dict.fromkeys(s.label for s in sorted(points, key=order)))
    positive = [v for s in points for v in (s.estimate, s.high) if v > 0] + [
        v for c in crude.values() for v in (c.rate, c.high) if v > 0] + [b.lower for b in (bounds or {}).values()
                                                                         if b.lower > 0]
    floor = min(positive) / 3.0 if positive else 1e-6  # where an estimate of 0 is drawn (a log axis has no 0)
    labelled = set()
    for s in sorted(points, key=lambda p: p.value):
        k = kinds.index(s.label)
        if not s.estimate > 0:
            ax.plot([s.value + 0.01 * (1 + 2 * k)], [floor], marker="v", color=f"C{(0, 2, 3, 4, 6, 7)[k % 6]}",
                    linestyle="none", label=f"{s.label}: estimate 0")
            continue
        low = max(s.low, s.estimate / 100.0)  # an interval can reach below 0: drawn down to the axis' floor
        ax.errorbar([s.value + 0.01 * (1 + 2 * k)], [s.estimate], yerr=[[s.estimate - low], [s.high - s.estimate]],
                    fmt="o^sdPh"[k % 6], color=f"C{(0, 2, 3, 4, 6, 7)[k % 6]}", capsize=3,
                    label=None if s.label in labelled else s.label)
        labelled.add(s.label)
    crude_labels = set()
    for c in sorted(crude.values(), key=lambda p: p.value):
        label = "crude Monte Carlo" if c.k else "crude: upper bound"
        shown = label if label not in crude_labels else None  # one legend entry per kind of crude point
        crude_labels.add(label)
        if c.k:
            ax.errorbar([c.value - 0.01], [c.rate], yerr=[[c.rate - c.low], [c.high - c.rate]], fmt="X", color="C1",
                        capsize=3, label=shown)
        else:
            ax.plot([c.value - 0.01], [c.high], marker="v", color="C1", label=shown)
    for i, b in enumerate(sorted((bounds or {}).values(), key=lambda p: p.value)):
        if b.lower > 0:  # a bound of 0 says nothing and has no place on a log axis
            ax.plot([b.value - 0.02], [b.lower], marker="^", color="C5", linestyle="none",
                    label="stratified lower bound" if i == 0 else None)
    ax.set_yscale("log")
    ax.set_xlabel(parameter)
    ax.set_ylabel(f"P({points[0].target})")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize="small")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


