"""The generated pages cover the code and the README (``docs/pages.py``).

The home page is README.md with its links made site-relative; the layout page
has a section per subpackage of idbench/ and the plugins, a row per module;
the API reference a page per subpackage with every module in it.
"""

from __future__ import annotations

import re
import sys

from support.docpages import DOCS, ROOT

sys.path.insert(0, str(DOCS))
import pages

GENERATED = {"index.md", "reference/layout.md", "reference/api.md",
             "reference/cli.md"}  # fmt: skip


def test_home_is_the_readme_with_links_that_work_on_the_site() -> None:
    home = pages.home()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert home.splitlines()[0] == readme.splitlines()[0]
    assert len(home.splitlines()) == len(readme.splitlines())
    for target in re.findall(r"(?<!!)\[[^\]]+\]\(([^)\s#]+)", home):
        if target.startswith(("http://", "https://")):
            continue
        assert (DOCS / target).is_file() or target in GENERATED, target


def test_home_rewrites_repository_links() -> None:
    text = (
        "[a](docs/tutorials/x.md#y), [b](examples/liver/body.toml), [c](https://x.org)"
    )
    assert pages.home(text) == (
        "[a](tutorials/x.md#y), b (`examples/liver/body.toml` in the repository), "
        "[c](https://x.org)"
    )


def test_no_generated_page_is_also_a_source_page() -> None:
    for path, _ in pages.iter_pages():
        assert not (DOCS / path).exists(), f"docs/{path} is generated: remove it"


def test_layout_has_every_subpackage_and_module() -> None:
    text = pages.layout()
    for folder in [ROOT / "idbench", *pages.PLUGINS]:
        for init in folder.rglob("__init__.py"):
            if init.parent != ROOT / "idbench":
                assert f"`{init.parent.relative_to(ROOT).as_posix()}/`" in text
        for module in folder.rglob("*.py"):
            if module.name != "__init__.py":
                assert f"| `{module.name}` |" in text, module
    assert "`idbench.cli`" in text  # the layers contract, from pyproject.toml


def test_api_pages_name_every_core_module_and_public_name() -> None:
    api = pages.api_pages()
    import idbench

    assert pages.public_names() == list(idbench.__all__)
    for name in idbench.__all__:
        assert f"::: idbench.{name}\n" in api["reference/api.md"]
    text = "\n".join(api.values())
    for module in (ROOT / "idbench").rglob("*.py"):
        if module.name != "__init__.py" and module.parent != ROOT / "idbench":
            assert f"::: {pages.dotted(module)}\n" in text, module
