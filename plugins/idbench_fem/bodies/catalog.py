"""Where a body and its meshes are: shipped bodies, mesh specs, the mesh cache.

A *body spec* is a path to a body TOML or the name of a shipped example
(:data:`SHIPPED`: ``liver``, ``kidney``). A *mesh spec* (what ``idbench
compare --meshes`` passes to the ``solid`` model) is one of

- ``truth``: the body's ``[mesh] truth``;
- a mesh file path (anything meshio reads);
- a file name stem of the body's meshes (``liver-n500``);
- a node count ``N``: the body's mesh named ``*-nN``; else, for a body with
  ``[mesh] generate``, a mesh of ``N`` nodes generated on first use; else the
  body's mesh file that has ``N`` nodes (whatever it is called).

Meshes of a ``[mesh] generate`` body that are missing are generated into
the cache folder (``$IDBENCH_CACHE_DIR/meshes/GEOMETRY``, by default the
user cache folder), never next to the body file; the files a body lists that
exist are used where they are. A generated mesh enters the cache only whole
and valid: gmsh writes it to a temporary folder beside it, it is read back
(meshio) and its node and tet counts and coordinates checked, then renamed
into place; a cached mesh that cannot be read (truncated by a full disk,
damaged) is generated again, with a warning.
"""

from __future__ import annotations

import errno
import functools
import logging
import os
import re
import tempfile
from pathlib import Path

import numpy as np

from idbench_fem.bodies.description import Body, load_body
from idbench_fem.bodies.mesh import SolidMesh, read_mesh

SHIPPED = ("liver", "kidney")
"""Names of the shipped example bodies (``examples/NAME/body.toml``)."""

CACHE_ENV = "IDBENCH_CACHE_DIR"

log = logging.getLogger(__name__)

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
    m = _SIZE.search(Path(name).stem)
    if path.is_file():
        try:
            get_mesh(path)  # read once per process anyway: the model needs it
            return path
        except (ValueError, OSError) as exc:
            if m is None:
                raise
            log.warning("cached mesh %s is unusable (%s); generating it again",
                        path, exc)  # fmt: skip
    if m is None:
        raise ValueError(
            f"{body.source}: cannot generate {name!r}: generated meshes are "
            f"named {geometry}-nNODES.msh"
        )
    try:
        _generate(geometry, int(m.group(1)), path)
    except OSError as exc:  # a full disk: one line naming the file
        if exc.errno is None:
            raise OSError(f"{exc} writing {str(path)!r}") from None
        text = exc.strerror or os.strerror(exc.errno)
        if exc.errno == errno.ENOSPC:
            text += " (the disk is full)"
        raise OSError(exc.errno, f"{text} writing", str(path)) from None
    return path


def _generate(geometry: str, nodes: int, path: Path) -> None:
    """Generate the mesh of ``nodes`` nodes into ``path``: whole and valid or not.

    Raises
    ------
    ValueError
        The file gmsh wrote does not read back as the mesh it made (naming
        ``path``); nothing is left in the cache.
    """
    from idbench_fem.bodies.geometry import mesh_series

    path.parent.mkdir(parents=True, exist_ok=True)
    # a folder beside the file, so that the rename is atomic (parallel runs)
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=".tmp-") as tmp:
        (info,) = mesh_series(geometry, [nodes], tmp)
        try:
            mesh = read_mesh(info.path)
        except ValueError as exc:
            raise ValueError(
                f"generated mesh {str(path)!r}: the file gmsh wrote is unusable "
                f"({exc}); is the disk full?"
            ) from None
        found = (len(mesh.points), len(mesh.tets))
        if found != (info.nodes, info.tets) or not np.isfinite(mesh.points).all():
            raise ValueError(
                f"generated mesh {str(path)!r}: the file gmsh wrote has "
                f"{found[0]} nodes and {found[1]} tets, gmsh made {info.nodes} "
                f"and {info.tets}; is the disk full?"
            )
        os.replace(info.path, path)


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
        return _by_node_count(body, int(spec))
    path = Path(spec).expanduser()
    if path.is_file():
        return path.resolve()
    names = ", ".join(p.stem for p in listed)
    raise ValueError(
        f"mesh {spec!r}: not a file, nor one of {body.source}'s meshes ({names}, "
        "truth)" + (", nor a node count" if body.mesh.geometry else "")
    )


def _by_node_count(body: Body, n: int) -> Path:
    """The body's listed mesh file with ``n`` nodes (as the model sees them)."""
    listed = [*body.mesh.models, body.mesh.truth]
    counts = []
    for path in listed:
        if path.is_file():
            nodes = len(get_mesh(path).points)
            if nodes == n:
                return path
            counts.append(f"{path.stem} {nodes}")
    raise ValueError(
        f"mesh {str(n)!r}: no mesh of {body.source} has {n} nodes (its meshes: "
        f"{', '.join(counts) or 'none on disk'}); give a node count, a file name "
        "stem, truth or a mesh file path"
    )


def mesh_spec(body: Body, path: Path) -> str:
    """How ``--meshes`` names the body's mesh file ``path``.

    N for a file named ``*-nN``, else its file name stem (``truth`` for the
    truth if its stem is another mesh's too).
    """
    m = _SIZE.search(path.stem)
    if m is not None:
        return m.group(1)
    stems = [p.stem for p in (*body.mesh.models, body.mesh.truth)]
    if stems.count(path.stem) > 1 and path == body.mesh.truth:
        return "truth"
    return path.stem


@functools.lru_cache(maxsize=8)
def _read(path: Path, mtime: float, size: int) -> SolidMesh:
    return read_mesh(path)


def get_mesh(path: Path) -> SolidMesh:
    """Read (once per process and file version) the mesh at ``path``."""
    st = path.stat()
    return _read(path, st.st_mtime, st.st_size)
