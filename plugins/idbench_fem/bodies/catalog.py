"""Where a body and its meshes are: shipped bodies, mesh specs, the mesh cache.

A *body spec* is a path to a body TOML or the name of a shipped example
(:data:`SHIPPED`: ``liver``, ``kidney``). A *mesh spec* (what ``idbench
compare --meshes`` passes to the ``solid`` model) is one of

- ``truth``: the body's ``[mesh] truth``;
- a mesh file path (anything meshio reads);
- a file name stem of the body's meshes (``liver-n500``);
- a node count ``N``: the body's mesh named ``*-nN``, else, for a body with
  ``[mesh] generate``, a mesh of ``N`` nodes generated on first use.

Meshes of a ``[mesh] generate`` body that are missing are generated into
the cache folder (``$IDBENCH_CACHE_DIR/meshes/GEOMETRY``, by default the
user cache folder), never next to the body file; the files a body lists that
exist are used where they are.
"""

from __future__ import annotations

import functools
import os
import re
import tempfile
from pathlib import Path

from idbench_fem.bodies.description import Body, load_body
from idbench_fem.bodies.mesh import SolidMesh, read_mesh

SHIPPED = ("liver", "kidney")
"""Names of the shipped example bodies (``examples/NAME/body.toml``)."""

CACHE_ENV = "IDBENCH_CACHE_DIR"

_SIZE = re.compile(r"-n(\d+)$")


def body_path(spec: str) -> Path:
    """The body TOML of ``spec``: a shipped example's name or a path.

    Raises
    ------
    ValueError
        If the file does not exist (naming the shipped examples).
    """
    if spec in SHIPPED:
        package = Path(__file__).resolve().parent.parent  # idbench_fem/
        for candidate in (
            package / "examples" / f"{spec}.toml",  # the wheel's copy
            package.parent.parent / "examples" / spec / "body.toml",  # a checkout
        ):
            if candidate.is_file():
                return candidate
    path = Path(spec).expanduser()
    if not path.is_file():
        raise ValueError(
            f"body {spec!r}: no such file; give a body TOML path or one of "
            f"{', '.join(SHIPPED)}"
        )
    return path.resolve()


@functools.lru_cache(maxsize=16)
def _load(path: Path, mtime: float) -> Body:
    return load_body(path)


def get_body(spec: str) -> Body:
    """Parse (once per process and file version) the body ``spec``."""
    path = body_path(spec)
    return _load(path, path.stat().st_mtime)


def mesh_cache() -> Path:
    """Folder of generated meshes: ``$IDBENCH_CACHE_DIR/meshes`` or the user's."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env) / "meshes"
    import platformdirs

    return Path(platformdirs.user_cache_dir("idbench")) / "meshes"


def _generated(body: Body, name: str) -> Path:
    """The cached mesh file ``name`` of a generate body, made if missing."""
    geometry = body.mesh.geometry
    assert geometry is not None
    folder = mesh_cache() / geometry
    path = folder / name
    if path.is_file():
        return path
    m = _SIZE.search(Path(name).stem)
    if m is None:
        raise ValueError(
            f"{body.source}: cannot generate {name!r}: generated meshes are "
            f"named {geometry}-nNODES.msh"
        )
    from idbench_fem.bodies.geometry import make_meshes

    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:  # atomic for parallel runs
        (made,) = make_meshes(geometry, [int(m.group(1))], tmp)
        os.replace(made, path)
    return path


def _listed(body: Body, path: Path) -> Path:
    """A mesh file the body lists: where it is, or generated into the cache."""
    if path.is_file():
        return path
    if body.mesh.geometry is not None:
        return _generated(body, path.name)
    raise ValueError(
        f"{body.source}: mesh file {str(path)!r} does not exist (add [mesh] "
        "generate = {...} or make it)"
    )


def mesh_file(body: Body, spec: str) -> Path:
    """The mesh file of a mesh ``spec`` for ``body`` (see the module docstring).

    Raises
    ------
    ValueError
        One line naming the spec and the meshes the body has.
    """
    spec = str(spec).strip()
    listed = [*body.mesh.models, body.mesh.truth]
    if spec == "truth":
        return _listed(body, body.mesh.truth)
    for path in listed:
        if spec == path.stem:
            return _listed(body, path)
    if spec.isdigit():
        for path in listed:
            m = _SIZE.search(path.stem)
            if m is not None and m.group(1) == spec:
                return _listed(body, path)
        if body.mesh.geometry is not None:
            if int(spec) < 50:
                raise ValueError(f"mesh {spec!r}: need at least 50 nodes")
            return _generated(body, f"{body.mesh.geometry}-n{spec}.msh")
    path = Path(spec).expanduser()
    if path.is_file():
        return path.resolve()
    names = ", ".join(p.stem for p in listed)
    raise ValueError(
        f"mesh {spec!r}: not a file, nor one of {body.source}'s meshes ({names}, "
        "truth)" + (", nor a node count" if body.mesh.geometry else "")
    )


@functools.lru_cache(maxsize=8)
def _read(path: Path, mtime: float, size: int) -> SolidMesh:
    return read_mesh(path)


def get_mesh(path: Path) -> SolidMesh:
    """Read (once per process and file version) the mesh at ``path``."""
    st = path.stat()
    return _read(path, st.st_mtime, st.st_size)
