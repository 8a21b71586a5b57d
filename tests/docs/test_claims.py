"""What the pages name exists: repository paths, modules, CLI flags, TOML keys.

- Repository paths in backticks or links (``idbench/run/compare.py``,
  ``examples/liver/body.toml``, ``tests/...``) exist, and dotted names
  (``idbench.report.write.write_report``) import.
- Every ``--flag`` of an ``idbench SUBCOMMAND`` line (code blocks and inline
  code) is an option of that subcommand in the real parser, plugins' commands
  included; a ``python studies/x.py`` or ``benchmarks/x.py`` line's flags are
  options of that script; a flag alone in inline code is an option of some
  command or script.
- Every ```toml block loads through the parser it is written for: a body
  description through the FE plugin's body parser (each commented-out key
  too), a comparison through the config loader and the settings classes, a
  recording's manifest against the keys the recording reader knows; the
  ``key = value`` pairs of the body reference are keys a body table accepts.
- No page or source file names an issue number or ``DESIGN.md``.
- README's "about N tests" is within 10% of what pytest collects.
"""

from __future__ import annotations

import argparse
import importlib
import re
import tomllib
from functools import cache
from pathlib import Path

import pytest
from support.docpages import ROOT, blocks, pages, prose

ROOTS = ("idbench/", "plugins/", "studies/", "benchmarks/", "tests/", "examples/",
         "docs/", ".ci/")  # fmt: skip
FILES = ("pyproject.toml", "mkdocs.yml", "README.md")
YOURS = {"recording.toml", "idbench_tiny_rls.py", "body.toml"}
"""Files a page asks the reader to write (not in the repository)."""
GENERATED = {"docs/reference/cli.md", "docs/reference/api.md", "docs/index.md",
             "docs/reference/layout.md"}  # fmt: skip
"""Pages written at build time (docs/gen_cli.py, docs/gen_pages.py)."""

_CODE = re.compile(r"`([^`\n]+)`")
_LINK = re.compile(r"\]\(([^)\s]+)\)")
_WORD = re.compile(r"^(-[\w-]+|[a-z][\w-]*)$")
_DOTTED = re.compile(r"^(idbench|idbench_fem|idbench_filters)(\.\w+)+$")


def _page_id(page: Path) -> str:
    return page.relative_to(ROOT).as_posix()


# --- repository paths and dotted names --------------------------------------


def _path_claims(page: Path) -> list[str]:
    text = prose(page)
    found = [m.group(1).strip() for m in _CODE.finditer(text)]
    found += [m.group(1) for m in _LINK.finditer(text)]
    out = []
    for raw in found:
        token = raw.split()[0] if raw.split() else raw
        token = token.rstrip(".,;:)").split("#")[0]
        if token.startswith(ROOTS) or token in FILES or _MODULE.match(token):
            out.append(token)
    return out


_MODULE = re.compile(r"^[\w/-]+\.(py|toml)$")
"""A file named relative to a folder the page means (``fem/batched.py``)."""


@cache
def _repository_files() -> tuple[str, ...]:
    skip = (".git", ".venv", "site", "__pycache__")
    return tuple(
        "/" + p.relative_to(ROOT).as_posix()
        for p in ROOT.rglob("*")
        if p.is_file()
        and not set(p.relative_to(ROOT).parts) & set(skip)
        and not p.relative_to(ROOT).parts[0].startswith(".venv")
    )


def _exists(claim: str) -> bool:
    if claim.rstrip("/") in {g.rstrip("/") for g in GENERATED}:
        return True
    if any(ch in claim for ch in "*?["):
        return any(ROOT.glob(claim))
    if claim in YOURS:
        return True
    if not claim.startswith(ROOTS) and claim not in FILES:  # a file of some folder
        return any(f.endswith("/" + claim) for f in _repository_files())
    return (ROOT / claim).exists()


@pytest.mark.parametrize("page", pages(), ids=_page_id)
def test_named_repository_paths_exist(page: Path) -> None:
    missing = sorted({c for c in _path_claims(page) if not _exists(c)})
    assert not missing, f"{_page_id(page)} names paths that do not exist: {missing}"


def _resolves(name: str) -> bool:
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        try:
            for attr in parts[i:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return False
        return True
    return False


@pytest.mark.parametrize("page", pages(), ids=_page_id)
def test_named_modules_and_objects_import(page: Path) -> None:
    names = {m.group(1).rstrip("()") for m in _CODE.finditer(prose(page))}
    names = {n for n in names if _DOTTED.match(n)}
    missing = sorted(n for n in names if not _resolves(n))
    assert not missing, f"{_page_id(page)} names what does not import: {missing}"


# --- command-line flags ------------------------------------------------------


@cache
def _subcommands() -> dict[str, set[str]]:
    from idbench.cli.parser import build_parser

    parser = build_parser()
    out = {"": {s for a in parser._actions for s in a.option_strings}}
    commands = (ROOT / "idbench" / "cli" / "commands.py").read_text(encoding="utf-8")
    if '"--debug" in argv' in commands:  # taken out before the parser sees it
        out[""].add("--debug")
    for action in parser._actions:  # argparse keeps no public list of subcommands
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out[name] = {s for a in sub._actions for s in a.option_strings}
    return out


@cache
def _script_flags(path: str) -> set[str]:
    source = (ROOT / path).read_text(encoding="utf-8")
    flags = set(re.findall(r"""["'](--[\w-]+)["']""", source))
    if "_cli.parser(" in source or "_cli.main(" in source:
        flags |= _script_flags("studies/_cli.py")
    return flags | {"-h", "--help"}


def _commands(page: Path) -> list[tuple[str, list[str]]]:
    """(command, its tokens) of every idbench or script line the page shows."""
    lines = []
    for block in blocks(page):
        if block.lang in ("", "bash", "sh", "console", "text"):
            lines += block.code.replace("\\\n", " ").splitlines()
    for m in re.finditer(r"^ {4}(\$ )?(idbench .*)$", prose(page), re.M):
        lines.append(m.group(2))  # indented code
    lines += [m.group(1) for m in _CODE.finditer(prose(page))]
    out = []
    for line in lines:
        line = line.strip().removeprefix("$ ")
        line = re.sub(r"^(\w+=\S+\s+)+", "", line)  # VAR=value before a command
        line = re.split(r"\s+#\s", line)[0]
        tokens = line.split()
        if len(tokens) >= 2 and tokens[0] == "idbench" and _WORD.match(tokens[1]):
            out.append((f"idbench {tokens[1]}", tokens[2:]))
        elif len(tokens) >= 2 and tokens[0] == "python" and tokens[1].endswith(".py"):
            out.append((tokens[1], tokens[2:]))
    return out


def _flag(token: str) -> str | None:
    m = re.match(r"^(--?[A-Za-z][\w-]*)", token)
    return m.group(1) if m and token.startswith("-") else None


@pytest.mark.parametrize("page", pages(), ids=_page_id)
def test_command_lines_use_real_flags(page: Path) -> None:
    subs = _subcommands()
    bad = []
    for command, tokens in _commands(page):
        if command.startswith("idbench "):
            sub = command.split()[1]
            if sub.startswith("-"):
                known, tokens = subs[""], [sub, *tokens]
            elif sub not in subs:
                bad.append(f"{command}: no such subcommand")
                continue
            else:
                known = subs[sub] | subs[""]
        elif (ROOT / command).is_file():
            known = _script_flags(command)
        else:
            bad.append(f"{command}: no such script")
            continue
        bad += [f"{command} {f}" for t in tokens if (f := _flag(t)) and f not in known]
    assert not bad, f"{_page_id(page)}: unknown commands or flags: {sorted(set(bad))}"


OTHER_FLAGS = {"--nworkers", "--nthreads", "--no-dashboard", "--dashboard-address",
               "--host", "--port", "--co", "--durations"}  # fmt: skip
"""Flags of other programs the pages show (dask, pytest)."""


@cache
def _all_flags() -> set[str]:
    flags = set().union(*_subcommands().values())
    for folder in ("studies", "benchmarks"):
        for path in (ROOT / folder).glob("*.py"):
            flags |= _script_flags(f"{folder}/{path.name}")
    return flags | OTHER_FLAGS


@pytest.mark.parametrize("page", pages(), ids=_page_id)
def test_flags_named_alone_exist(page: Path) -> None:
    named = set()
    for m in _CODE.finditer(prose(page)):
        span = m.group(1).strip()
        if re.fullmatch(r"--[A-Za-z][\w-]*(=\S*|\s+\S+)?", span):
            named.add(re.match(r"--[\w-]+", span).group(0))  # type: ignore[union-attr]
    missing = sorted(named - _all_flags())
    assert not missing, f"{_page_id(page)} names flags no command has: {missing}"


# --- TOML --------------------------------------------------------------------


def _toml_blocks() -> list:
    out = []
    for page in pages():
        for block in blocks(page):
            if block.lang == "toml":
                out.append(pytest.param(block, id=block.where))
    return out


def _kind(text: str) -> str:
    raw = tomllib.loads(text)
    if "build-system" in raw or "project" in raw:
        return "pyproject"
    if "mesh" in raw or "manipulation" in raw:
        return "body"
    if "format" in raw:
        return "recording"
    return "compare"


def _body_error(raw: dict) -> str | None:
    from idbench_fem.bodies.description import parse_body

    try:
        parse_body(raw, "<docs>", ROOT / "examples" / "liver")
    except ValueError as exc:
        return str(exc)
    return None


def _unknown_key(message: str | None) -> bool:
    return message is not None and "unknown key" in message


def _check_body(text: str, where: str) -> None:
    raw = tomllib.loads(text)
    error = _body_error(raw)
    assert error is None, f"{where}: the body parser refuses the block: {error}"
    # each commented-out `key = value` line, uncommented alone, is a known key
    lines = text.splitlines()
    header = None  # a commented-out [table] the next commented keys belong to
    for i, line in enumerate(lines):
        h = re.match(r"^#\s*(\[\w+\])\s*(#.*)?$", line.strip())
        if h or not line.strip().startswith("#"):
            header = h.group(1) if h else None
            continue
        m = re.match(r"^#\s*(\w+\s*=\s*.+?)(\s+#.*)?$", line.strip())
        if not m:
            continue
        if header:
            trial = [*lines, header, m.group(1)]
        else:
            trial = [*lines[:i], m.group(1), *lines[i + 1 :]]
        try:
            raw = tomllib.loads("\n".join(trial))
        except tomllib.TOMLDecodeError:
            continue  # a key already set in that table: a comment on it
        error = _body_error(raw)
        assert not _unknown_key(error), f"{where}: commented {m.group(1)!r}: {error}"


def _check_compare(text: str, where: str, tmp_path: Path) -> None:
    from idbench.cli.parser import shorthand_settings
    from idbench.core.settings import build_settings, model_settings
    from idbench.estimate.posterior import PosteriorSettings
    from idbench.plan.check import CalibrationSettings  # wherever it lives
    from idbench.plan.config import build_config, load_toml
    from idbench.registry.registry import cached_registry

    reg = cached_registry()
    path = tmp_path / "block.toml"
    path.write_text(text, encoding="utf-8")
    toml = load_toml(path, shorthand_settings(reg))
    config = build_config(toml=toml, registry=reg).resolve(reg)
    for name, given in config.estimator_settings.items():
        build_settings(
            reg.estimator(name), dict(given), f"{where}: [estimators.{name}]"
        )
    for name, given in config.model_settings.items():
        model_settings(reg, name, dict(given))
    build_settings(PosteriorSettings, dict(config.posterior_settings), where)
    calibration = dict(config.calibration)
    calibration.pop("scenarios", None)
    calibration.pop("mesh", None)
    build_settings(CalibrationSettings, calibration, where)


def _check_recording(text: str, where: str) -> None:
    source = (ROOT / "idbench" / "store" / "recording.py").read_text(encoding="utf-8")
    known = set(re.findall(r"""["'](\w+)["']""", source))
    known |= set(re.findall(r"^\s*(\w+)\s*=", source.split('"""')[1], re.M))  # its doc
    unknown = sorted(k for k in tomllib.loads(text) if k not in known)
    assert not unknown, f"{where}: keys the recording reader does not know: {unknown}"


@pytest.mark.parametrize("block", _toml_blocks())
def test_toml_blocks_load(block, tmp_path) -> None:
    kind = _kind(block.code)
    if kind == "body":
        _check_body(block.code, block.where)
    elif kind == "compare":
        _check_compare(block.code, block.where, tmp_path)
    elif kind == "recording":
        _check_recording(block.code, block.where)


def _body_accepts(key: str) -> bool:
    """Whether some table of the shipped liver's body accepts ``key``."""
    base = tomllib.loads((ROOT / "examples" / "liver" / "body.toml").read_text())
    tables: list[dict] = [base]
    tables += [v for v in base.values() if isinstance(v, dict)]
    tables += list(base.get("manipulation", []))
    for table in tables:
        if key in table:
            return True
        table[key] = 0
        try:
            error = _body_error(base)
        finally:
            del table[key]
        if not _unknown_key(error):
            return True
    return False


def test_body_reference_names_real_keys() -> None:
    from idbench.plan.config import FIELDS

    page = ROOT / "docs" / "reference" / "body-toml.md"
    pairs = re.findall(r"`(\w+)\s*=\s*[^`]+`", prose(page))
    keys = sorted(set(pairs))
    unknown = [k for k in keys if k not in FIELDS and not _body_accepts(k)]
    assert not unknown, f"{_page_id(page)} names keys no parser accepts: {unknown}"


# --- issue numbers and DESIGN.md ---------------------------------------------
# "issue 26", "issues 9", "#14" (not a CSS colour, "#222;"), and DESIGN.md, a
# file that does not ship (docs/design.md does).

_STALE = re.compile(r"\bissues?\s+#?\d+|(?<![\w&#/'\"])#\d{1,4}\b(?![\w;-])|DESIGN\.md")


def _stale(path: Path) -> list[str]:
    out = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        for m in _STALE.finditer(line):
            out.append(f"{path.relative_to(ROOT).as_posix()}:{i}: {m.group(0)}")
    return out


@pytest.mark.parametrize("page", pages(), ids=_page_id)
def test_pages_name_no_issue_number_or_design_md(page: Path) -> None:
    found = _stale(page)
    assert not found, "\n".join(found)


def _sources() -> list[Path]:
    out = []
    for folder in ("idbench", "plugins", "studies", "benchmarks"):
        for path in sorted((ROOT / folder).rglob("*")):
            if (
                path.suffix in (".py", ".toml", ".md")
                and "__pycache__" not in path.parts
            ):
                out.append(path)
    return out


def test_sources_name_no_issue_number_or_design_md() -> None:
    found = [hit for path in _sources() for hit in _stale(path)]
    assert not found, "\n".join(found)


# --- the README's test count -------------------------------------------------


@pytest.mark.slow
def test_readme_test_count_is_about_right() -> None:
    import subprocess
    import sys

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    said = re.search(r"about ([\d,]+) tests", readme)
    assert said, "README.md: say 'about N tests' (or drop the test count and this)"
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--co", "-q", "-p", "no:cacheprovider"],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    found = re.search(r"(\d+) tests? collected", done.stdout)
    assert found, done.stdout[-2000:]
    n, claimed = int(found.group(1)), int(said.group(1).replace(",", ""))
    assert abs(claimed - n) <= 0.1 * n, f"README says about {claimed} tests; {n} now"
