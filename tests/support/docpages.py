"""The documentation as the docs tests read it: pages, fenced blocks, directives.

A fenced block may be preceded (blank lines between allowed) by an HTML
comment that tells ``test_examples.py`` how to run it; readers of the page,
on the site or as plain Markdown, do not see it::

    <!-- test:
    skip: REASON                 not run; a reason is required, skips are counted
    slow                         the page's case is marked slow (still run in CI)
    before: SHELL                run in the page's folder before the block
    append: PREFIX => OPTIONS    appended to each command line starting with
                                 PREFIX (the longest matching PREFIX wins;
                                 argparse keeps the last value of an option)
    replace: OLD => NEW          text replaced in the block before it runs
    prelude: PYTHON              a line run before a Python block
    then: PYTHON                 a line run after a Python block (a check)
    save: PATH                   write the block (any language) to PATH
    -->

Directives are one a line; ``append``, ``replace``, ``prelude``, ``then`` and
``before`` may repeat. The blocks of a page run in order in one temporary
folder, which has ``examples/`` and ``studies/`` of the repository in it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

_FENCE = re.compile(
    r"^(?P<fence>```+)(?P<lang>[\w+-]*)[^\n]*\n(?P<body>.*?)^(?P=fence)\s*$",
    re.S | re.M,
)
_DIRECTIVE = re.compile(r"<!--\s*test:(?P<body>.*?)-->\s*\Z", re.S)
KEYS = ("skip", "slow", "before", "append", "replace", "prelude", "then", "save")


@dataclass
class Block:
    """A fenced block of a page and the directives before it."""

    page: Path
    line: int
    lang: str
    code: str
    directives: list[tuple[str, str]] = field(default_factory=list)

    @property
    def where(self) -> str:
        """``path:line`` of the block's opening fence, from the repository."""
        return f"{self.page.relative_to(ROOT).as_posix()}:{self.line}"

    def get(self, key: str) -> list[str]:
        """The values of every directive ``key``."""
        return [v for k, v in self.directives if k == key]

    @property
    def skip(self) -> str | None:
        """The reason the block is not run, or None."""
        reasons = self.get("skip")
        return reasons[0] if reasons else None


def _directives(before: str, where: str) -> list[tuple[str, str]]:
    m = _DIRECTIVE.search(before)
    if m is None:
        return []
    out = []
    for raw in m.group("body").strip().splitlines():
        line = raw.strip()
        if not line:
            continue
        key, _, value = line.partition(":") if ":" in line else (line, "", "")
        key = key.strip()
        if key not in KEYS:
            raise ValueError(f"{where}: unknown test directive {line!r}; known: {KEYS}")
        out.append((key, value.strip()))
    return out


def blocks(page: Path) -> list[Block]:
    """The fenced blocks of ``page``, in order, with their directives."""
    text = page.read_text(encoding="utf-8")
    out = []
    last = 0
    for m in _FENCE.finditer(text):
        line = text.count("\n", 0, m.start()) + 1
        where = f"{page.relative_to(ROOT).as_posix()}:{line}"
        before = text[last : m.start()]
        found = _directives(before, where)
        out.append(Block(page, line, m.group("lang"), m.group("body"), found))
        last = m.end()
    return out


def pages() -> list[Path]:
    """Every Markdown page of docs/ and README.md."""
    return [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]


def prose(page: Path) -> str:
    """The page without its fenced blocks and HTML comments."""
    text = page.read_text(encoding="utf-8")
    text = re.sub(r"<!--.*?-->", "", text, flags=re.S)
    return _FENCE.sub("", text)
