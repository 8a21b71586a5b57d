"""Writes the CLI reference page from the parser itself (mkdocs-gen-files).

Run by ``mkdocs build``: every subcommand's ``--help``, as the installed idbench
prints it, so the page cannot drift from the code.
"""

from __future__ import annotations

import argparse
import os

import mkdocs_gen_files

from idbench.cli.parser import build_parser


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse keeps no public list of subcommands
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _help(parser: argparse.ArgumentParser) -> str:
    return parser.format_help()


def main() -> None:
    """Write ``reference/cli.md``: the top-level help, then each subcommand's."""
    os.environ["COLUMNS"] = "88"  # argparse wraps help to this width
    parser = build_parser()
    lines = [
        "# Command line",
        "",
        "Generated from the parser at build time: what `idbench COMMAND --help`"
        " prints.",
        "",
        "```text",
        _help(parser).rstrip(),
        "```",
    ]
    for name, sub in sorted(_subparsers(parser).items()):
        lines += ["", f"## idbench {name}", "", "```text", _help(sub).rstrip(), "```"]
    with mkdocs_gen_files.open("reference/cli.md", "w") as page:
        page.write("\n".join(lines) + "\n")


main()
