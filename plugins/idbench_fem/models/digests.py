"""What keys a solid model's truths: SHA-256 digests of its body and meshes.

A body or mesh read from a file is keyed on the file's bytes; one built in
memory (the beam's) on what its states depend on. The model's ``describe``
gives them, and the core's truth cache keys on that.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import replace
from pathlib import Path

from idbench_fem.bodies.description import Body, Markers, ShapeError
from idbench_fem.bodies.mesh import SolidMesh


def _file_digest(path: Path) -> str:
    """The file's SHA-256, computed once per modification time."""
    return _digest_cached(path, path.stat().st_mtime)


def body_digest(body: Body) -> str:
    """The body file's SHA-256; of what the states depend on for a body in memory.

    That is its description without markers, shape-error points and probes,
    so that one truth serves every marker count (as the truth's key wants).
    """
    path = Path(body.source)
    if path.is_file():
        return _file_digest(path)
    states = replace(body, markers=Markers(), shape_error=ShapeError(), probes=())
    text = repr(states) + "".join(  # a driven grasp's displacement is no repr
        f"|{m.name}:{m.displacement}" for m in body.manipulations if m.driven
    )
    text += "".join(  # nor is conserve
        f"|{m.name}:conserve={m.conserve}"
        for m in body.manipulations
        if m.conserve != "none"
    )
    if body.supports or body.reference:  # nor are these (both change states)
        text += f"|{body.supports!r}|{body.reference!r}"
    if body.modulus_field is not None:  # no repr either
        text += f"|field:{body.modulus_field!r}"
    return hashlib.sha256(text.encode()).hexdigest()


def mesh_digest(mesh: SolidMesh) -> str:
    """The mesh file's SHA-256; of its arrays for a mesh built in memory."""
    path = Path(mesh.path)
    return _file_digest(path) if path.is_file() else mesh.digest()


@functools.lru_cache(maxsize=64)
def _digest_cached(path: Path, mtime: float) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()
