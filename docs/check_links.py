"""Check the relative links of the project's Markdown files: every linked file exists and every
#anchor names a heading of its file (GitHub's anchor rules). External links are not fetched.

    python docs/check_links.py            # README.md, docs/, results/, studies/ READMEs
    python docs/check_links.py FILE.md ...

Exit status 1 and one line per broken link when any is broken."""

from __future__ import annotations

import re
import sys
import unicodedata
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"```.*?```", flags=re.S)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped (but - and _), spaces to -."""
    text = heading.strip().lower().replace("`", "")
    kept = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in "LN")
    return kept.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of a Markdown file's headings (a repeated heading gets -1, -2, ...)."""
    found: set[str] = set()
    seen: dict[str, int] = {}
    for line in FENCE.sub("", path.read_text(encoding="utf-8")).splitlines():
        if line.startswith("#"):
            base = slug(line.lstrip("#"))
            n = seen.get(base, 0)
            seen[base] = n + 1
            found.add(base if n == 0 else f"{base}-{n}")
    return found


def broken_links(source: Path) -> list[str]:
    """One line per broken relative link of ``source``."""
    problems = []
    for target in LINK.findall(FENCE.sub("", source.read_text(encoding="utf-8"))):
        if re.match(r"[a-z]+:", target):
            continue
        file_part, _, fragment = target.partition("#")
        dest = (source.parent / file_part).resolve() if file_part else source.resolve()
        if not dest.exists():
            problems.append(f"{source}: no file {target}")
        elif fragment and dest.suffix == ".md" and fragment not in anchors(dest):
            problems.append(f"{source}: no heading for {target}")
    return problems


def default_files() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "results").glob("*.md")),
            *sorted((ROOT / "studies").glob("**/README.md"))]


def main(argv: list[str]) -> int:
    files = [Path(a) for a in argv] or default_files()
    problems = [p for f in files for p in broken_links(f)]
    print("\n".join(problems) if problems else f"{len(files)} files, no broken link")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
