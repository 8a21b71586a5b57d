r"""Text from plugins or from a shared output folder, made safe to show.

Names, settings and error messages come from plugins (or from a
``runs.parquet`` someone else wrote) and reach a terminal, ``report.md`` and
``report.html``. :func:`printable` is the one function every such string goes
through: control characters (C0 ``\x00``-``\x1f``, DEL, C1 ``\x80``-``\x9f``)
and Unicode bidirectional overrides become visible escapes (``\n``,
``\x1b``, ``\u202e``), so no ANSI/OSC sequence reaches a terminal (no
hyperlink, no cleared screen), a newline cannot break a table row, and two
names that differ only by such characters stay distinguishable. The
wrappers add what each medium needs on top: :func:`markdown_cell` (HTML
escaped, table pipes and link brackets escaped), :func:`rich_text` (rich
markup shown as text); HTML pages use ``html.escape(printable(s))``.
"""

from __future__ import annotations

import html
import re
from typing import Any

_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")
_SPACES = re.compile(r"[\t\n\r\f\v]+")


def printable(text: Any, *, join_lines: bool = False) -> str:
    r"""``text`` as a single line of visible characters.

    Parameters
    ----------
    text
        Any value; ``str()`` of it is used.
    join_lines
        For messages: line breaks and tabs become one space (a message's
        lines joined) instead of a visible ``\n``.

    Examples
    --------
    >>> printable("a\x1b[2Jb\nc")
    'a\\x1b[2Jb\\nc'
    >>> printable("line one\n  line two", join_lines=True)
    'line one   line two'
    """
    s = str(text)
    if join_lines:
        s = _SPACES.sub(" ", s)
    return _CONTROL.sub(_escape, s)


def _escape(m: re.Match[str]) -> str:
    c = m.group(0)
    if c in _NAMED:
        return _NAMED[c]
    return f"\\x{ord(c):02x}" if ord(c) < 0x100 else f"\\u{ord(c):04x}"


def markdown_cell(text: Any, *, join_lines: bool = False) -> str:
    r""":func:`printable` text for a markdown table cell or line.

    HTML is escaped (``<``, ``>``, ``&``: a renderer shows it as text), and
    so are backslashes, ``|`` (a cell stays a cell) and ``[``/``]`` (no
    link is made from a name).

    Examples
    --------
    >>> markdown_cell("a|b<img src=x>")
    'a\\|b&lt;img src=x&gt;'
    """
    s = html.escape(printable(text, join_lines=join_lines), quote=False)
    for c in "\\|[]":
        s = s.replace(c, "\\" + c)
    return s


def rich_text(text: Any, *, join_lines: bool = False) -> Any:
    """:func:`printable` text as a ``rich.text.Text``: markup is not interpreted."""
    from rich.text import Text

    return Text(printable(text, join_lines=join_lines))


def rich_markup(text: Any, *, join_lines: bool = False) -> str:
    """:func:`printable` text with rich markup escaped, for a markup string."""
    from rich.markup import escape

    return str(escape(printable(text, join_lines=join_lines)))
