"""The layers and their import rules (pyproject's [tool.importlinter]) hold, checked by import-linter."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_import_contracts_are_kept() -> None:
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    assert exe, "import-linter is part of the test extra: pip install -e '.[test]'"
    out = subprocess.run([exe, "--no-cache"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert " 0 broken" in out.stdout.split("Contracts:")[-1]


def test_every_subpackage_has_a_docstring_saying_what_it_is() -> None:
    import ast

    for init in sorted((REPO / "mcverify").glob("*/__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text()))
        assert doc and len(doc) > 30, f"{init.relative_to(REPO)} needs a docstring describing its layer"


def test_importing_the_library_leaves_matplotlib_alone() -> None:
    """No import side effects: every module of mcverify imports without loading pyplot or choosing
    matplotlib's backend (figures are drawn as Figure objects and saved by their own canvas)."""
    code = (
        "import importlib, pkgutil, sys, matplotlib, mcverify\n"
        "before = matplotlib.rcParams._get('backend')\n"
        "for m in pkgutil.walk_packages(mcverify.__path__, 'mcverify.'):\n"
        "    if not m.name.endswith('__main__'):\n"
        "        importlib.import_module(m.name)\n"
        "print(matplotlib.rcParams._get('backend') == before, 'matplotlib.pyplot' in sys.modules)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "False"]


def test_the_command_line_is_a_package_of_small_modules() -> None:
    """One module per command: none over about 450 lines (the old cli.py had 1,078)."""
    sizes = {p.name: len(p.read_text().splitlines()) for p in (REPO / "mcverify" / "cli").glob("*.py")}
    assert {"run.py", "estimate.py", "replay.py", "report.py", "compare.py", "falsify.py", "fields.py",
            "kernels.py"} <= set(sizes)
    assert max(sizes.values()) <= 450, sizes
