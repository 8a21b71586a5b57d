"""Headless Chromium for the tests of report.html (through Playwright).

Skipped, with the reason, only where no browser can be driven: Playwright
not installed, or no Chromium (Debian: ``apt-get install chromium``; or
``playwright install chromium``). Nothing here downloads a browser.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from typing import Any

import pytest

CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
]


def chromium() -> str | None:
    """Debian's chromium if installed (None: Playwright's own, if any)."""
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return None


def launched() -> Iterator[Any]:
    """A running headless browser (a generator for a fixture); skips without one."""
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="playwright is not installed (test extra)"
    )
    with sync_api.sync_playwright() as p:
        try:
            b = p.chromium.launch(executable_path=chromium(), args=CHROMIUM_ARGS)
        except Exception as exc:  # no browser binary on this machine
            pytest.skip(f"no Chromium to drive: {str(exc).splitlines()[0]}")
        yield b
        b.close()
