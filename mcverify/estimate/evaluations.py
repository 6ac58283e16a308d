"""The episodes an importance-sampling cell has already evaluated, kept on disk while the cell runs
(``evaluated_cellNNN.jsonl``), so that ``--resume`` after an interrupt continues the cell instead of
starting it again.

The cross-entropy iterations and final draws of a cell are deterministic given the scores of their
episodes (the draws follow the campaign seed, the cell and the episode ids), so a resumed cell asks
for the same episodes with the same scenario values and noise tilt, in the same batches. A batch whose
every episode is in the file with those inputs takes its rows from the file; anything else runs.
One JSON line per episode, appended and fsync'ed after each finished batch:
``{"episode": id, "values": [...], "tilt": {...} | null, "row": {...}}``. A line cut short by a
kill is cut off when the file is read again. Rows hold plain Python values (floats, ints, bools,
strings, lists, None), which JSON gives back exactly (floats by their shortest repr, NaN and
infinities as JSON's extensions). The file is removed once the cell's result is stored.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mcverify.errors import RunError


def cache_file(out: Path, cell_index: int) -> Path:
    """Where cell ``cell_index`` keeps its evaluated episodes while it runs."""
    return Path(out) / f"evaluated_cell{cell_index:03d}.jsonl"


def _plain(x: Any) -> Any:
    """``x`` as JSON gives it back (tuples become lists), for comparing inputs."""
    return json.loads(json.dumps(x))


class EvaluationCache:
    """Evaluated episodes of one cell by episode id, read from and appended to ``path``."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._records: dict[int, dict[str, Any]] = {}
        if self.path.exists():
            text = self.path.read_text()
            if not text.endswith("\n"):  # a killed append: drop its fragment, so the next append starts a line
                text = text[:text.rfind("\n") + 1]
                self.path.write_text(text)
            for number, line in enumerate(text.splitlines(), start=1):
                try:
                    rec = json.loads(line)
                    if not isinstance(rec["row"], dict) or not isinstance(rec["values"], list) or "tilt" not in rec:
                        raise ValueError("not an evaluated episode")
                    self._records[int(rec["episode"])] = rec
                except (ValueError, KeyError, TypeError) as err:
                    raise RunError(f"{self.path} line {number} is damaged ({err}); delete the file to run the cell "
                                   "in progress from its start") from None

    def __len__(self) -> int:
        return len(self._records)

    def rows(self, ids: Sequence[int], values: Mapping[int, Sequence[float]], tilt: Any) -> list[dict] | None:
        """The stored rows of episodes ``ids`` when every one was evaluated with ``values[id]`` and the
        noise tilt ``tilt`` (a mapping or None); otherwise None (the batch must run)."""
        want_tilt = _plain(tilt)
        out = []
        for e in ids:
            rec = self._records.get(int(e))
            if rec is None or rec["values"] != _plain(list(values[e])) or rec["tilt"] != want_tilt:
                return None
            out.append(rec["row"])
        return out

    def add(self, rows: Sequence[dict[str, Any]], values: Mapping[int, Sequence[float]], tilt: Any) -> None:
        """Append one finished batch (rows carrying ``cell_episode``) and make it durable."""
        lines = []
        for row in rows:
            e = int(row["cell_episode"])
            rec = {"episode": e, "values": list(values[e]), "tilt": _plain(tilt), "row": row}
            lines.append(json.dumps(rec))
            self._records[e] = _plain(rec)
        with open(self.path, "a") as fh:
            fh.write("".join(line + "\n" for line in lines))
            fh.flush()
            os.fsync(fh.fileno())

    def remove(self) -> None:
        """Forget the file (the cell's result is stored)."""
        self.path.unlink(missing_ok=True)
