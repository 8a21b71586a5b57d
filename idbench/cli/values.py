"""How the command line's strings become values: numbers, lists, assignments.

Each parser raises :class:`UsageError` with one line naming the option, the
text given and what is allowed.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


class UsageError(Exception):
    """Bad command-line input; printed as one line, exit status 2."""



def toml_value(text: str) -> Any:
    """A setting's value as TOML would read it (number, bool, list), else the text."""
    import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def assignments(name: str) -> Any:
    """Parse ``KEY=VALUE[,KEY=VALUE...]`` into a dict (values as TOML reads them)."""

    def parse(text: str) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for part in split_top_level(text):
            key, sep, value = part.partition("=")
            if not sep or not key.strip() or not value.strip():
                raise UsageError(f"--{name} {text!r}: need NAME=VALUE[,NAME=VALUE]")
            out[key.strip()] = toml_value(value.strip())
        return out

    return parse


def add_option_argument(parser: argparse.ArgumentParser, what: str, help: str) -> None:
    """``--WHAT-option NAME=VALUE[,...]``, repeatable, into ``WHAT_options``."""
    parser.add_argument(
        f"--{what}-option",
        dest=f"{what}_options",
        type=assignments(f"{what}-option"),
        action="append",
        help=help,
    )


def split_top_level(text: str) -> list[str]:
    """Split at commas that are not inside brackets (``grid=[20,4,4],nu=0.3``)."""
    parts, depth, cur = [], 0, ""
    for ch in text:
        depth += (ch in "[{(" and 1) or 0
        depth -= (ch in "]})" and 1) or 0
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    return [p for p in [*parts, cur] if p.strip()]


def numbers(name: str, kind: type = float) -> Any:
    """Parser of ``--name`` as comma-separated ``kind`` values (at least one)."""
    what = "whole number" if kind is int else "number"

    def parse(text: str) -> tuple[Any, ...]:
        try:
            values = tuple(kind(v) for v in text.split(",") if v.strip())
        except ValueError:
            raise UsageError(
                f"--{name} {text!r}: need comma-separated {what}s"
            ) from None
        if not values:
            raise UsageError(f"--{name} {text!r}: need at least one {what}")
        return values

    return parse


def names(text: str) -> tuple[str, ...]:
    """Comma-separated names, blanks left out."""
    return tuple(v.strip() for v in text.split(",") if v.strip())


def number(name: str, kind: type = float) -> Any:
    """Parser of ``--name`` as one ``kind`` value."""
    def parse(text: str) -> Any:
        try:
            return kind(text)
        except ValueError:
            what = "a whole number" if kind is int else "a number"
            raise UsageError(f"--{name} {text!r}: need {what}") from None

    return parse


def path(name: str) -> Any:
    """Parser of ``--name`` as a non-empty path."""
    def parse(text: str) -> Path:
        if not text.strip():
            raise UsageError(f"--{name} {text!r}: need a path")
        return Path(text)

    return parse


def raw_option(argv: list[str], name: str) -> str | None:
    """The text given for option ``name`` (for error messages)."""
    for i, arg in enumerate(argv):
        if arg == name and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(name + "="):
            return arg.split("=", 1)[1]
    return None
