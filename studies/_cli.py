"""The command line every study script shares: ``--quick``, ``--out``, progress."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path


def parser(doc: str, out: str) -> argparse.ArgumentParser:
    """Arguments of a study (add more before ``parse_args``); logs progress.

    Parameters
    ----------
    doc
        The script's module docstring; its first line describes the script.
    out
        Default results folder, e.g. ``"results/fig2"``.
    """
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small meshes, seconds")
    p.add_argument("--out", type=Path, default=Path(out), help=f"default {out}")
    return p
