"""``idbench mesh SURFACE``: tetrahedral meshes of a surface file at node counts.

Reads an STL, OBJ or PLY surface (:mod:`idbench_fem.bodies.surface_file`),
refuses one that is open, not manifold or crosses itself (one line each,
saying where, exit 2), meshes it at each asked node count
(:mod:`idbench_fem.bodies.surface_mesh`), and prints a quality table and the
``[mesh]`` lines to paste into a body TOML. Progress goes to stderr, a line
per mesh.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from idbench import Command, ConfigError


def _sizes(text: str) -> tuple[int, ...]:
    try:
        sizes = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--sizes {text!r}: need comma-separated node counts, e.g. 500,1000,4000"
        ) from None
    if not sizes or any(s < 20 for s in sizes):
        raise argparse.ArgumentTypeError(
            f"--sizes {text!r}: need node counts of at least 20"
        )
    return tuple(sorted(set(sizes)))


def configure(k: argparse.ArgumentParser) -> None:
    """The arguments of ``idbench mesh``."""
    k.description = (
        "Mesh a closed surface (STL, OBJ or PLY) into linear tetrahedra at each "
        "node count (within 10%), print their quality and the [mesh] lines of a "
        "body TOML. The largest is the truth, the others the model meshes."
    )
    k.add_argument("surface", type=Path, help="the surface file (STL, OBJ or PLY)")
    k.add_argument(
        "--sizes", type=_sizes, required=True,
        help="node counts, comma-separated (e.g. 500,1000,2000,8000)",
    )  # fmt: skip
    k.add_argument(
        "--scale", type=float, default=1.0,
        help="metres per unit of the file (0.001 for millimetres; default 1)",
    )  # fmt: skip
    k.add_argument(
        "--out", type=Path, default=Path("meshes"),
        help="folder of the meshes, STEM-nN.msh (default: meshes)",
    )  # fmt: skip
    k.add_argument("-q", "--quiet", action="store_true", help="no progress lines")


def run(args: argparse.Namespace) -> int:
    """``idbench mesh``: check the surface, mesh it, print the table."""
    from idbench_fem.bodies.surface_file import read_surface, surface_problems
    from idbench_fem.bodies.surface_mesh import MeshingError, mesh_surface

    surface = read_surface(args.surface, args.scale)
    problems = surface_problems(surface)
    if problems:
        for line in problems:
            print(f"idbench: error: {line}", file=sys.stderr)
        return 2
    if args.out.exists() and not args.out.is_dir():
        raise ConfigError(f"--out {str(args.out)!r} is a file; need a folder")
    args.out.mkdir(parents=True, exist_ok=True)
    say = (lambda text: None) if args.quiet else _stderr
    say(
        f"surface {str(args.surface)!r}: {len(surface.points)} vertices, "
        f"{len(surface.triangles)} triangles, volume {surface.volume:.4g} m^3 "
        f"(scale {args.scale:g}); closed, manifold, no crossing"
    )
    made = []
    t0 = time.perf_counter()
    for n in args.sizes:
        path = args.out / f"{args.surface.stem}-n{n}.msh"
        try:
            result = mesh_surface(surface, n, path)
        except MeshingError as exc:
            raise ConfigError(str(exc)) from None
        made.append(result)
        say(
            f"[{time.perf_counter() - t0:.0f} s] {path.name}: {result.nodes} nodes "
            f"(asked {n}), {result.tets} tets, h = {result.h * 1000:.3g} mm, "
            f"{result.tries} {'try' if result.tries == 1 else 'tries'}, "
            f"{result.seconds:.1f} s"
        )
    print(quality_table(made, surface.volume))
    print()
    print(mesh_lines(made))
    off = [m for m in made if abs(m.nodes / m.asked - 1) > 0.10]
    for m in off:
        print(
            f"idbench: error: {m.path.name}: {m.nodes} nodes, not within 10% of "
            f"{m.asked} (after {m.tries} tries); ask for another count",
            file=sys.stderr,
        )
    return 2 if off or any(m.inverted for m in made) else 0


def _stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def quality_table(made: list[Any], surface_volume: float) -> str:
    """The meshes' quality, one line each (inverted must be 0)."""
    head = ("mesh", "asked", "nodes", "tets", "inverted", "min quality",
            "volume (m^3)", "volume / surface's")  # fmt: skip
    rows = [
        (str(m.path), str(m.asked), str(m.nodes), str(m.tets), str(m.inverted),
         f"{m.min_quality:.3f}", f"{m.volume:.4g}", f"{m.volume / surface_volume:.4f}")
        for m in made
    ]  # fmt: skip
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]

    def line(cells: tuple[str, ...]) -> str:
        first = cells[0].ljust(widths[0])
        rest = [c.rjust(w) for c, w in zip(cells[1:], widths[1:], strict=True)]
        return "  ".join([first, *rest]).rstrip()

    rule = "  ".join("-" * w for w in widths)
    notes = (
        "quality: the mean ratio, 1 for a regular tetrahedron, 0 for a flat one; "
        "a coarse mesh holds less volume than the surface (its polyhedron cuts "
        "the curves)"
    )
    return "\n".join([line(head), rule, *(line(r) for r in rows), notes])


def mesh_lines(made: list[Any]) -> str:
    """The ``[mesh]`` table of a body TOML: the finest is the truth."""
    truth, *models = sorted(made, key=lambda m: -m.nodes)
    models = sorted(models, key=lambda m: m.nodes)
    listed = ", ".join(f'"{m.path.as_posix()}"' for m in models)
    return "\n".join([
        "# paste into your body TOML (paths relative to its folder; here, for a",
        "# body TOML in the current folder):",
        "[mesh]",
        f'truth = "{truth.path.as_posix()}"',
        f"models = [{listed}]",
    ])  # fmt: skip


MESH = Command(
    help="mesh a surface file (STL, OBJ, PLY) into tetrahedra at node counts",
    configure=configure,
    run=run,
)
