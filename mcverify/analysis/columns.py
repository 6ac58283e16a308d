"""An episode table as typed numpy columns, converted once (the summary's working form).

Booleans with null read as False, numbers as float64 with null as NaN, anything else as an object
array; the accessors below never raise for a column a run does not have.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc


class Columns:
    """An episode table as numpy columns, converted once: booleans (null = False), numbers as
    float64 (null = NaN), anything else as an object array. ``take`` selects rows."""

    def __init__(self, data: Mapping[str, np.ndarray], num_rows: int) -> None:
        self._data = dict(data)
        self.num_rows = num_rows
        self.column_names = tuple(self._data)

    @classmethod
    def from_table(cls, t: pa.Table) -> Columns:
        data = {}
        for name in t.column_names:
            col = t.column(name)
            if pa.types.is_boolean(col.type):
                data[name] = np.asarray(pc.fill_null(col, False).to_numpy(zero_copy_only=False), dtype=bool)
            elif pa.types.is_integer(col.type) and col.null_count == 0:
                # numpy's conversion, not Arrow's checked cast: a 64-bit seed above 2**53 (valid in a
                # campaign) is not exactly representable and Arrow refuses it; nothing here does
                # arithmetic on seeds, and every smaller integer converts exactly either way.
                data[name] = np.asarray(col.to_numpy(zero_copy_only=False)).astype(np.float64)
            elif pa.types.is_integer(col.type) or pa.types.is_floating(col.type):
                data[name] = np.asarray(pc.cast(col, pa.float64()).to_numpy(zero_copy_only=False), dtype=np.float64)
            else:
                data[name] = np.asarray(col.to_pylist(), dtype=object)
        return cls(data, t.num_rows)

    def __getitem__(self, name: str) -> np.ndarray:
        return self._data[name]

    def drop(self, names: Sequence[str]) -> Columns:
        return Columns({k: v for k, v in self._data.items() if k not in names}, self.num_rows)

    def take(self, rows: np.ndarray) -> Columns:
        rows = np.asarray(rows, dtype=np.int64)
        return Columns({k: v[rows] for k, v in self._data.items()}, int(rows.size))


def bools(t: Columns, name: str) -> np.ndarray:
    x = t[name]
    return x if x.dtype == bool else np.array([bool(v) if v is not None else False for v in x], dtype=bool)


def floats(t: Columns, name: str) -> np.ndarray:
    x = t[name]
    if x.dtype == np.float64:
        return x
    return np.array([math.nan if v is None else float(v) for v in x], dtype=np.float64)


def strings(t: Columns, name: str) -> np.ndarray:
    if name not in t.column_names:
        return np.full(t.num_rows, "", dtype=object)
    return t[name].astype(object)
