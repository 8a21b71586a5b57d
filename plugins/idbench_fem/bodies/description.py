"""The body description of a general solid (TOML), parsed into frozen dataclasses.

A body names, by mesh regions or geometric selectors, what is fixed, how it is
manipulated, what is observed and what is identified::

    [mesh]
    truth = "meshes/liver-n16000.msh"       # paths relative to this file
    models = ["meshes/liver-n200.msh", "meshes/liver-n1000.msh"]
    generate = { geometry = "liver", sizes = [200, 1000, 16000] }  # if missing

    [material]
    law = "neo-hookean"    # or "svk"
    E = 4000.0             # Pa
    nu = 0.47
    density = 1060.0       # kg/m3
    # E_regions = { inclusion = 20000.0 }  # optional: E of named volume regions

    [fixed]                # exactly one of: name, box, sphere, half_space, patch
    name = "ligament"

    [[manipulation]]
    name = "grasp-lift"
    kind = "grasp"         # total force over a surface patch around a point
    point = [0.04, 0.045, -0.03]
    radius = 0.01
    force = [0.0, 0.0, 0.5]            # N at the end of the ramp
    transfer = "lateral-push"          # optional: the transfer target scenario
    # conserve = "resultant"           # optional: every mesh gets the truth's force

    [[manipulation]]
    name = "grasp-pull"
    kind = "grasp"         # displacement-controlled: the patch moves by
    point = [0.04, 0.045, -0.03]       # displacement (all its nodes, all
    radius = 0.01                      # components), the tool's force is
    displacement = [0.0, 0.004, 0.0]   # measured (m at the end of the ramp)

    [[manipulation]]
    name = "lateral-push"
    kind = "traction"      # or "pressure" (dead, Pa, positive into the body)
    region = "anterior"    # a name or a selector table
    traction = [-50.0, 0.0, 0.0]       # Pa

    [[manipulation]]
    name = "sag-90"
    kind = "gravity"
    acceleration = [0.0, -9.81, 0.0]   # m/s2

    [markers]              # points = [[x, y, z], ...] (snapped to the surface)
    region = "anterior"    # or all surface nodes of a region
    snap_distance = 0.005  # m, how far a marker may be from the surface
    # placement = "volume" # points used as given, located in each mesh's tets

    [shape_error]
    grid = [10, 7, 6]      # regular grid clipped to the body, or nodes = true
    margin = 0.003         # m, keep grid points this far inside the surface
    # locate = "contained" # every point must lie in each model mesh

    [parameters]           # absent: one E; else one E per region
    regions = ["parenchyma", "inclusion"]
    # bounds = [1.0, 1e8]  # Pa, of every parameter (default 1e-3 E .. 1e3 E)

    [[probe]]              # optional: traces get tip_x, tip_y, tip_z
    name = "tip"           # (no probe: u_max, the largest displacement)
    point = [0.2, 0.015, 0.015]

    [targets]              # optional: hidden points, never observed, scored (TRE)
    tumour = [0.02, 0.003, 0.0]                     # one point (m)
    vessel = [[0.01, 0.0, 0.0], [0.03, 0.0, 0.0]]   # or several

Selectors (wherever a region is expected): ``"name"`` or ``{ name = ... }``,
``{ box = { lower = [...], upper = [...] } }``,
``{ sphere = { centre = [...], radius = r } }``,
``{ half_space = { point = [...], normal = [...] } }`` (the side the normal
points to), ``{ patch = { point = [...], radius = r } }`` (the surface around
the surface point nearest to ``point``), ``{ slab = { index = i, count = n } }``
(slab i of n equal slabs along x of the mesh's bounding box).

``conserve = "resultant"`` on a manipulation scales each mesh's nodal loads
so that their resultant equals the reference (truth) mesh's (for gravity:
its mass); absent or ``"none"``, each mesh carries what its selector
captures there (:mod:`idbench_fem.bodies.figures`). A displacement-controlled
grasp has no load to conserve (refused).

A grasp has either ``force`` (force-controlled: a dead load) or
``displacement`` (displacement-controlled: the patch's nodes move by it,
ramped like a load, and the tool's force is what the model's ``reaction``
gives). With displacements imposed and only displacements observed, the
solution of a body with one homogeneous E does not depend on E at all
(f_int = E g(u) = 0 away from the tool), so E is identifiable only if the
tool's force is observed: the model declares it (``needs_observed =
("reaction",)``) and a comparison whose observation has no ``force`` block is
refused before it runs. A ``kind = "displacement"`` is refused, pointing to
the grasp's ``displacement``.

Errors are one-line ``ValueError``s naming the file, the bad value and what is
allowed. Mesh-dependent checks (names, empty regions, markers off the body)
happen when a region is resolved on a mesh (:mod:`idbench_fem.bodies.resolve`;
:func:`~idbench_fem.bodies.resolve.check` does all of them).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies.field import FieldSpec, parse_field
from idbench_fem.bodies.manipulations import Manipulation, parse_manipulation
from idbench_fem.bodies.reader import TableReader, table
from idbench_fem.bodies.reference import ImagedShape, parse_reference
from idbench_fem.bodies.regions import SELECTORS, Region
from idbench_fem.bodies.resolve import SNAP_DISTANCE
from idbench_fem.bodies.supports import Support, parse_supports
from idbench_fem.fem.materials import LAWS, lame, make_material

if TYPE_CHECKING:
    from idbench_fem.bodies.design import Design

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Vec = tuple[float, float, float]

@dataclass(frozen=True)
class Material:
    """Law name, Young's modulus (Pa), Poisson's ratio and density (kg/m3).

    ``E_regions`` = ((volume region, E), ...) overrides E in those regions (the
    truth's stiff inclusion, say); see :func:`element_moduli`.
    """

    law: str = "svk"
    E: float = 5000.0
    nu: float = 0.45
    density: float = 1000.0
    E_regions: tuple[tuple[str, float], ...] = ()

    def make(self, E: float | None = None):  # type: ignore[no-untyped-def]
        """The law object of :mod:`idbench_fem.fem.materials` (at ``E`` if given)."""
        return make_material(self.law, self.E if E is None else E, self.nu)


PLACEMENTS = ("surface", "volume")
"""How markers given by coordinates are read: snapped to the surface, or as is."""

LOCATES = ("nearest", "contained")
"""How shape-error points are located in a model mesh."""


@dataclass(frozen=True)
class Markers:
    """Observed points: coordinates snapped to the surface, or a region's nodes.

    ``placement = "surface"``: the points are snapped to the reference mesh's
    surface and projected onto each model mesh's; ``"volume"``: they are
    used as given and interpolated in the tet of each model mesh that
    contains them (points on the boundary of a box, say).
    """

    points: tuple[Vec, ...] = ()
    region: Region | None = None
    snap_distance: float = SNAP_DISTANCE
    placement: str = "surface"


@dataclass(frozen=True)
class ShapeError:
    """Shape-error points: a grid clipped to the body, or the truth mesh's nodes."""

    grid: tuple[int, int, int] = (10, 8, 6)
    nodes: bool = False
    margin: float = 0.0
    locate: str = "nearest"
    """``"nearest"``: a point a coarse mesh misses takes the clipped weights of
    its nearest tet; ``"contained"``: every point must lie in each model mesh."""


@dataclass(frozen=True)
class MeshFiles:
    """Truth and model meshes, and how to generate them if missing."""

    truth: Path
    models: tuple[Path, ...] = ()
    geometry: str | None = None
    sizes: tuple[float, ...] = ()


@dataclass(frozen=True)
class Body:
    """A parsed body description (see the module docstring)."""

    source: str
    mesh: MeshFiles
    material: Material
    fixed: Region | None
    """None: the body is held by its ``supports`` only."""
    manipulations: tuple[Manipulation, ...]
    markers: Markers
    shape_error: ShapeError
    parameter_regions: tuple[Region, ...] = ()
    parameter_bounds: tuple[float, float] | None = None
    """Bounds (Pa) of every parameter; None: 1e-3 E to 1e3 E."""
    probes: tuple[tuple[str, Vec], ...] = ()
    """Named points whose displacements are the traces' probes (``NAME_x``
    ...); none: the largest nodal displacement ``u_max``."""
    targets: tuple[tuple[str, Vec], ...] = ()
    """Hidden target points (name, point); ``name[i]`` for a list's i-th."""
    supports: tuple[Support, ...] = field(default=(), repr=False)
    """Surface regions on springs (:mod:`idbench_fem.bodies.supports`); not in
    the repr, which keys the truths of bodies built in memory."""
    reference: ImagedShape | None = field(default=None, repr=False)
    """The meshes are the shape imaged under a manipulation (``[reference]``)."""
    modulus_field: FieldSpec | None = field(default=None, repr=False)
    """``[field]``: E per cell of a partition (:mod:`idbench_fem.bodies.field`)."""
    design: Design | None = field(default=None, repr=False)
    """The offline design (``[design]``, :mod:`idbench_fem.bodies.design`), or
    None. (Not in the repr, which keys the truths of bodies built in memory.)"""

    def manipulation(self, name: str) -> Manipulation:
        """The manipulation called ``name``."""
        for m in self.manipulations:
            if m.name == name:
                return m
        names = ", ".join(m.name for m in self.manipulations)
        raise ValueError(f"{self.source}: no manipulation {name!r}; it has {names}")

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """``("E",)``, or ``E_<region>`` per parameter region."""
        if not self.parameter_regions:
            return ("E",)
        return tuple(
            f"E_{r.name}" if r.name is not None else f"E_region{i}"
            for i, r in enumerate(self.parameter_regions)
        )

    @property
    def parameter_values(self) -> tuple[float, ...]:
        """The true value (Pa) of each parameter: its region's ``E_regions``, else E."""
        if not self.parameter_regions:
            return (self.material.E,)
        given = dict(self.material.E_regions)
        return tuple(
            given.get(r.name or "", self.material.E) for r in self.parameter_regions
        )


# -- parsing ---------------------------------------------------------------------


def parse_body(
    raw: dict[str, Any], source: str = "<body>", base: Path | None = None
) -> Body:
    """Parse a body description (the TOML as a dict); see the module docstring.

    Parameters
    ----------
    raw
        The parsed TOML.
    source
        Name for messages (the file).
    base
        Directory that relative mesh paths are relative to.

    Raises
    ------
    ValueError
        One line naming the bad value and what is allowed.
    """
    base = Path(".") if base is None else Path(base)
    top = (
        "mesh",
        "material",
        "fixed",
        "manipulation",
        "markers",
        "shape_error",
        "parameters",
        "probe",
        "targets",
        "support",
        "reference",
        "field",
        "design",
    )
    TableReader(source, "body").keys(raw, top)

    mt = table(raw, "mesh", source)
    c = TableReader(source, "[mesh]")
    c.keys(mt, ("truth", "models", "generate"))
    if not isinstance(mt.get("truth"), str):
        raise c.error(f"truth = {mt.get('truth')!r}: need the truth mesh file's path")
    models = mt.get("models", [])
    if not isinstance(models, list) or not all(isinstance(m, str) for m in models):
        raise c.error(f"models = {models!r}: need a list of mesh file paths")
    gen = mt.get("generate", {})
    if not isinstance(gen, dict) or (gen and set(gen) != {"geometry", "sizes"}):
        raise c.error(f"generate = {gen!r}: need {{ geometry = ..., sizes = [...] }}")
    meshes = MeshFiles(
        base / mt["truth"],
        tuple(base / m for m in models),
        gen.get("geometry"),
        tuple(gen.get("sizes", ())),
    )

    mat = table(raw, "material", source)
    c = TableReader(source, "[material]")
    c.keys(mat, ("law", "E", "nu", "density", "E_regions"))
    law = mat.get("law", "svk")
    if law not in LAWS:
        raise c.error(f"law = {law!r}: allowed are {', '.join(LAWS)}")
    E = c.number("E", mat.get("E", 5000.0), positive=True)
    nu = c.number("nu", mat.get("nu", 0.45))
    try:
        lame(E, nu)
    except ValueError as exc:
        raise c.error(str(exc)) from None
    density = c.number("density", mat.get("density", 1000.0))
    if density < 0:
        raise c.error(f"density = {density:g}: a mass density must be >= 0 (kg/m3)")
    er = mat.get("E_regions", {})
    if not isinstance(er, dict):
        raise c.error(f"E_regions = {er!r}: need a table {{ region = E, ... }}")
    E_regions = tuple(
        (k, c.number(f"E_regions.{k}", v, positive=True)) for k, v in er.items()
    )
    material = Material(law, E, nu, density, E_regions)

    supports = parse_supports(raw.get("support", []), source)
    if "fixed" not in raw and not supports:
        raise ValueError(
            f"{source}: no [fixed] region: the body could move rigidly; name a "
            f"region or give one of {', '.join(SELECTORS[1:])} (or a [[support]])"
        )
    fx = table(raw, "fixed", source)
    fixed = None
    if "fixed" in raw:
        fixed = TableReader(source, "[fixed]").region("fixed", fx)

    manip = raw.get("manipulation", [])
    if not isinstance(manip, list) or not manip:
        raise ValueError(f"{source}: no [[manipulation]]: give at least one load path")
    manipulations = tuple(parse_manipulation(m, i, source) for i, m in enumerate(manip))
    names = [m.name for m in manipulations]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ValueError(f"{source}: two manipulations are called {dup!r}")
    for m in manipulations:
        if m.transfer and (m.transfer not in names or m.transfer == m.name):
            raise ValueError(
                f"{source}: [[manipulation]] {m.name!r} transfer = {m.transfer!r}: "
                f"need another manipulation of this body ({', '.join(names)})"
            )
    if density == 0 and any(m.kind == "gravity" for m in manipulations):
        raise ValueError(
            f"{source}: [material] density = 0 but a manipulation is gravity"
        )

    mk = table(raw, "markers", source)
    c = TableReader(source, "[markers]")
    c.keys(mk, ("points", "region", "snap_distance", "placement"))
    if ("points" in mk) == ("region" in mk):
        raise c.error("needs exactly one of points = [[x, y, z], ...] or region = ...")
    pts = mk.get("points", [])
    if not isinstance(pts, list):
        raise c.error(f"points = {pts!r}: need a list of [x, y, z]")
    markers = Markers(
        tuple(c.vector(f"points[{i}]", p) for i, p in enumerate(pts)),
        c.region("region", mk["region"]) if "region" in mk else None,
        c.number(
            "snap_distance", mk.get("snap_distance", SNAP_DISTANCE), positive=True
        ),
        c.choice("placement", mk.get("placement", "surface"), PLACEMENTS),
    )
    if "points" in mk and not markers.points:
        raise c.error("points = []: need at least one marker")

    se = table(raw, "shape_error", source)
    c = TableReader(source, "[shape_error]")
    c.keys(se, ("grid", "nodes", "margin", "locate"))
    grid = se.get("grid", [10, 8, 6])
    if (
        not isinstance(grid, list)
        or len(grid) != 3
        or not all(
            isinstance(g, int) and not isinstance(g, bool) and g >= 1 for g in grid
        )
    ):
        raise c.error(f"grid = {grid!r}: need three point counts >= 1")
    nodes = se.get("nodes", False)
    if not isinstance(nodes, bool):
        raise c.error(f"nodes = {nodes!r}: need true or false")
    margin = c.number("margin", se.get("margin", 0.0))
    if margin < 0:
        raise c.error(f"margin = {margin:g}: need >= 0 (m)")
    shape_error = ShapeError(
        (grid[0], grid[1], grid[2]), nodes, margin,
        c.choice("locate", se.get("locate", "nearest"), LOCATES),
    )  # fmt: skip

    pa = table(raw, "parameters", source)
    c = TableReader(source, "[parameters]")
    c.keys(pa, ("regions", "bounds"))
    regions = pa.get("regions", [])
    if not isinstance(regions, list) or len(regions) == 1:
        raise c.error(
            f"regions = {regions!r}: need a list of two or more regions (omit it "
            "for one E)"
        )
    parameter_regions = tuple(
        c.region(f"regions[{i}]", r) for i, r in enumerate(regions)
    )
    bounds = pa.get("bounds")
    if bounds is not None:
        if not isinstance(bounds, list) or len(bounds) != 2:
            raise c.error(f"bounds = {bounds!r}: need [lower, upper] in Pa")
        lo, hi = (c.number("bounds", b, positive=True) for b in bounds)
        if not lo < hi:
            raise c.error(f"bounds = {bounds!r}: need lower < upper")
        bounds = (lo, hi)
    modulus_field = parse_field(raw.get("field"), source)
    if modulus_field is not None and parameter_regions:
        raise c.error("regions and a [field] exclude each other: give one of them")
    body = Body(
        source,
        meshes,
        material,
        fixed,
        manipulations,
        markers,
        shape_error,
        parameter_regions,
        bounds,
        _probes(raw.get("probe", []), source),
        _targets(table(raw, "targets", source), source),
        supports,
        parse_reference(raw.get("reference"), source, tuple(names)),
        modulus_field,
    )
    if "design" not in raw:
        return body
    from idbench_fem.bodies.design import parse_design

    design = parse_design(raw["design"], source, body)
    return replace(body, design=design)


def _targets(raw: dict[str, Any], source: str) -> tuple[tuple[str, Vec], ...]:
    """``[targets]``: name = [x, y, z], or name = [[x, y, z], ...]."""
    c = TableReader(source, "[targets]")
    out: list[tuple[str, Vec]] = []
    for name, value in raw.items():
        many = isinstance(value, list) and bool(value) and isinstance(value[0], list)
        if not many:
            out.append((name, c.vector(name, value)))
            continue
        for i, v in enumerate(value):
            out.append((f"{name}[{i}]", c.vector(f"{name}[{i}]", v)))
    return tuple(out)


def _probes(raw: Any, source: str) -> tuple[tuple[str, Vec], ...]:
    """``[[probe]]`` tables: ``name`` and ``point`` (a point in the body)."""
    if not isinstance(raw, list):
        raise ValueError(f"{source}: [[probe]] must be a list of tables")
    out = []
    for i, p in enumerate(raw):
        c = TableReader(source, f"[[probe]] {i}")
        if not isinstance(p, dict):
            raise c.error("must be a table with name and point")
        c.keys(p, ("name", "point"))
        name = p.get("name")
        if not isinstance(name, str) or not name.isidentifier():
            raise c.error(f"name = {name!r}: need a name (letters, digits, _)")
        out.append((name, c.vector("point", p.get("point"))))
    return tuple(out)


def load_body(path: str | Path) -> Body:
    """Read and parse a body TOML file (mesh paths relative to its folder)."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"body file {str(path)!r}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"body file {str(path)!r} is not valid TOML: {exc}") from None
    return parse_body(raw, str(path), path.parent)
