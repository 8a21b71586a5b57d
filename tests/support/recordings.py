"""Edited copies of a recording folder, for the tests of what the door refuses."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from idbench.store import recording


def arrays_of(path: Path) -> dict[str, np.ndarray]:
    """The arrays of the recording folder ``path`` (name: array), loaded."""
    with np.load(path / recording.ARRAYS) as npz:
        return {k: np.array(npz[k]) for k in npz.files}


def edited_copy(
    src: Path,
    dst: Path,
    arrays: Callable[[dict[str, np.ndarray]], None] | None = None,
    toml: Callable[[str], str] | None = None,
) -> Path:
    """A copy ``dst`` of the recording folder ``src``, edited; ``dst``.

    Parameters
    ----------
    src, dst
        The recording folder and where its copy goes (it must not exist).
    arrays
        Edits the arrays (name: array) in place; they are saved again.
    toml
        Takes the manifest's text and returns the one to write.
    """
    shutil.copytree(src, dst)
    if arrays is not None:
        data = arrays_of(dst)
        arrays(data)
        np.savez(dst / recording.ARRAYS, **data)
    if toml is not None:
        path = dst / recording.MANIFEST
        path.write_text(toml(path.read_text()))
    return dst
