"""Files written atomically: a temporary name in the same folder, then a rename.

A reader never sees half a file, and a killed writer leaves no file under the final name; the
temporary file gets the mode ``open`` would give (``mkstemp`` makes files 0o600). JSON is written
with :func:`json_default`, so numpy scalars, tuples, sets and paths need no conversion first.
Nothing here knows about run folders (:mod:`mcverify.store`).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq


def _file_mode() -> int:
    """0o666 less the process umask: what ``open`` would give (``mkstemp`` makes files 0o600)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


#: The mode of every file written here.
FILE_MODE = _file_mode()


def atomic_write(path: Path, write: Callable[[str], None]) -> None:
    """Write ``path`` through ``write(temporary_name)`` in the same folder, then rename: a reader
    never sees half a file, and a killed writer leaves no file under the final name."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        os.chmod(tmp, FILE_MODE)
        write(tmp)
        os.replace(tmp, path)
    except OSError as err:
        if err.filename is None:  # pyarrow says "No space left on device" without naming the file
            raise named(err, path) from err
        raise
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def named(err: OSError, path: Path) -> OSError:
    """``err`` naming the file it was writing: the one line the user sees must say which file
    could not be written."""
    return OSError(err.errno, err.strerror or str(err), str(path))


def atomic_write_bytes(path: Path, data: bytes) -> None:
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))


def atomic_parquet(table: pa.Table, path: Path) -> str:
    """Write ``table`` to ``path`` atomically (:func:`atomic_write`); returns the file's SHA-256."""
    digest: list[str] = []

    def write(tmp: str) -> None:
        pq.write_table(table, tmp)
        digest.append(sha256_file(Path(tmp)))

    atomic_write(path, write)
    return digest[0]


def write_json_atomic(path: Path, data: Any) -> None:
    atomic_write_bytes(Path(path), (json.dumps(data, indent=2, sort_keys=False, default=json_default) + "\n").encode())


def json_default(obj: Any) -> Any:
    if hasattr(obj, "item"):
        return obj.item()
    if isinstance(obj, tuple | set):
        return list(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def replace_section(path: Path, section: str, begin: str, end: str) -> None:
    """Replace the generated section of a Markdown file that starts with the line ``begin`` and ends
    with ``end`` (``section`` carries both markers), or append it; the rest of the file is kept.
    Used by the benchmarks that write into results/BENCHMARKS.md."""
    path = Path(path)
    text = path.read_text(encoding="utf-8") if path.is_file() else "# Benchmarks\n\n"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + section.rstrip("\n") + rest.split(end, 1)[1]
    else:
        text = text.rstrip("\n") + "\n\n" + section
    atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as fh:
        fh.seek(-1, os.SEEK_END)
        return fh.read(1) == b"\n"
