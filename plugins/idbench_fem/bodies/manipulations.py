"""A body's manipulations: the load paths of its ``[[manipulation]]`` tables.

Each is a dead load ramped linearly over a scenario's K steps (a traction, a
pressure, gravity or a grasp's force) or a grasp that prescribes its patch's
displacement; :func:`parse_manipulation` reads one table, checked, and
:mod:`idbench_fem.bodies.loads` turns it into nodal forces on a mesh.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from idbench_fem.bodies.figures import CONSERVE
from idbench_fem.bodies.reader import TableReader
from idbench_fem.bodies.regions import Region

Vec = tuple[float, float, float]

KINDS = ("traction", "pressure", "gravity", "grasp")
"""Manipulation kinds."""

_REFUSED = ("displacement", "prescribed-displacement", "prescribed_displacement")



@dataclass(frozen=True)
class Manipulation:
    """One load path, ramped linearly over the K steps of a scenario.

    Attributes
    ----------
    name
        Scenario name.
    kind
        ``traction``, ``pressure``, ``gravity`` or ``grasp``.
    region
        Loaded surface (traction, pressure) or the grasp patch.
    vector
        Traction (Pa), gravity acceleration (m/s2) or grasp force (N) at t = 1
        (None for a displacement-controlled grasp).
    pressure
        Dead pressure (Pa) at t = 1, positive into the body.
    transfer
        The manipulation its identified values are tested on (the transfer
        error); empty: the next one of the body.
    displacement
        A displacement-controlled grasp's displacement (m) at t = 1: every
        node of the patch moves by it (None: force-controlled).
    """

    name: str
    kind: str
    region: Region | None = None
    vector: Vec | None = None
    pressure: float | None = None
    transfer: str = ""
    displacement: Vec | None = field(default=None, repr=False)
    """(Not in the repr, which keys the truths of bodies built in memory: a
    force-controlled manipulation's is as before the field existed.)"""
    conserve: str = field(default="none", repr=False)
    """``"resultant"``: each mesh's nodal loads are scaled to the reference
    mesh's resultant (:mod:`idbench_fem.bodies.figures`); ``"none"``: each
    mesh carries what its selector captures. (Not in the repr either.)"""

    @property
    def driven(self) -> bool:
        """Whether it prescribes a displacement (the tool moves; its force is read)."""
        return self.displacement is not None



def parse_manipulation(raw: Any, i: int, source: str) -> Manipulation:
    """The ``[[manipulation]]`` table number ``i`` (from 1) of ``source``.

    Raises
    ------
    ValueError
        One line naming the file, the table, the bad value and what is allowed.
    """
    if not isinstance(raw, dict):
        raise ValueError(f"{source}: [[manipulation]] {i} must be a table")
    name = raw.get("name")
    c = TableReader(
        source, f"[[manipulation]] {name!r}" if name else f"[[manipulation]] {i}"
    )
    if not isinstance(name, str) or not name:
        raise c.error(f"name = {name!r}: every manipulation needs a name")
    kind = raw.get("kind")
    if kind in _REFUSED:
        raise c.error(
            f"kind = {kind!r}: not a kind; a displacement-controlled manipulation is "
            "a grasp with displacement = [dx, dy, dz] instead of force (observe its "
            "force: from displacements alone, a homogeneous E cannot be identified)"
        )
    if kind not in KINDS:
        raise c.error(f"kind = {kind!r}: allowed are {', '.join(KINDS)}")
    needs = {
        "traction": ("region", "traction"),
        "pressure": ("region", "pressure"),
        "gravity": ("acceleration",),
        "grasp": ("point", "radius", "force"),
    }[kind]
    if kind == "grasp" and "displacement" in raw:
        if "force" in raw:
            raise c.error(
                "has force and displacement: a grasp is force-controlled (force) "
                "or displacement-controlled (displacement), not both"
            )
        needs = ("point", "radius", "displacement")
    c.keys(raw, ("name", "kind", "transfer", "conserve", *needs))
    transfer = raw.get("transfer", "")
    if not isinstance(transfer, str):
        raise c.error(f"transfer = {transfer!r}: need a manipulation name")
    conserve = c.choice("conserve", raw.get("conserve", "none"), CONSERVE)
    if conserve != "none" and "displacement" in raw:
        raise c.error(
            f"conserve = {conserve!r}: a displacement-controlled grasp puts no "
            "load on the body (the tool's force is measured); remove conserve"
        )
    for key in needs:
        if key not in raw:
            also = "; or displacement instead of force" if kind == "grasp" else ""
            raise c.error(f"needs {key} (a {kind} has {', '.join(needs)}{also})")
    if kind == "traction":
        return Manipulation(
            name,
            kind,
            c.region("region", raw["region"]),
            c.vector("traction", raw["traction"]),
            transfer=transfer,
            conserve=conserve,
        )
    if kind == "pressure":
        return Manipulation(
            name,
            kind,
            c.region("region", raw["region"]),
            pressure=c.number("pressure", raw["pressure"]),
            transfer=transfer,
            conserve=conserve,
        )
    if kind == "gravity":
        return Manipulation(
            name,
            kind,
            vector=c.vector("acceleration", raw["acceleration"]),
            transfer=transfer,
            conserve=conserve,
        )
    patch = (c.vector("point", raw["point"]), c.number("radius", raw["radius"], True))
    if "displacement" in raw:
        return Manipulation(
            name,
            kind,
            Region(patch=patch),
            transfer=transfer,
            conserve=conserve,
            displacement=c.vector("displacement", raw["displacement"]),
        )
    return Manipulation(
        name,
        kind,
        Region(patch=patch),
        c.vector("force", raw["force"]),
        transfer=transfer,
        conserve=conserve,
    )
