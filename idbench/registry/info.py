"""What a registered estimator or model can be set to: fields, defaults, meaning.

The meaning of a setting is its whole entry in the numpy docstring's
Attributes or Parameters section (never cut after a first sentence, which
would end at "e.g."), asked first of the class that declares the field.
Private fields (leading ``_``) and fields not in ``__init__`` are never
listed.
"""

from __future__ import annotations

import dataclasses
import inspect
from typing import Any


def settings(obj: Any) -> list[dict[str, Any]]:
    """The settings of ``obj``, a settings dataclass (none for anything else).

    Returns
    -------
    list of dict
        ``name``, ``type`` (as annotated), ``default`` (None if required) and
        ``meaning`` per public field, in declaration order.
    """
    target = obj
    if not (isinstance(target, type) and dataclasses.is_dataclass(target)):
        return []
    rows = []
    for f in dataclasses.fields(target):
        if f.name.startswith("_") or not f.init:
            continue
        if f.default is not dataclasses.MISSING:
            default: Any = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = None
        rows.append(
            {
                "name": f.name,
                "type": str(f.type),
                "default": default,
                "meaning": _meaning(target, f.name),
            }
        )
    return rows


def summary_line(obj: Any) -> str:
    """The first sentence of ``obj``'s docstring, without reST markup."""
    doc = (obj.__doc__ or "").strip().splitlines()
    return _sentence(doc[0]) if doc else ""


def _meaning(cls: type, name: str) -> str:
    """``name``'s entry in a numpy docstring's Attributes/Parameters, in full.

    The class that declares the field is asked first, then the others of the
    MRO.
    """
    owners = [c for c in cls.__mro__ if name in inspect.get_annotations(c)]
    for c in owners + [c for c in cls.__mro__ if c not in owners]:
        text = _doc_entries(c.__doc__ or "").get(name, "")
        if text and not text.lower().startswith("the shared settings"):
            return text
    return ""


def _doc_entries(doc: str) -> dict[str, str]:
    """``{name: its whole description, one line}`` of Attributes/Parameters."""
    lines = inspect.cleandoc(doc).splitlines()
    out: dict[str, str] = {}
    section = False
    names: list[str] = []
    for i, line in enumerate(lines):
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if nxt.startswith("---") and line.strip():
            section = line.strip() in ("Attributes", "Parameters")
            names = []
            continue
        if not section or line.startswith("---") or not line.strip():
            continue
        if not line.startswith(" "):
            names = [n.strip() for n in line.split(":")[0].split(",")]
        elif names:
            for n in names:
                out[n] = f"{out.get(n, '')} {line.strip()}".strip()
    return {n: _plain(t) for n, t in out.items()}


def _plain(text: str) -> str:
    """``text`` without reST markup."""
    return text.replace("``", "").replace(":class:", "").replace("~", "")


def _sentence(text: str) -> str:
    """The first sentence of ``text``, without reST markup."""
    text = _plain(text)
    end = text.find(". ")
    return text if end < 0 else text[: end + 1]
