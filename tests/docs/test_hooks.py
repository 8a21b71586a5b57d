"""Every hook spec has its section in the hook reference, with an example.

The sections of docs/reference/hooks.md are generated at build time from
idbench/registry/hookspecs.py (``docs/pages.py``); this checks, per hook spec
(a new one is picked up when it lands), that its section is there with its
signature, and that its docstring has an Examples section whose code compiles
and implements the hook (datasette's test_docs.py, for our hooks).
"""

from __future__ import annotations

import inspect
import sys

import pytest
from support.docpages import DOCS, ROOT

sys.path.insert(0, str(DOCS))
import pages

from idbench.registry import hookspecs

SPECS = sorted(
    name
    for name, fn in inspect.getmembers(hookspecs, inspect.isfunction)
    if getattr(fn, "idbench_spec", None) is not None
)


def test_the_generator_finds_every_hookspec() -> None:
    assert sorted(h.name for h in pages.hooks()) == SPECS


@pytest.mark.parametrize("name", SPECS)
def test_hookspec_has_a_section(name: str) -> None:
    text = pages.hook_sections()
    assert f"## `{name}`\n" in text
    section = text.split(f"## `{name}`\n", 1)[1].split("\n## ", 1)[0]
    assert f"def {name}(register" in section, section[:300]
    assert "**Example**" in section, f"{name}: no example in its section"


@pytest.mark.parametrize("name", SPECS)
def test_hookspec_example_implements_the_hook(name: str) -> None:
    hook = next(h for h in pages.hooks() if h.name == name)
    parts = hook.parts()
    assert "Examples" in parts, f"{name}: its docstring has no Examples section"
    code = "\n".join(
        line[4:]
        for line in parts["Examples"].splitlines()
        if line.startswith((">>> ", "... ")) or line in (">>>", "...")
    )
    compile(code, f"<{name} example>", "exec")
    assert "@idbench.hookimpl" in code and f"def {name}(register)" in code, code


def test_the_build_appends_the_sections_to_the_page() -> None:
    assert (DOCS / "reference" / "hooks.md").is_file()
    assert "docs/gen_pages.py" in (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    assert "hook_sections()" in (DOCS / "gen_pages.py").read_text(encoding="utf-8")
