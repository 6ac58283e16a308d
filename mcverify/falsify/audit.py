"""Audit a search's counterexamples with the reference solver: ``mcverify report SEARCH_DIR --audit``.

Every counterexample of a search is an episode of one of its generation folders, which are run folders:
each is audited as a run's episode is (:func:`mcverify.campaign.audit.audit`: the same noise and draws,
IPOPT at every step) and the audit kept in that generation folder's ``audits.json``, so an episode is
never audited twice and the search's report shows every kept audit beside its counterexample. The verdict
is on the search's requirement: "confirmed" when the reference solver violates it too.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from mcverify.campaign.audit import AuditResult, audit, record, recorded
from mcverify.falsify import generation_folder


def key(rec: Mapping[str, Any]) -> str:
    """A counterexample's key among the search's audits: its replay id ``gG/E``."""
    return f"g{int(rec['generation']):03d}/{int(rec['episode_id'])}"


def kept(out_dir: Path, records: Sequence[Mapping[str, Any]]) -> dict[str, dict] | None:
    """The audits kept in the generation folders of ``records``, by :func:`key`; None when none was ever made."""
    found: dict[str, dict] = {}
    for generation in sorted({int(r["generation"]) for r in records}):
        for episode, entry in recorded(generation_folder.path(out_dir, generation)).items():
            found[f"g{generation:03d}/{episode}"] = entry
    return found or None


def audit_all(out_dir: Path, records: Sequence[Mapping[str, Any]], requirement: str,
              progress: Callable[[str], None] = lambda msg: None) -> list[AuditResult]:
    """Audit every counterexample in ``records`` not audited yet on the search's ``requirement`` (a named
    one: whether the reference solver violates it too), keeping each in its generation folder."""
    done = kept(out_dir, records) or {}
    todo = [r for r in records if key(r) not in done]
    results = []
    for k, rec in enumerate(todo):
        gen_dir = generation_folder.path(out_dir, rec["generation"])
        progress(f"auditing counterexample {key(rec)} with the reference solver ({k + 1} of {len(todo)})")
        res = audit(gen_dir, int(rec["episode_id"]), requirement=requirement)
        record(gen_dir, res)
        progress(f"{key(rec)}: {res.describe()}")
        results.append(res)
    return results
