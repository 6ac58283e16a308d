"""``mcverify compare RUN_A RUN_B``: per-cell differences between two runs, with intervals.

Cells are matched by name (or by explicit ``--pair CELL_A CELL_B``, which may also compare two
cells of one run); cells of one run without a match are listed, never dropped silently.

Paired or unpaired is decided per matched pair from how the runs derive their episode keys
(``rollout.episode_key``): an episode's disturbances and scenario draws come from
(seed, cell index, cell episode), or from (seed, cell episode) when the campaign sets
``common_random_numbers``. When both runs give episode ``e`` of the two cells the same key (same
seed, and both with common random numbers or both without and the same cell index), episode ``e``
saw identical disturbances under A and B: the comparison is **paired** over the episodes both ran
(the exact McNemar test and the interval for the difference of rates that agrees with it; paired
bootstrap for differences of means). Otherwise it is **unpaired** (the Miettinen-Nurminen score
interval and the score test it inverts). Either way the interval excludes 0 exactly when the test
rejects at the same level (:mod:`mcverify.analysis.comparisons`). The output says which and why,
for every cell.
Episodes whose outcome is ``error`` are left out (and counted). The model fields in which two
compared cells differ (read from each run's manifest) are listed, so that what was varied is on the
page, not only which runs were compared.
"""

from __future__ import annotations

import json
import math
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mcverify import store
from mcverify.analysis import stats, summary
from mcverify.analysis.cells import json_ready
from mcverify.analysis.metrics import METRICS
from mcverify.errors import RunError
from mcverify.reporting.tables import DASH, Section, Table, fmt_num, fmt_p, is_missing, to_latex, to_markdown

#: Rates compared (those both runs have).
RATES = ("safe", "collision", "collision_front", "collision_opp", "ellipse_violation", "invariance_breach",
         "opp_invariance_breach", "overtook", "went_back", "timeout")
#: Values whose means are compared (and whose minima are shown).
VALUES = ("min_dist_front_m", "min_gap_front_m", "min_gap_opp_m", "min_gap_opp_any_m", "min_h_front",
          "overtake_time_s")


@dataclass(frozen=True)
class Run:
    """A finished run folder: ``label`` (the folder's name, never an absolute path), manifest and
    episodes."""

    label: str
    manifest: Mapping[str, Any]
    table: pa.Table

    @property
    def seed(self) -> int:
        return int(self.manifest["campaign"]["seed"])

    @property
    def crn(self) -> bool:
        return bool(self.manifest["campaign"].get("common_random_numbers", False))

    def cells(self) -> list[str]:
        names = [c["name"] for c in sorted(self.manifest.get("cells", []), key=lambda c: c["index"])]
        for n in self.table.column("cell").to_pylist() if self.table.num_rows else []:
            if n not in names:
                names.append(n)
        return names

    def cell_index(self, name: str) -> int | None:
        for c in self.manifest.get("cells", []):
            if c["name"] == name:
                return int(c["index"])
        return None

    def opposing_kind(self, name: str) -> str | None:
        """The cell's opposing vehicle ("none", "human", "autonomous"), None if not recorded."""
        for c in self.manifest.get("cells", []):
            if c["name"] == name:
                return (c.get("params") or {}).get("opposing", {}).get("kind")
        return None

    def params(self, name: str) -> dict[str, Any]:
        """The cell's resolved model fields, flattened to ``section.field`` (empty if not recorded)."""
        for c in self.manifest.get("cells", []):
            if c["name"] == name:
                return flat_params(c.get("params") or {})
        return {}

    def rows(self, name: str) -> pa.Table:
        mask = np.array([n == name for n in self.table.column("cell").to_pylist()], dtype=bool)
        return self.table.filter(pa.array(mask))


def load_run(run_dir: Path) -> Run:
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise RunError(f"run folder not found: {run_dir}")
    manifest = store.read_json(run_dir / store.MANIFEST)
    return Run(run_dir.resolve().name, manifest, store.read_episodes(run_dir))


def flat_params(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """A cell's nested model as dotted keys (``noise.scale``), for comparing two cells."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, Mapping):
            out.update(flat_params(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def model_differences(a: Run, cell_a: str, b: Run, cell_b: str) -> list[dict[str, Any]]:
    """The model fields whose resolved values differ between the two cells, in field order:
    ``{"field", "a", "b"}`` (None where one side does not have the field)."""
    pa_, pb = a.params(cell_a), b.params(cell_b)
    fields = list(pa_) + [f for f in pb if f not in pa_]
    return [{"field": f, "a": pa_.get(f), "b": pb.get(f)} for f in fields if pa_.get(f) != pb.get(f)]


def pairing(a: Run, cell_a: str, b: Run, cell_b: str) -> tuple[bool, str]:
    """Whether episode e of ``cell_a`` in run A and of ``cell_b`` in run B share their key, and why."""
    if a.seed != b.seed:
        return False, f"the runs use different seeds ({a.seed} and {b.seed}), so their disturbances differ"
    if a.crn and b.crn:
        return True, (f"both runs use seed {a.seed} with common random numbers: episode e of either cell drew its "
                      "disturbances from the key (seed, e)")
    if a.crn != b.crn:
        return False, "one run uses common random numbers and the other does not, so their episode keys differ"
    ia, ib = a.cell_index(cell_a), b.cell_index(cell_b)
    if ia is None or ib is None or ia != ib:
        return False, (f"without common random numbers the key is (seed, cell index, e) and the cell indices differ "
                       f"({ia} and {ib})")
    return True, (f"both runs use seed {a.seed}, no common random numbers and cell index {ia}: episode e of either "
                  "cell drew its disturbances from the key (seed, cell index, e)")


def compare_runs(
    a: Run,
    b: Run,
    *,
    level: float = 0.95,
    pairs: Sequence[tuple[str, str]] | None = None,
    bootstrap_resamples: int = 2000,
) -> dict[str, Any]:
    """Every matched cell pair compared; see the module docstring. Returns a JSON-friendly dict
    with ``run_a``/``run_b`` (label, campaign, seed, common random numbers), ``level``,
    ``comparisons`` (one per pair), ``only_in_a``/``only_in_b``."""
    stats.rate_summary(0, 1, level)  # checks level
    names_a, names_b = a.cells(), b.cells()
    if pairs:
        for ca, cb in pairs:
            if ca not in names_a:
                raise RunError(f"--pair: run A ({a.label}) has no cell {ca!r}; its cells: {'; '.join(names_a)}")
            if cb not in names_b:
                raise RunError(f"--pair: run B ({b.label}) has no cell {cb!r}; its cells: {'; '.join(names_b)}")
        matched = list(pairs)
        only_a = [n for n in names_a if n not in {p[0] for p in pairs}]
        only_b = [n for n in names_b if n not in {p[1] for p in pairs}]
    else:
        matched = [(n, n) for n in names_a if n in names_b]
        only_a = [n for n in names_a if n not in names_b]
        only_b = [n for n in names_b if n not in names_a]
    comparisons = [_compare_cells(a, ca, b, cb, level, bootstrap_resamples) for ca, cb in matched]
    describe = lambda r: {"label": r.label, "campaign": r.manifest["campaign"]["name"], "seed": r.seed,  # noqa: E731
                          "common_random_numbers": r.crn,
                          "settings": list(r.manifest["campaign"].get("settings") or [])}
    return {
        "run_a": describe(a),
        "run_b": describe(b),
        "level": level,
        "explicit_pairs": bool(pairs),
        "comparisons": comparisons,
        "only_in_a": only_a,
        "only_in_b": only_b,
    }


def _compare_cells(a: Run, cell_a: str, b: Run, cell_b: str, level: float, resamples: int) -> dict:
    ta, tb = a.rows(cell_a), b.rows(cell_b)
    paired, reason = pairing(a, cell_a, b, cell_b)
    ok_a, ok_b = _not_error(ta), _not_error(tb)
    errors = {"a": int((~ok_a).sum()), "b": int((~ok_b).sum())}
    ep_a = np.asarray(ta.column("cell_episode").to_pylist(), dtype=np.int64)
    ep_b = np.asarray(tb.column("cell_episode").to_pylist(), dtype=np.int64)
    ia = ib = None
    if paired:
        common = np.intersect1d(ep_a[ok_a], ep_b[ok_b])
        if common.size == 0:
            paired, reason = False, reason + "; but no episode ran (without error) in both, so the test is unpaired"
        else:
            ia = np.array([int(np.flatnonzero(ep_a == e)[0]) for e in common])
            ib = np.array([int(np.flatnonzero(ep_b == e)[0]) for e in common])
            left = int(ok_a.sum() + ok_b.sum() - 2 * common.size)
            if left:
                reason += f"; {left} episode(s) ran in one cell only and are left out"
    # without an opposing vehicle in either cell its metrics are placeholders (False / NaN)
    no_opp = a.opposing_kind(cell_a) == "none" and b.opposing_kind(cell_b) == "none"
    skip = set(summary.OPPOSING_METRICS) | {"collision"} if no_opp else set()
    rates = {}
    for name in (r for r in RATES if r not in skip):
        fa, fb = _flags(ta, name), _flags(tb, name)
        if fa is None or fb is None:
            continue
        if paired:
            r = stats.compare_paired(fa[ia], fb[ib], level=level)
            rates[name] = {**r, "k_a": r["both"] + r["only_a"], "k_b": r["both"] + r["only_b"], "n_a": r["n"],
                           "n_b": r["n"]}
        else:
            ka, na, kb, nb = int(fa[ok_a].sum()), int(ok_a.sum()), int(fb[ok_b].sum()), int(ok_b.sum())
            if na == 0 or nb == 0:
                continue
            r = stats.compare_unpaired(ka, na, kb, nb, level=level)
            rates[name] = {**r, "k_a": ka, "n_a": na, "k_b": kb, "n_b": nb}
    values = {}
    for name in (v for v in VALUES if v not in skip):
        if name not in ta.column_names or name not in tb.column_names:
            continue
        va, vb = _floats(ta, name), _floats(tb, name)
        seed = zlib.crc32(f"{cell_a}/{cell_b}/{name}".encode())
        if paired:
            d = stats.bootstrap_mean_difference(va[ia], vb[ib], paired=True, level=level, n_resamples=resamples,
                                                seed=seed)
        else:
            d = stats.bootstrap_mean_difference(va[ok_a], vb[ok_b], paired=False, level=level, n_resamples=resamples,
                                                seed=seed)
        fa_, fb_ = va[ok_a & np.isfinite(va)], vb[ok_b & np.isfinite(vb)]
        d["min_a"] = float(fa_.min()) if fa_.size else math.nan
        d["min_b"] = float(fb_.min()) if fb_.size else math.nan
        values[name] = d
    return {
        "cell_a": cell_a,
        "cell_b": cell_b,
        "paired": paired,
        "reason": reason,
        "pairs": int(ia.size) if paired else 0,
        "episodes_a": int(ok_a.sum()),
        "episodes_b": int(ok_b.sum()),
        "errors": errors,
        "rates": rates,
        "values": values,
        "model_differences": model_differences(a, cell_a, b, cell_b),
    }


def _not_error(t: pa.Table) -> np.ndarray:
    if "outcome" not in t.column_names:
        return np.ones(t.num_rows, dtype=bool)
    return np.array([o != "error" for o in t.column("outcome").to_pylist()], dtype=bool)


def _flags(t: pa.Table, name: str) -> np.ndarray | None:
    if name == "collision":
        present = [c for c in ("collision_front", "collision_opp") if c in t.column_names]
        return np.logical_or.reduce([_flags(t, c) for c in present]) if present else None
    if name not in t.column_names:
        return None
    return np.array([bool(x) for x in t.column(name).to_pylist()], dtype=bool)


def _floats(t: pa.Table, name: str) -> np.ndarray:
    return np.array([math.nan if x is None else float(x) for x in t.column(name).to_pylist()], dtype=np.float64)


# ------------------------------------------------------------------------------------ rendering


def _pair_label(c: Mapping[str, Any]) -> str:
    return c["cell_a"] if c["cell_a"] == c["cell_b"] else f"{c['cell_a']} vs {c['cell_b']}"


def tables(result: Mapping[str, Any]) -> list[Table]:
    """The comparison as three tables: how each cell pair is compared and why, the rates (one
    block per pair) and the distances and times (one block per pair)."""
    comps = result["comparisons"]
    if not comps:
        return []
    level = result["level"]
    test_name = "score test"
    out = [Table(
        "compare-method", "How each cell pair is compared",
        ["cell (A vs B)", "test", "episodes", "why"],
        [[_pair_label(c),
          "paired: exact McNemar" if c["paired"] else f"unpaired: {test_name}",
          f"{c['pairs']} pairs" if c["paired"] else f"{c['episodes_a']} vs {c['episodes_b']}",
          c["reason"] + (f"; errors left out: {c['errors']['a']} in A, {c['errors']['b']} in B"
                         if c["errors"]["a"] or c["errors"]["b"] else "")]
         for c in comps],
        [f"A = {result['run_a']['label']} (campaign {result['run_a']['campaign']}), B = {result['run_b']['label']} "
         f"(campaign {result['run_b']['campaign']})."],
        align="llll",
    )]
    model = _model_table(comps)
    if model is not None:
        out.append(model)
    rows: list[list[str] | Section] = []
    for c in comps:
        if not c["rates"]:
            continue
        rows.append(Section(f"{_pair_label(c)} ({'paired, McNemar' if c['paired'] else 'unpaired, ' + test_name})"))
        for name in RATES:
            r = c["rates"].get(name)
            if not r:
                continue
            rows.append([
                METRICS[name].label, f"{r['k_a']}/{r['n_a']}", f"{r['k_b']}/{r['n_b']}",
                f"{fmt_num(r['diff'], 3, signed=True)} [{fmt_num(r['low'], 3, signed=True)}, "
                f"{fmt_num(r['high'], 3, signed=True)}]",
                fmt_p(r["p_value"]),
                f"{r['only_a']} / {r['only_b']}" if c["paired"] else DASH,
            ])
    if rows:
        out.append(Table(
            "compare-rates", "Rates: A − B",
            ["rate", "A", "B", f"A − B [{level:.0%} CI]", "p-value", "discordant (A only / B only)"], rows,
            ["Interval for the difference of rates and p-value: paired, the two-sided exact McNemar test and the "
             "interval that agrees with it (Clopper-Pearson on the discordant pairs); unpaired, the "
             "Miettinen-Nurminen score interval and the score test it inverts. Either way the interval "
             "excludes 0 exactly when p < " + f"{1 - level:.2g}" + ". Discordant pairs: episodes where only A, or "
             "only B, had the event."],
        ))
    rows = []
    for c in comps:
        block = [name for name, d in c["values"].items() if d["n_a"] or d["n_b"]]
        if not block:
            continue
        rows.append(Section(f"{_pair_label(c)} ({'paired' if c['paired'] else 'unpaired'})"))
        for name in block:
            d = c["values"][name]
            if is_missing(d["diff"]):
                diff = DASH
            elif is_missing(d["low"]):
                diff = fmt_num(d["diff"], signed=True)
            else:
                diff = (f"{fmt_num(d['diff'], signed=True)} [{fmt_num(d['low'], signed=True)}, "
                        f"{fmt_num(d['high'], signed=True)}]")
            rows.append([METRICS[name].label, fmt_num(d["min_a"]), fmt_num(d["min_b"]), fmt_num(d["mean_a"]),
                         fmt_num(d["mean_b"]), diff,
                         f"{d['n_a']} pairs" if d["paired"] else f"{d['n_a']} / {d['n_b']}"])
    if rows:
        out.append(Table(
            "compare-values", "Distances and times: A − B",
            ["quantity", "min A", "min B", "mean A", "mean B", f"mean A − B [{level:.0%} CI]", "values used"], rows,
            ["Minima are minima; the difference of means has a percentile-bootstrap interval (of the per-episode "
             "differences when paired; a pair is used when both values exist)."],
        ))
    return out


def _model_value(v: Any) -> str:
    if v is None:
        return DASH
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v) if not isinstance(v, list | tuple) else "[" + ", ".join(_model_value(x) for x in v) + "]"


def _model_table(comps: Sequence[Mapping[str, Any]]) -> Table | None:
    """The model fields that differ, one block per cell pair (one block for all when every pair
    differs in the same way); None when no pair differs (the summary line says so)."""
    diffs = [c.get("model_differences") or [] for c in comps]
    if not any(diffs):
        return None
    row = lambda d: [d["field"], _model_value(d["a"]), _model_value(d["b"])]  # noqa: E731
    if all(d == diffs[0] for d in diffs):
        rows: list[list[str] | Section] = [row(d) for d in diffs[0]]
        scope = "every compared cell pair"
    else:
        rows = []
        for c, d in zip(comps, diffs, strict=True):
            rows.append(Section(f"{_pair_label(c)}: {len(d)} field(s)" if d else f"{_pair_label(c)}: none"))
            rows += [row(x) for x in d]
        scope = "each cell pair"
    return Table("compare-model", "Model fields that differ", ["field", "A", "B"], rows,
                 [f"The resolved model of the two cells ({scope}), as stored in each run's manifest: grid values, "
                  "campaign file and --set settings alike. Fields not listed are equal."], align="lll")


def model_summary(result: Mapping[str, Any]) -> str:
    """One line for the summary: how many model fields differ (or that none do)."""
    diffs = [c.get("model_differences") or [] for c in result["comparisons"]]
    fields = sorted({d["field"] for ds in diffs for d in ds})
    if not fields:
        return "the same in every compared cell pair"
    shown = ", ".join(f"`{f}`" for f in fields[:6]) + (f" and {len(fields) - 6} more" if len(fields) > 6 else "")
    return f"{len(fields)} field(s) differ ({shown}; table \"Model fields that differ\")"


def _settings_text(run: Mapping[str, Any]) -> str:
    """``, --set `a=1`, --set `b=2``` for a run started with command-line settings, else nothing."""
    return "".join(f", --set `{s}`" for s in run.get("settings") or [])


def render_markdown(result: Mapping[str, Any]) -> str:
    a, b = result["run_a"], result["run_b"]
    lines = [
        f"# mcverify compare: {a['label']} vs {b['label']}",
        "",
        f"- **A**: {a['label']} (campaign {a['campaign']}, seed {a['seed']}, common random numbers "
        f"{'yes' if a['common_random_numbers'] else 'no'}{_settings_text(a)})",
        f"- **B**: {b['label']} (campaign {b['campaign']}, seed {b['seed']}, common random numbers "
        f"{'yes' if b['common_random_numbers'] else 'no'}{_settings_text(b)})",
        f"- **cells compared**: {len(result['comparisons'])}"
        + (" (pairs given with --pair)" if result["explicit_pairs"] else " (matched by name)"),
    ]
    if result["only_in_a"]:
        lines.append(f"- **only in A, not compared**: {'; '.join(result['only_in_a'])}")
    if result["only_in_b"]:
        lines.append(f"- **only in B, not compared**: {'; '.join(result['only_in_b'])}")
    if not result["comparisons"]:
        lines.append("- no cell of A matches a cell of B by name; give pairs with `--pair CELL_A CELL_B`")
    else:
        lines.append(f"- **model**: {model_summary(result)}")
    lines.append("")
    for t in tables(result):
        lines += [to_markdown(t), ""]
    return "\n".join(lines)


def write(out_dir: Path, result: Mapping[str, Any]) -> list[Path]:
    """compare.md, compare.json (strict JSON) and compare.tex (booktabs tables) in ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / "compare.md", out_dir / "compare.json", out_dir / "compare.tex"]
    paths[0].write_text(render_markdown(result), encoding="utf-8")
    paths[1].write_text(json.dumps(json_ready(result), indent=2) + "\n", encoding="utf-8")
    paths[2].write_text("\n\n".join(to_latex(t) for t in tables(result)) + "\n", encoding="utf-8")
    return paths
