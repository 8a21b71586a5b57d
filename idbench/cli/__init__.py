"""The ``idbench`` command.

Its parser, its commands and progress on the terminal.
"""

from __future__ import annotations

from idbench.cli.commands import main

__all__ = ["main"]
