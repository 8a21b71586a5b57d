"""The generated pages of the documentation, as text (no mkdocs needed).

``docs/gen_pages.py`` writes them at build time (mkdocs-gen-files) and the
tests in ``tests/docs/`` read them through the same functions, so what the
site shows and what the tests check cannot differ:

- :func:`home`: the home page, README.md with its links made site-relative;
- :func:`layout`: the code's layout, from the package tree, the modules'
  docstrings and the import-linter contracts of pyproject.toml;
- :func:`api_pages`: the Python API, ``idbench.__all__`` and one page per
  subpackage of mkdocstrings directives;
- :func:`hook_sections`: one section per hook spec of
  ``idbench/registry/hookspecs.py``, with its signature and its example.
"""

from __future__ import annotations

import ast
import inspect
import re
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
"""The repository."""
CORE = ROOT / "idbench"
PLUGINS = (ROOT / "plugins" / "idbench_fem", ROOT / "plugins" / "idbench_filters")

_LINK = re.compile(r"(?<!!)\[([^\]]+)\]\(([^)\s]+)\)")


# --- the home page -----------------------------------------------------------


def site_link(target: str) -> str | None:
    """Where a README link points on the site, or None for a repository file.

    ``docs/x.md#y`` becomes ``x.md#y``; web addresses and anchors stay.
    """
    if target.startswith(("http://", "https://", "mailto:", "#")):
        return target
    if target.startswith("docs/"):
        return target.removeprefix("docs/")
    return None


def home(readme: str | None = None) -> str:
    """The home page: README.md, its links rewritten for the site.

    A link into ``docs/`` points to the page; a link to another repository
    file becomes its text and the path, as plain text (the site does not ship
    the repository).
    """
    if readme is None:
        readme = (ROOT / "README.md").read_text(encoding="utf-8")

    def rewrite(m: re.Match[str]) -> str:
        label, target = m.group(1), m.group(2)
        where = site_link(target)
        if where is not None:
            return f"[{label}]({where})"
        if f"`{target}`" in label:
            return label
        return f"{label} (`{target}` in the repository)"

    return _LINK.sub(rewrite, readme)


# --- the layout page ---------------------------------------------------------


def _docstring(path: Path) -> str:
    return ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""


def _first_line(path: Path) -> str:
    doc = _docstring(path).strip()
    if not doc:
        return "(no docstring)"
    first = doc.split("\n\n")[0]
    return " ".join(first.split())


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def _modules(folder: Path) -> list[Path]:
    return sorted(p for p in folder.glob("*.py") if p.name != "__init__.py")


def _packages(folder: Path) -> list[Path]:
    return sorted(
        p for p in folder.iterdir() if p.is_dir() and (p / "__init__.py").is_file()
    )


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _table(folder: Path) -> list[str]:
    rows = ["| module | lines | what it holds (first line of its docstring) |"]
    rows.append("|---|---|---|")
    for module in _modules(folder):
        line = _first_line(module).replace("|", "\\|")
        rows.append(f"| `{module.name}` | {_lines(module)} | {line} |")
    for sub in _packages(folder):
        n = sum(_lines(p) for p in sub.rglob("*.py"))
        line = _first_line(sub / "__init__.py").replace("|", "\\|")
        rows.append(f"| `{sub.name}/` | {n} | {line} (below) |")
    return rows


def _section(folder: Path, level: int) -> list[str]:
    head = "#" * level
    doc = _docstring(folder / "__init__.py").strip() or "(no docstring)"
    out = [f"{head} `{_rel(folder)}/`", "", doc, ""]
    if _modules(folder) or _packages(folder):
        out += [*_table(folder), ""]
    for sub in _packages(folder):
        out += _section(sub, min(level + 1, 4))
    return out


def layers() -> list[tuple[str, list[str]]]:
    """The import-linter ``layers`` contracts of pyproject.toml: (name, layers)."""
    raw = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    contracts = raw.get("tool", {}).get("importlinter", {}).get("contracts", [])
    out = []
    for c in contracts:
        if c.get("type") != "layers":
            continue
        prefix = "".join(f"{x}." for x in c.get("containers", [])[:1])
        out.append((c["name"], [f"{prefix}{layer}" for layer in c["layers"]]))
    return out


def contracts() -> list[str]:
    """Every import-linter contract of pyproject.toml, one line each."""
    raw = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    out = []
    for c in raw.get("tool", {}).get("importlinter", {}).get("contracts", []):
        out.append(f"- {c['name']} (`{c['type']}`)")
    return out


def layout() -> str:
    """The layout page: every subpackage and module, with the contracts."""
    core = sorted(p.name for p in _packages(CORE))
    total = sum(_lines(p) for p in CORE.rglob("*.py"))
    n_modules = sum(1 for p in CORE.rglob("*.py") if p.name != "__init__.py")
    out = [
        "# Layout of the code",
        "",
        "Generated from the package tree at build time: each folder's `__init__`"
        " docstring, each module's first docstring line and its length in lines,"
        " and the import contracts of `pyproject.toml` (checked by `lint-imports`)."
        " Nothing here is written by hand, so it cannot go stale.",
        "",
        f'`idbench/` is the core: {len(core)} subpackages ("rooms"),'
        f" {n_modules} modules, {total:,} lines. It knows no model, estimator or"
        " physics: an import-linter contract checks that it never imports a plugin,"
        " and `tests/core/test_core_names_no_plugin.py` that no string in it names a"
        " built-in plugin's model, scenario, estimator or mesh.",
        "",
        "## Import contracts",
        "",
        *contracts(),
        "",
    ]
    for name, order in layers():
        out += [
            f"**{name}** (top to bottom; a layer imports only those below it;"
            " names on one line import neither way):",
            "",
        ]
        sep = " \\| "
        for i, layer in enumerate(order, 1):
            out.append(f"{i}. " + sep.join(f"`{x.strip()}`" for x in layer.split("|")))
        out.append("")
    face = CORE / "__init__.py"
    rows = _table(CORE)
    rows.insert(2, f"| `__init__.py` | {_lines(face)} | {_first_line(face)} |")
    out += ["## The core", "", *rows, ""]
    for sub in _packages(CORE):
        out += _section(sub, 3)
    out += ["## The built-in plugins", ""]
    for plugin in PLUGINS:
        out += _section(plugin, 3)
    return "\n".join(out).rstrip() + "\n"


# --- the API reference -------------------------------------------------------


def public_names() -> list[str]:
    """``idbench.__all__``, read from ``idbench/__init__.py`` without importing."""
    tree = ast.parse((CORE / "__init__.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
        ):
            return [ast.literal_eval(e) for e in node.value.elts]  # type: ignore[attr-defined]
    return []


def dotted(path: Path) -> str:
    """The module name of a file under the repository or plugins/."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[0] == "plugins":
        parts = parts[1:]
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def api_pages() -> dict[str, str]:
    """``{path: text}``: ``reference/api.md`` and ``reference/api/ROOM.md``."""
    rooms = _packages(CORE)
    index = [
        "# Python API",
        "",
        "Generated at build time from the code: first the public face, every name"
        " in `idbench.__all__` (what plugins and scripts import: `from idbench"
        " import ...`), then one page per subpackage with every module's"
        " documented members.",
        "",
        "Subpackages: "
        + ", ".join(f"[`{p.name}`](api/{p.name}.md)" for p in rooms)
        + ".",
        "",
        "## `idbench`",
        "",
        "::: idbench",
        "    options:",
        "      show_root_heading: false",
        "      members: false",
        "",
    ]
    for name in public_names():
        index += [f"::: idbench.{name}", "    options:", "      heading_level: 3", ""]
    pages = {"reference/api.md": "\n".join(index)}
    for room in rooms:
        lines = [f"# `idbench.{room.name}`", ""]
        lines += ["[All subpackages](../api.md)", ""]
        lines += [f"::: {dotted(room)}", "    options:", "      members: false", ""]
        for module in sorted(room.rglob("*.py")):
            if module.name == "__init__.py":
                continue
            lines += [f"::: {dotted(module)}", "    options:", "      heading_level: 2"]
            lines.append("")
        pages[f"reference/api/{room.name}.md"] = "\n".join(lines)
    return pages


# --- the hook reference ------------------------------------------------------


@dataclass(frozen=True)
class Hook:
    """A hook spec: its name, signature and docstring (numpy style)."""

    name: str
    signature: str
    doc: str

    def parts(self) -> dict[str, str]:
        """The docstring's summary (key ``""``) and numpy sections by title."""
        return _numpy_sections(self.doc)


def hooks() -> list[Hook]:
    """Every function marked ``@hookspec`` in idbench.registry.hookspecs, in order."""
    from idbench.registry import hookspecs

    found = []
    for name, fn in vars(hookspecs).items():
        if inspect.isfunction(fn) and getattr(fn, "idbench_spec", None) is not None:
            found.append(Hook(name, _signature(fn), inspect.getdoc(fn) or ""))
    found.sort(key=lambda h: inspect.getsourcelines(getattr(hookspecs, h.name))[1])
    return found


def _signature(fn: object) -> str:
    """``name(arg: type, ...) -> type`` with the annotations as written."""
    sig = inspect.signature(fn)  # type: ignore[arg-type]

    def text(annotation: object) -> str:
        return (
            annotation
            if isinstance(annotation, str)
            else inspect.formatannotation(annotation)
        )

    args = ", ".join(
        p.name if p.annotation is p.empty else f"{p.name}: {text(p.annotation)}"
        for p in sig.parameters.values()
    )
    back = (
        ""
        if sig.return_annotation is sig.empty
        else f" -> {text(sig.return_annotation)}"
    )
    return f"{fn.__name__}({args}){back}"  # type: ignore[attr-defined]


_ROLE = re.compile(r":(?:class|func|mod|data|meth|attr):`~?([^`]+)`")


def _markdown(text: str) -> str:
    """Sphinx roles as code: ``:class:`idbench.X` `` becomes `` `idbench.X` ``."""
    return _ROLE.sub(r"`\1`", text)


def _parameters(text: str) -> str:
    """A numpy Parameters section as a list: ``- `name`: description``."""
    items: list[list[str]] = []
    for line in text.splitlines():
        if line and not line.startswith(" "):
            items.append([f"`{line.strip()}`:"])
        elif items and line.strip():
            items[-1].append(line.strip())
    return "\n".join("- " + " ".join(item) for item in items)


_SECTION = re.compile(r"^(?P<title>[A-Z][A-Za-z ]+)\n-{3,}\n", re.M)


def _numpy_sections(doc: str) -> dict[str, str]:
    out: dict[str, str] = {}
    matches = list(_SECTION.finditer(doc))
    out[""] = doc[: matches[0].start() if matches else len(doc)].strip()
    for i, m in enumerate(matches):
        end = matches[i + 1].start() if i + 1 < len(matches) else len(doc)
        out[m.group("title").strip()] = doc[m.end() : end].strip()
    return out


def _examples(text: str) -> str:
    """A numpy Examples section as Markdown: ``>>>`` lines as a Python block."""
    out: list[str] = []
    block: list[str] = []

    def flush() -> None:
        if block:
            out.extend(["```python", *block, "```", ""])
            block.clear()

    for line in text.splitlines():
        if line.startswith((">>> ", "... ")) or line in (">>>", "..."):
            block.append(line[4:])
        elif line.strip() == "" and block:
            continue
        else:
            flush()
            out.append(line)
    flush()
    return "\n".join(out).strip()


def hook_sections() -> str:
    """One ``##`` section per hook spec: signature, description, example."""
    out = []
    for hook in hooks():
        parts = hook.parts()
        out += [
            f"## `{hook.name}`",
            "",
            "```python",
            "@idbench.hookimpl",
            f"def {hook.signature}: ...",
            "```",
            "",
            _markdown(parts[""]),
            "",
        ]
        for title, body in parts.items():
            if title in ("", "Examples"):
                continue
            if title == "Parameters":
                body = _parameters(body)
            out += [f"**{title}**", "", _markdown(body), ""]
        if "Examples" in parts:
            out += ["**Example**", "", _markdown(_examples(parts["Examples"])), ""]
    return "\n".join(out).rstrip() + "\n"


def iter_pages() -> Iterator[tuple[str, str]]:
    """Every generated page: (path under docs/, text); hooks are appended."""
    yield "index.md", home()
    yield "reference/layout.md", layout()
    yield from api_pages().items()
