r"""Procedural organ-like bodies meshed with gmsh (OpenCASCADE) at several sizes.

Two geometries, in metres, built from scaled spheres so that no data has to be
downloaded:

``liver``
    A liver-like lobe about 16 x 10 x 8 cm: a large right-lobe ellipsoid fused
    with a thinner left-lobe ellipsoid (:data:`LIVER_ELLIPSOIDS`). Frame: x
    along the long axis (right lobe at +x), y antero-posterior (+y anterior),
    z cranio-caudal (+z superior). Physical groups: surfaces ``ligament`` (the
    superior-posterior "bare area" where the lobe hangs from the diaphragm,
    the fixed region), ``anterior`` (what a laparoscope sees: marker
    candidates), ``inferior_edge`` (the antero-inferior rim a tool grasps),
    ``posterior`` (the rest); volume ``liver``.
``kidney``
    A kidney-like bean about 11 x 6 x 4 cm: an ellipsoid with an ellipsoidal
    notch cut at the hilum (-y side), and a stiff spherical inclusion
    (a tumour, radius 10 mm; element size at most radius / 2 inside it, so
    it is resolved at every resolution). Physical groups: surfaces ``hilum`` (the notch,
    where vessels and ureter hold it: the fixed region), ``anterior``
    (z > 0), ``posterior`` (z < 0); volumes ``parenchyma`` and ``inclusion``.

The patches are cut into the CAD model (OpenCASCADE ``fragment`` with boxes),
so every resolution has exactly the same fixed region and patches, and the
meshes are conforming across them. Files are gmsh MSH 4.1: meshio reads it
with the physical groups as ``cell_sets`` (names as in gmsh).

Reproducibility: one thread, fixed algorithms and options, no randomness; the
same input gives byte-identical files, and a node-count target gives the same
mesh whatever other sizes are asked for (tested).

Cost (2 shared cores, load ~7): the ~16,000-node truth (about 85,000 tets)
takes 4 s to mesh at a given element length and 13 s with a node-count target
(a few trial meshes find the length), about 130 MB peak memory, for either
geometry; meshes of 200-2,000 nodes take 1-3 s each.
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

Ellipsoid = tuple[tuple[float, float, float], tuple[float, float, float]]
"""(centre, semi-axes), metres."""

LIVER_ELLIPSOIDS: tuple[Ellipsoid, ...] = (
    ((0.030, 0.000, 0.000), (0.055, 0.050, 0.040)),  # right lobe
    ((-0.030, 0.005, 0.010), (0.045, 0.035, 0.022)),  # left lobe
)
"""The liver is the union of these ellipsoids."""

KIDNEY_ELLIPSOID: Ellipsoid = ((0.0, 0.0, 0.0), (0.055, 0.030, 0.020))
"""The kidney before the hilum notch."""

KIDNEY_NOTCH: Ellipsoid = ((0.0, -0.032, 0.0), (0.022, 0.018, 0.030))
"""Removed from the kidney ellipsoid: the hilum."""

KIDNEY_INCLUSION: tuple[tuple[float, float, float], float] = ((0.02, 0.003, 0.0), 0.01)
"""Centre and radius of the stiff inclusion (m)."""

TRUTH_NODES = 16_000
"""Default node-count target of the truth mesh."""

_REFERENCE_SIZE = {"liver": 0.012, "kidney": 0.008}
"""Element size (m) giving about 600 nodes."""

_NODE_TOLERANCE = 0.05  # relative, for node-count targets
_ATTEMPTS = 8


@dataclass(frozen=True)
class MeshInfo:
    """What :func:`make_meshes` wrote: file, size asked for, nodes and time."""

    path: Path
    size: float
    h: float
    nodes: int
    tets: int
    seconds: float


def _ellipsoid(occ, centre, axes) -> tuple[int, int]:  # type: ignore[no-untyped-def]
    tag = occ.addSphere(*centre, 1.0)
    occ.dilate([(3, tag)], *centre, *axes)
    return (3, tag)


def _box(occ, lo, hi) -> tuple[int, int]:  # type: ignore[no-untyped-def]
    return (3, occ.addBox(*lo, *(b - a for a, b in zip(lo, hi, strict=True))))


def _build_liver(gmsh, h: float) -> None:  # type: ignore[no-untyped-def]
    occ = gmsh.model.occ
    lobes = [_ellipsoid(occ, c, a) for c, a in LIVER_ELLIPSOIDS]
    body, _ = occ.fuse(lobes[:1], lobes[1:])
    tools = {
        "ligament": _box(occ, (0.0, -0.06, 0.028), (0.09, 0.01, 0.08)),
        "inferior_edge": _box(occ, (0.01, 0.02, -0.06), (0.07, 0.07, -0.02)),
        "anterior": _box(occ, (-0.1, 0.0, -0.1), (0.1, 0.1, 0.1)),
    }
    _, pieces = occ.fragment(body, list(tools.values()))
    occ.synchronize()
    kept = pieces[0]
    _remove_others(gmsh, kept)
    labels = _label_surfaces(gmsh, kept, dict(zip(tools, pieces[1:], strict=True)))
    for name in ("ligament", "anterior", "inferior_edge", "posterior"):
        gmsh.model.addPhysicalGroup(2, labels[name], name=name)
    gmsh.model.addPhysicalGroup(3, [t for _, t in kept], name="liver")


def _build_kidney(gmsh, h: float) -> None:  # type: ignore[no-untyped-def]
    occ = gmsh.model.occ
    bean = _ellipsoid(occ, *KIDNEY_ELLIPSOID)
    notch = _ellipsoid(occ, *KIDNEY_NOTCH)
    centre, radius = KIDNEY_INCLUSION
    inclusion = (3, occ.addSphere(*centre, radius))
    anterior = _box(occ, (-0.1, -0.1, 0.0), (0.1, 0.1, 0.1))
    _, pieces = occ.fragment([bean], [notch, inclusion, anterior])
    occ.synchronize()
    removed = set(pieces[1])
    kept = [v for v in pieces[0] if v not in removed]
    hilum = {
        s for _, s in gmsh.model.getBoundary(list(removed), oriented=False)
    }  # faces the notch shares with the kept bean survive the removal
    _remove_others(gmsh, kept)
    labels = _label_surfaces(gmsh, kept, {"anterior": pieces[3]})
    surfaces = labels["anterior"] + labels["posterior"]
    gmsh.model.addPhysicalGroup(
        2, sorted(s for s in surfaces if s in hilum), name="hilum"
    )
    for name in ("anterior", "posterior"):
        rest = [s for s in labels[name] if s not in hilum]
        gmsh.model.addPhysicalGroup(2, rest, name=name)
    inner = set(pieces[2])
    gmsh.model.addPhysicalGroup(
        3, [t for v in kept if v not in inner for t in v[1:]], name="parenchyma"
    )
    gmsh.model.addPhysicalGroup(
        3, [t for v in kept if v in inner for t in v[1:]], name="inclusion"
    )
    # resolve the inclusion at every resolution: size <= radius / 2 inside it
    field = gmsh.model.mesh.field
    ball = field.add("Ball")
    field.setNumber(ball, "XCenter", centre[0])
    field.setNumber(ball, "YCenter", centre[1])
    field.setNumber(ball, "ZCenter", centre[2])
    field.setNumber(ball, "Radius", radius)
    field.setNumber(ball, "Thickness", radius)
    field.setNumber(ball, "VIn", min(h, radius / 2.0))
    field.setNumber(ball, "VOut", h)
    field.setAsBackgroundMesh(ball)


def _remove_others(gmsh, kept) -> None:  # type: ignore[no-untyped-def]
    """Delete the tool pieces outside the body."""
    others = [v for v in gmsh.model.getEntities(3) if v not in set(kept)]
    gmsh.model.occ.remove(others, recursive=True)
    gmsh.model.occ.synchronize()


def _label_surfaces(gmsh, kept, tools) -> dict[str, list[int]]:  # type: ignore[no-untyped-def]
    """Label each outer surface by the first tool its volume piece lies in.

    An outer surface bounds exactly one volume piece of the fragmented body,
    and that piece lies inside or outside each tool; surfaces of pieces in no
    tool are ``posterior``.
    """
    labels: dict[str, list[int]] = {name: [] for name in (*tools, "posterior")}
    for _, s in gmsh.model.getBoundary(kept, combined=True, oriented=False):
        up, _ = gmsh.model.getAdjacencies(2, s)
        piece = (3, int(up[0]))
        name = next((n for n, vols in tools.items() if piece in vols), "posterior")
        labels[name].append(int(s))
    return {k: sorted(v) for k, v in labels.items()}


GEOMETRIES: dict[str, Callable[..., None]] = {
    "liver": _build_liver,
    "kidney": _build_kidney,
}
"""Builders by name: each adds the CAD model and its physical groups."""


def _mesh(geometry: str, h: float, path: Path | None) -> tuple[int, int]:
    """Mesh ``geometry`` with element size ``h``; write to ``path`` if given.

    Returns the number of nodes and of tetrahedra.
    """
    import gmsh

    gmsh.initialize(interruptible=False)
    try:
        opt = gmsh.option.setNumber
        opt("General.Terminal", 0)
        opt("General.NumThreads", 1)
        opt("Mesh.MaxNumThreads1D", 1)
        opt("Mesh.MaxNumThreads2D", 1)
        opt("Mesh.MaxNumThreads3D", 1)
        opt("Mesh.Algorithm", 6)  # Frontal-Delaunay surfaces
        opt("Mesh.Algorithm3D", 1)  # Delaunay
        opt("Mesh.RandomSeed", 1)
        opt("Mesh.MeshSizeMin", 0.0)
        opt("Mesh.MeshSizeMax", h)
        opt("Mesh.MeshSizeFromCurvature", 0)
        opt("Mesh.MeshSizeFromPoints", 0)
        opt("Mesh.MeshSizeExtendFromBoundary", 0)
        opt("Mesh.Optimize", 1)
        opt("Mesh.MshFileVersion", 4.1)
        opt("Mesh.Binary", 0)
        opt("Mesh.SaveAll", 0)
        gmsh.model.add(geometry)
        GEOMETRIES[geometry](gmsh, h)
        gmsh.model.mesh.generate(3)
        tets, nodes = gmsh.model.mesh.getElementsByType(4)  # 4: linear tets
        n_nodes = len(set(nodes.tolist()))
        if path is not None:
            gmsh.write(str(path))
        return n_nodes, len(tets)
    finally:
        gmsh.finalize()


def _length_for(geometry: str, n_nodes: int, h0: float) -> tuple[float, int, int]:
    """Find an element size whose mesh has ``n_nodes`` within 5%.

    Secant steps on log(nodes) against log(h), starting from ``h0``; returns
    the size and its node and tet counts (the closest found if none is within
    the tolerance).
    """
    import math

    tried: list[tuple[float, int, int]] = []
    h, slope = h0, -3.0
    for _ in range(_ATTEMPTS):
        nodes, tets = _mesh(geometry, h, None)
        tried.append((h, nodes, tets))
        if abs(nodes / n_nodes - 1) <= _NODE_TOLERANCE:
            break
        if len(tried) >= 2:
            (h1, n1, _), (h2, n2, _) = tried[-2:]
            if n1 != n2 and h1 != h2:
                slope = min(-1.5, max(-4.0, math.log(n2 / n1) / math.log(h2 / h1)))
        h *= (n_nodes / nodes) ** (1.0 / slope)
    return min(tried, key=lambda t: abs(math.log(t[1] / n_nodes)))


def make_meshes(
    geometry: str, sizes: Sequence[float], out_dir: str | Path
) -> list[Path]:
    """Mesh ``geometry`` at several sizes; return the files, coarse to fine.

    Parameters
    ----------
    geometry
        ``"liver"`` or ``"kidney"``.
    sizes
        Each an ``int``: a target node count (met within 5% by adjusting the
        element size), or a ``float``: the characteristic element length in
        metres (gmsh's ``MeshSizeMax``; finer inside the kidney's inclusion). E.g.
        ``[200, 500, 1000, 2000, TRUTH_NODES]``.
    out_dir
        Created if missing. Files are ``{geometry}-n{count}.msh`` for node
        targets and ``{geometry}-h{length}.msh`` for lengths; existing ones
        are overwritten.

    Returns
    -------
    list of Path
        Sorted by node count (the last one is the truth mesh).
    """
    return [info.path for info in mesh_series(geometry, sizes, out_dir)]


def mesh_series(
    geometry: str, sizes: Sequence[float], out_dir: str | Path
) -> list[MeshInfo]:
    """:func:`make_meshes` with node counts and timings, coarse to fine."""
    if geometry not in GEOMETRIES:
        raise ValueError(f"geometry {geometry!r}: allowed are {', '.join(GEOMETRIES)}")
    if not sizes:
        raise ValueError("sizes: give at least one node count or element length")
    for s in sizes:
        ok = isinstance(s, int | float) and not isinstance(s, bool) and s > 0
        if not ok or (isinstance(s, int) and s < 50):
            raise ValueError(
                f"size {s!r}: give a node count (int >= 50) or an element "
                "length in metres (float > 0)"
            )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    infos = []
    for size in sizes:
        t0 = time.perf_counter()
        if isinstance(size, int):
            # a start that depends on (geometry, size) only, so that a size
            # gives the same mesh whatever else is in the list
            h0 = _REFERENCE_SIZE[geometry] * (600 / size) ** (1.0 / 3.0)
            h, _, _ = _length_for(geometry, size, h0)
            name = f"{geometry}-n{size}.msh"
        else:
            h, name = float(size), f"{geometry}-h{size:g}.msh"
        path = out / name
        nodes, tets = _mesh(geometry, h, path)
        info = MeshInfo(path, float(size), h, nodes, tets, time.perf_counter() - t0)
        log.info(
            "%s: %d nodes, %d tets, h = %.4g m, %.1f s",
            name,
            nodes,
            tets,
            h,
            info.seconds,
        )
        infos.append(info)
    return sorted(infos, key=lambda i: i.nodes)


def main(argv: Sequence[str] | None = None) -> None:
    """Command line.

    ``python -m idbench_fem.bodies.geometry liver --sizes 200,2000``.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("geometry", choices=sorted(GEOMETRIES))
    parser.add_argument(
        "--sizes",
        default=f"200,500,1000,2000,{TRUTH_NODES}",
        help="comma-separated node counts (ints) or element lengths in m (floats)",
    )
    parser.add_argument("--out", default=".", help="output directory")
    args = parser.parse_args(argv)
    sizes = [float(s) if "." in s else int(s) for s in args.sizes.split(",")]
    for info in mesh_series(args.geometry, sizes, args.out):
        print(
            f"{info.path}\t{info.nodes} nodes\t{info.tets} tets\t"
            f"h = {info.h:.4g} m\t{info.seconds:.1f} s"
        )


if __name__ == "__main__":
    main()
