"""``idbench check BODY.toml``: a body on each of its meshes, as tables.

Per mesh (the models, then the truth): nodes, tets, the worst tet quality,
volume, mass and fixed area; per manipulation and mesh: the loaded area,
the resultant and its moment about the fixed region's centroid
(:mod:`idbench_fem.bodies.figures`), each also over the truth mesh's, and
the factor ``conserve`` scales the mesh's loads by; each marker's distance
to each mesh's surface and each target's depth below it. Everything the
body's regions, markers and targets do not fit is a problem: one line each
(naming the mesh and the culprit as the TOML counts it), exit 2; else the
tables and exit 0. A load off the truth's by more than 2% is a note (it is
measured, and ``conserve = "resultant"`` removes it), not a problem.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from idbench import LOAD_FIGURES, Command

TOLERANCE = 0.02
"""A load figure off the truth's by more than this gets a note."""


def configure(k: argparse.ArgumentParser) -> None:
    """The arguments of ``idbench check``."""
    k.description = (
        "Check a body TOML on each of its meshes: nodes, tets, quality, fixed "
        "area, each manipulation's loaded area and resultant against the "
        "truth's, markers' and targets' distances to the surface. Exit 2 with "
        "one line per problem."
    )
    k.add_argument("body", help="the body TOML (or a shipped body: liver, kidney)")


def run(args: argparse.Namespace) -> int:
    """``idbench check``: the tables on stdout, problems on stderr."""
    from idbench_fem.bodies.catalog import body_path, get_body

    body = get_body(str(body_path(args.body)))
    tables, problems, notes = inspect(body)
    print("\n\n".join(tables))
    for line in notes:
        print(f"note: {line}")
    for line in problems:
        print(f"idbench: error: {line}", file=sys.stderr)
    return 2 if problems else 0


def _meshes(body: Any, problems: list[str]) -> list[tuple[str, Any]]:
    """(name, mesh) of the body's model meshes then its truth; missing ones noted."""
    from idbench_fem.bodies.catalog import get_mesh, mesh_file, mesh_spec

    out = []
    for path in [*body.mesh.models, body.mesh.truth]:
        try:
            mesh = get_mesh(mesh_file(body, mesh_spec(body, path)))
        except (ValueError, OSError) as exc:
            problems.append(str(exc))
            continue
        out.append((path.stem, mesh))
    return out


def inspect(body: Any) -> tuple[list[str], list[str], list[str]]:
    """The tables, the problems and the notes of ``body`` on its meshes."""
    problems: list[str] = []
    meshes = _meshes(body, problems)
    truth_stem = Path(body.mesh.truth).stem
    if not meshes or meshes[-1][0] != truth_stem:
        problems.append(f"{body.source}: its truth mesh cannot be read: no ratios")
        return [], problems, []
    truth = meshes[-1][1]

    def attempt(fn: Callable[[], Any]) -> Any:
        try:
            return fn()
        except ValueError as exc:
            if str(exc) not in problems:
                problems.append(str(exc))
            return None

    tables = [_mesh_table(body, meshes, attempt)]
    loads, notes = _load_table(body, meshes, truth, attempt)
    tables.append(loads)
    tables += _point_tables(body, meshes, attempt, notes)
    return tables, problems, notes


def _table(head: list[str], rows: list[list[str]], title: str) -> str:
    """An aligned text table: the first column left, the others right."""
    if not rows:
        return f"{title}\n(none: see the problems)"
    widths = [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(head)]

    def line(cells: list[str]) -> str:
        out = [cells[0].ljust(widths[0])]
        out += [c.rjust(w) for c, w in zip(cells[1:], widths[1:], strict=True)]
        return "  ".join(out).rstrip()

    return "\n".join([title, line(head), "  ".join("-" * w for w in widths),
                      *(line(r) for r in rows)])  # fmt: skip


def _g(x: float | None, digits: int = 4) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{digits}g}"


def _ratio(x: float | None, ref: float | None) -> str:
    if x is None or ref is None or not ref:
        return "-"
    return f"{x / ref:.4f}"


def _mesh_table(body: Any, meshes: list[tuple[str, Any]], attempt: Any) -> str:
    from idbench_fem.bodies import resolve
    from idbench_fem.bodies.figures import fixed_region
    from idbench_fem.bodies.mesh import tet_quality

    figs = []
    for _, mesh in meshes:
        fixed = attempt(lambda mesh=mesh: resolve.fixed_nodes(body, mesh))
        area = None if fixed is None else fixed_region(mesh, fixed)[0]
        attempt(lambda mesh=mesh: resolve.element_regions(body, mesh))
        attempt(lambda mesh=mesh: resolve.element_moduli(body, mesh))
        volume = float(mesh.volumes.sum())
        quality = float(tet_quality(mesh.points, mesh.tets).min())
        figs.append((mesh, area, volume, quality))
    _, t_area, t_volume, _ = figs[-1]
    rows = []
    for (name, _), (mesh, area, volume, quality) in zip(meshes, figs, strict=True):
        label = f"{name} (truth)" if mesh is figs[-1][0] else name
        rows.append([
            label, str(len(mesh.points)), str(len(mesh.tets)), f"{quality:.3f}",
            _g(volume), _ratio(volume, t_volume),
            _g(body.material.density * volume), _g(area), _ratio(area, t_area),
        ])  # fmt: skip
    head = ["mesh", "nodes", "tets", "min quality", "volume (m^3)", "/ truth",
            "mass (kg)", "fixed area (m^2)", "/ truth"]  # fmt: skip
    return _table(head, rows, f"{body.source}: meshes (quality: the mean ratio, "
                  "1 regular, 0 flat)")  # fmt: skip


def _load_table(
    body: Any, meshes: list[tuple[str, Any]], truth: Any, attempt: Any
) -> tuple[str, list[str]]:
    from idbench_fem.bodies.figures import conserve_scale, figures
    from idbench_fem.bodies.loads import nodal_forces

    rows, notes = [], []
    for m in body.manipulations:

        def measure(mesh: Any, m: Any = m) -> tuple[dict[str, float], float]:
            if m.driven:
                from idbench_fem.bodies.resolve import driven_nodes

                driven_nodes(body, m.name, mesh)
            scale = conserve_scale(body, m, mesh, truth)
            forces = scale * nodal_forces(m, mesh, body.material.density)
            return figures(body, m, mesh, forces, scale=scale), scale

        found = [
            (name, attempt(lambda mesh=mesh: measure(mesh))) for name, mesh in meshes
        ]
        ref = found[-1][1][0] if found[-1][1] is not None else None
        for name, got in found:
            if got is None:
                continue
            fig, scale = got
            ratio = {
                k: (fig[k] / ref[k] if ref and ref.get(k) else np.nan) for k in fig
            }
            rows.append([
                m.name, m.kind, m.conserve, name, _g(fig["area"]),
                _ratio(fig["area"], ref and ref["area"]), _g(fig["resultant"]),
                _ratio(fig["resultant"], ref and ref["resultant"]),
                _g(fig.get("moment")),
                _ratio(fig.get("moment"), ref and ref.get("moment")),
                f"{scale:.4f}",
            ])  # fmt: skip
            off = [
                f"{k} {ratio[k]:.3f}"
                for k in ("resultant", "moment", "area")
                if k in ratio
                and np.isfinite(ratio[k])
                and abs(ratio[k] - 1) > TOLERANCE
            ]
            if off and name != found[-1][0]:
                fix = (
                    "; conserve = \"resultant\" gives it the truth's force"
                    if m.conserve == "none" and "resultant" in off[0]
                    else ""
                )
                notes.append(
                    f"{m.name} on {name}: its load differs from the truth's by more "
                    f"than {TOLERANCE:.0%} ({', '.join(off)}){fix}"
                )
    units = {k: f" ({u})" for k, u in LOAD_FIGURES.items()}
    head = ["manipulation", "kind", "conserve", "mesh", f"area{units['area']}",
            "/ truth", f"resultant{units['resultant']}", "/ truth",
            f"moment{units['moment']}", "/ truth", "scale"]  # fmt: skip
    title = (
        "loads at the end of each path (moment: about the fixed "
        "region's centroid; scale: conserve's factor)"
    )
    return _table(head, rows, title), notes


def _point_tables(
    body: Any, meshes: list[tuple[str, Any]], attempt: Any, notes: list[str]
) -> list[str]:
    """Markers' distances and targets' depths per mesh.

    Markers and targets are placed on the truth mesh (the comparison's
    reference), so what does not fit the truth is a problem; on a model mesh
    a marker is projected onto its surface and a target outside it is taken
    at the nearest tet: a note.
    """
    from idbench_fem.bodies import resolve
    from idbench_fem.bodies.surface import inside, project_to_surface

    out = []
    mk = body.markers
    names = [name for name, _ in meshes]
    truth = meshes[-1][1]
    if mk.region is not None:
        rows = []
        for name, mesh in meshes:
            pts = attempt(lambda mesh=mesh: resolve.marker_points(body, mesh))
            rows.append([name, "-" if pts is None else str(len(pts))])
        title = f"markers: the surface nodes of region {mk.region.describe()}"
        out.append(_table(["mesh", "markers"], rows, title))
    else:
        pts = np.asarray(mk.points, dtype=float)
        attempt(lambda: resolve.marker_points(body, truth))
        signed = []
        for name, mesh in meshes:
            d = project_to_surface(mesh, pts)[3]
            signed.append(np.where(inside(mesh, pts), -d, d))
            far = np.flatnonzero(d > mk.snap_distance)
            if len(far) and mesh is not truth and mk.placement == "surface":
                i = int(far[0])
                notes.append(
                    f"[markers] point {i + 1} is {1000 * d[i]:.3g} mm from the "
                    f"surface of {name} ({len(far)} marker(s) beyond snap_distance): "
                    "it is placed on the truth and projected onto this mesh"
                )
        rows = [
            [str(i + 1), *(f"{1000 * d[i]:.2f}" for d in signed)]
            for i in range(len(pts))
        ]
        title = (
            "markers: distance to each mesh's surface (mm; < 0 inside; "
            f"snap_distance {1000 * mk.snap_distance:g} mm, placement {mk.placement})"
        )
        out.append(_table(["marker", *names], rows, title))
    if body.targets:
        attempt(lambda: resolve.target_depths(body, truth))
        pts = np.array([p for _, p in body.targets], dtype=float)
        depths = []
        for name, mesh in meshes:
            d = project_to_surface(mesh, pts)[3]
            outside = ~inside(mesh, pts)
            depths.append(np.where(outside, -d, d))
            if outside.any() and mesh is not truth:
                i = int(np.flatnonzero(outside)[0])
                notes.append(
                    f"[targets] {body.targets[i][0]} (target {i + 1}) lies outside "
                    f"{name}, {1000 * d[i]:.3g} mm from its surface: its nearest "
                    "tet is used there"
                )
        rows = [
            [f"{i + 1} {name}", *(f"{1000 * d[i]:.2f}" for d in depths)]
            for i, (name, _) in enumerate(body.targets)
        ]
        title = "targets: depth below each mesh's surface (mm; < 0 outside)"
        out.append(_table(["target", *names], rows, title))
    return out


CHECK = Command(
    help="check a body TOML on each of its meshes (regions, loads, markers)",
    configure=configure,
    run=run,
)
