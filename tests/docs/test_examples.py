"""Every tutorial's and how-to's code blocks run, on small settings.

The ```python, ```bash and ```sh blocks of docs/tutorials/*.md and
docs/how-to/*.md, and README.md's Python example, run in a temporary folder
(one per page, blocks in order) with a temporary ``IDBENCH_CACHE_DIR``. A
block runs as the page shows it unless an HTML comment before it says how
to make it small or why it cannot run here (``docs/pages`` readers do not
see it); the directives are described in ``tests/support/docpages.py``. Every skip names
its reason, and :data:`SKIPS` counts them, so that a new skip is a decision.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from support.docpages import DOCS, ROOT, Block, blocks

RUN = ("python", "bash", "sh")
PAGES = [*sorted(DOCS.glob("tutorials/*.md")), *sorted(DOCS.glob("how-to/*.md"))]
SKIPS = 4
"""Blocks not run, each with its reason in the page (see test_skips_have_reasons)."""


def _cases() -> list[tuple[Path, list[Block]]]:
    cases = [
        (page, [b for b in blocks(page) if b.lang in RUN or b.get("save")])
        for page in PAGES
    ]
    readme = [b for b in blocks(ROOT / "README.md") if b.lang == "python"]
    return [*cases, (ROOT / "README.md", readme)]


def _params() -> list:
    out = []
    for page, found in _cases():
        slow = any(b.get("slow") or ("slow", "") in b.directives for b in found)
        marks = [pytest.mark.slow] if slow else []
        name = page.relative_to(ROOT).as_posix()
        out.append(pytest.param(page, found, id=name, marks=marks))
    return out


def _strip_comment(line: str) -> str:
    """``line`` without a trailing shell comment (outside quotes)."""
    quote = None
    for i, ch in enumerate(line):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip()
    return line


def replaced(block: Block) -> str:
    """The block's code with its ``replace`` directives applied."""
    code = block.code
    for rule in block.get("replace"):
        old, _, new = rule.partition(" => ")
        assert old in code, f"{block.where}: replace {old!r}: not in the block"
        code = code.replace(old, new)
    return code


def shell_script(block: Block) -> str:
    """The block's shell lines, continuations joined, ``append`` applied."""
    code = replaced(block)
    appends = []
    for rule in block.get("append"):
        prefix, _, options = rule.partition(" => ")
        appends.append((prefix.strip(), options.strip()))
    appends.sort(key=lambda a: -len(a[0]))
    lines = code.replace("\\\n", " ").splitlines()
    out = []
    for raw in lines:
        line = _strip_comment(raw)
        flat = " ".join(line.split())
        for prefix, options in appends:
            if flat.startswith(prefix):
                line = f"{line} {options}"
                break
        out.append(line)
    return "\n".join(out) + "\n"


def python_script(block: Block) -> str:
    """The block with its ``replace``, ``prelude`` and ``then`` directives."""
    code = replaced(block)
    return "\n".join([*block.get("prelude"), code, *block.get("then")]) + "\n"


def _run(argv: list[str], cwd: Path, env: dict[str, str], block: Block) -> None:
    done = subprocess.run(
        argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, (
        f"{block.where}: exit status {done.returncode}\n--- stdout\n"
        f"{done.stdout[-3000:]}\n--- stderr\n{done.stderr[-3000:]}"
    )


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    """One truth and mesh cache for the module: pages share small meshes."""
    return tmp_path_factory.mktemp("docs-cache")


@pytest.mark.parametrize(("page", "found"), _params())
def test_page_blocks_run(page: Path, found: list[Block], tmp_path, cache) -> None:
    for name in ("examples", "studies"):
        (tmp_path / name).symlink_to(ROOT / name)
    env = {**os.environ, "IDBENCH_CACHE_DIR": str(cache), "MPLBACKEND": "Agg"}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.pop("IDBENCH_DISABLE_PLUGIN_AUTOLOAD", None)
    for i, block in enumerate(found):
        for path in block.get("save"):
            (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / path).write_text(block.code, encoding="utf-8")
        if block.skip is not None or block.get("save"):
            continue
        for command in block.get("before"):
            _run(["bash", "-euo", "pipefail", "-c", command], tmp_path, env, block)
        if block.lang == "python":
            script = tmp_path / f"block_{i}.py"
            script.write_text(python_script(block), encoding="utf-8")
            _run([sys.executable, script.name], tmp_path, env, block)
        else:
            script = tmp_path / f"block_{i}.sh"
            script.write_text(shell_script(block), encoding="utf-8")
            _run(["bash", "-euo", "pipefail", script.name], tmp_path, env, block)


def test_skips_have_reasons() -> None:
    skipped = []
    for _, found in _cases():
        for block in found:
            if block.skip is not None:
                assert len(block.skip) > 10, f"{block.where}: skip needs a reason"
                skipped.append(f"{block.where}: {block.skip}")
    assert len(skipped) == SKIPS, "blocks not run changed:\n" + "\n".join(skipped)


def test_append_keeps_the_page_command() -> None:
    block = Block(ROOT / "README.md", 1, "bash", "idbench compare --seeds 5 \\\n"
                  "    --out runs/   # a comment\nidbench report runs/\n",
                  [("append", "idbench compare => --seeds 1")])  # fmt: skip
    script = shell_script(block)
    assert shlex.split(script.splitlines()[0]) == [
        "idbench", "compare", "--seeds", "5", "--out", "runs/", "--seeds", "1"
    ]  # fmt: skip
    assert script.splitlines()[1] == "idbench report runs/"
