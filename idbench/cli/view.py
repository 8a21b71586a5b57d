"""``idbench view DIR [--run ID]``: open a comparison's 3D view in a browser.

The view is report.html's (:mod:`idbench.report.view3d`); it is written first
when it is missing or older than the results, or when the folder's stored
surfaces fail their checks (the page then says so instead of showing them).
Where no browser can be started (a terminal over ssh, no display), the file's
path is printed instead, to open elsewhere.
"""

from __future__ import annotations

import argparse
import os
import sys
import webbrowser
from pathlib import Path
from typing import Any

DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY")
"""Without one of these, a Linux or BSD session has no screen to open a page on."""


class ViewError(ValueError):
    """``idbench view`` cannot show DIR as asked (one line)."""


def add_parser(sub: Any) -> None:
    """Add the ``view`` subcommand to the ``idbench`` parser's ``sub``."""
    v = sub.add_parser(
        "view",
        help="open a compare output's 3D view in the browser",
        description="Open DIR's report.html at its 3D view in the web browser "
        "(writing the report first if it is missing or older than the results); "
        "without a browser (e.g. over ssh), print the file's path.",
    )
    v.add_argument("directory", type=Path, help="the --out DIR of idbench compare")
    v.add_argument("--run", metavar="ID", help="show this run first (its run_id)")
    v.add_argument(
        "--no-browser", action="store_true", help="only print the file's path"
    )


def cmd_view(args: argparse.Namespace) -> int:
    """``idbench view DIR``: see the module."""
    import pandas as pd

    from idbench.report.write import write_report

    root = Path(args.directory)
    if not (root / "runs.parquet").exists():
        raise ViewError(
            f"{root / 'runs.parquet'} not found: is {root} a compare output?"
        )
    page = root / "report.html"
    if stale(root):
        write_report(root)
    fragment = "view"
    if args.run:
        ids = [str(i) for i in pd.read_parquet(root / "runs.parquet")["run_id"]]
        found = [i for i in ids if i == args.run] or [
            i for i in ids if i.startswith(args.run)
        ]
        if len(found) != 1:
            what = "no run" if not found else f"{len(found)} runs"
            raise ViewError(f"--run {args.run!r}: {what} of {root} has that id")
        fragment = f"run={found[0]}"
    url = page.resolve().as_uri() + "#" + fragment
    if not args.no_browser and can_open() and webbrowser.open(url):
        print(f"opened {page}")
        return 0
    print(page)
    print(
        "(no browser here: open that file in a browser, e.g. after copying the "
        f"folder to your machine, at #{fragment})"
    )
    return 0


def stale(root: Path) -> bool:
    """Whether DIR's report.html must be written again before it is shown."""
    import json

    from idbench.store import surfaces

    page = root / "report.html"
    if not page.exists():
        return True
    written = page.stat().st_mtime
    sources = [root / "runs.parquet", *surfaces.folder(root).glob("*.npz")]
    if any(p.stat().st_mtime > written for p in sources if p.exists()):
        return True
    try:
        inputs = json.loads((root / "manifest.json").read_text()).get("inputs", [])
    except (OSError, ValueError, AttributeError):
        inputs = []
    return bool(surfaces.check(root, inputs if isinstance(inputs, list) else []))


def can_open() -> bool:
    """Whether a graphical browser can be started here (a display, or not Unix)."""
    if sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return any(os.environ.get(v) for v in DISPLAY_VARIABLES)
    return True
