"""A body's modulus field: the ``[field]`` table, and the truth it may carry.

::

    [field]
    cells = 50            # parameter cells (k-means of the truth mesh's volume);
                          # "known": two, the truth's inclusion and the rest
    seed = 0              # of the k-means
    length = 0.02         # m: the prior's correlation length
    # std = 0.5           # the prior's std of ln E (default: the comparison's)

    [[field.inclusion]]   # the truth: E times contrast inside the region
    region = { sphere = { centre = [0.02, 0.003, 0.0], radius = 0.01 } }
    contrast = 3.0

    # [field.random]      # or a smooth random truth drawn from the prior
    # std = 0.3           # of ln E
    # length = 0.02       # m
    # cells = 400         # its cells on the truth mesh (finer than the model's)
    # seed = 1

With ``[field]`` the model's parameters are ``E_cell000``, ``E_cell001``, ...
(one per cell; :mod:`idbench_fem.bodies.partition`) instead of ``E`` or the
``[parameters]`` regions, which it excludes. The truth's moduli are the
body's (``E``, ``E_regions``) times each inclusion's ``contrast`` in the
tetrahedra whose centroid its region selects, times exp of the random draw.
The model options ``field_cells``, ``field_length``, ``field_std`` and
``field_seed`` (``--model-option``) set or override the table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.bodies.reader import TableReader
from idbench_fem.bodies.regions import Region, region_cells

FloatArray = NDArray[np.float64]

KNOWN = "known"
"""``cells = "known"``: the truth's inclusion and the rest, two parameters."""
DEFAULT_LENGTH = 0.02
"""m: the prior's correlation length when none is given (20 mm)."""


@dataclass(frozen=True)
class RandomTruth:
    """A smooth random truth: ln E + a draw of the field prior on finer cells."""

    std: float = 0.3
    length: float = DEFAULT_LENGTH
    cells: int = 400
    seed: int = 1


@dataclass(frozen=True)
class FieldSpec:
    """The ``[field]`` table (see the module docstring)."""

    cells: int | str = 50
    seed: int = 0
    length: float = DEFAULT_LENGTH
    std: float | None = None
    inclusions: tuple[tuple[Region, float], ...] = ()
    random: RandomTruth | None = None

    @property
    def known(self) -> bool:
        """Whether the cells are the truth's inclusion and the rest."""
        return self.cells == KNOWN


def parse_field(raw: Any, source: str) -> FieldSpec | None:
    """The ``[field]`` table parsed (None if absent).

    Raises
    ------
    ValueError
        One line naming the bad value and what is allowed.
    """
    if raw is None:
        return None
    c = TableReader(source, "[field]")
    if not isinstance(raw, dict):
        raise c.error("must be a table")
    c.keys(raw, ("cells", "seed", "length", "std", "inclusion", "random"))
    cells = raw.get("cells", 50)
    if cells != KNOWN and not _whole(cells, 1):
        raise c.error(f"cells = {cells!r}: need a whole number >= 1 or {KNOWN!r}")
    seed = raw.get("seed", 0)
    if not _whole(seed, 0):
        raise c.error(f"seed = {seed!r}: need a whole number >= 0")
    length = c.number("length", raw.get("length", DEFAULT_LENGTH), positive=True)
    std = raw.get("std")
    std = None if std is None else c.number("std", std, positive=True)
    inclusions = []
    listed = raw.get("inclusion", [])
    if not isinstance(listed, list):
        raise c.error("inclusion must be a list of tables ([[field.inclusion]])")
    for i, inc in enumerate(listed):
        r = TableReader(source, f"[[field.inclusion]] {i}")
        if not isinstance(inc, dict):
            raise r.error("must be a table with region and contrast")
        r.keys(inc, ("region", "contrast"))
        if "region" not in inc or "contrast" not in inc:
            raise r.error("needs region and contrast")
        inclusions.append(
            (r.region("region", inc["region"]),
             r.number("contrast", inc["contrast"], positive=True))
        )  # fmt: skip
    random = None
    if "random" in raw:
        r = TableReader(source, "[field.random]")
        rt = raw["random"]
        if not isinstance(rt, dict):
            raise r.error("must be a table")
        r.keys(rt, ("std", "length", "cells", "seed"))
        n, s = rt.get("cells", 400), rt.get("seed", 1)
        if not (_whole(n, 1) and _whole(s, 0)):
            raise r.error(f"cells = {n!r}, seed = {s!r}: need whole numbers")
        random = RandomTruth(
            r.number("std", rt.get("std", 0.3), positive=True),
            r.number("length", rt.get("length", length), positive=True), n, s,
        )  # fmt: skip
    if cells == KNOWN and not inclusions:
        raise c.error('cells = "known" needs a [[field.inclusion]] (the known region)')
    return FieldSpec(cells, seed, length, std, tuple(inclusions), random)


def _whole(x: Any, low: int) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= low


def inclusion_mask(
    spec: FieldSpec, mesh: SolidMesh, source: str, empty_ok: bool = False
) -> NDArray[np.bool_]:
    """Which tetrahedra (T,) lie in one of the truth's inclusions.

    Raises
    ------
    ValueError
        An inclusion that selects no tetrahedron (unless ``empty_ok``: a
        coarse model mesh may have none whose centroid is inside).
    """
    inside = np.zeros(len(mesh.tets), dtype=bool)
    for region, _ in spec.inclusions:
        try:
            cells = region_cells(mesh, region, what=f"{source}: [[field.inclusion]]")
        except ValueError:
            if not empty_ok:
                raise
            continue
        inside[cells] = True
    return inside


def truth_factors(spec: FieldSpec, mesh: SolidMesh, source: str) -> FloatArray:
    """The truth's modulus over the body's, per tetrahedron (T,).

    The product of the inclusions' contrasts (where their regions select a
    tetrahedron) and exp of the random draw (piecewise constant on its own
    cells of ``mesh``).
    """
    factor = np.ones(len(mesh.tets))
    for region, contrast in spec.inclusions:
        cells = region_cells(mesh, region, what=f"{source}: [[field.inclusion]]")
        factor[cells] *= contrast
    if spec.random is not None:
        factor *= np.exp(random_draw(spec.random, mesh))
    return factor


def random_draw(random: RandomTruth, mesh: SolidMesh) -> FloatArray:
    """A draw (T,) of the field prior N(0, Sigma) on the random truth's own cells."""
    from idbench import FieldPrior, ParameterField
    from idbench_fem.bodies.partition import assign, cell_geometry, kmeans_centres

    centres = kmeans_centres(mesh, random.cells, random.seed)
    cell = assign(mesh, centres)
    g = cell_geometry(mesh, cell, len(centres))
    field = ParameterField(g.centroids, g.volumes, g.edges, g.areas, random.length)
    prior = FieldPrior.of(field, np.zeros(field.p), random.std)
    rng = np.random.default_rng(random.seed)
    return np.asarray(prior.sample(rng, 1)[0][cell])
