r"""Elastic supports of a body: surface regions held by springs (``[[support]]``).

A support is a Robin condition on a surface region :math:`\Gamma_s`: the
region is held by springs of normal and tangential stiffness per unit area
(N/m3), the traction on it

.. math::

    \mathbf{t} = -\left(k_n\, \mathbf{n}\mathbf{n}^T
                 + k_t\, (\mathbf{I} - \mathbf{n}\mathbf{n}^T)\right) \mathbf{u},

with :math:`\mathbf{n}` the reference outward normal (the springs keep
their directions, like the dead loads). It replaces a clamp where what
holds the organ is soft and unknown (ligaments, the organs it lies on)::

    [[support]]
    name = "ligament"          # parameter names k_n_ligament, k_t_ligament
    region = "ligament"        # a surface region: a name or a selector
    k_n = 2.0e4                # N/m3, normal stiffness per unit area (the truth's)
    k_t = 5.0e3                # N/m3, tangential (default 0)
    identify = ["k_n"]         # stiffnesses that are parameters (default: none)
    prior = { k_n = [1.0e4, 1.0e4] }   # mean, std of each identified one
    bounds = { k_n = [20.0, 2.0e7] }   # default 1e-3 .. 1e3 times the value

A body with supports may leave out ``[fixed]``; then its springs must hold
it against every rigid motion, which is checked on each mesh (normal springs
alone on one flat region let it slide: give ``k_t > 0``). Both
stiffnesses enter the internal force linearly, so an identified one has the
one-solve sensitivity of a modulus (:mod:`idbench_fem.fem.springs`). The
``name`` defaults to the region's name; without one (a selector) it is
required. Parsing only: the mesh-dependent checks (an empty region) happen
when the springs are assembled on a mesh.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from idbench_fem.bodies.reader import TableReader
from idbench_fem.bodies.regions import Region

STIFFNESSES = ("k_n", "k_t")
"""The stiffnesses of a support: normal and tangential, per unit area (N/m3)."""

BOUNDS = (1e-3, 1e3)
"""Default bounds of an identified stiffness, as multiples of its value."""


@dataclass(frozen=True)
class Support:
    """One ``[[support]]`` table: a surface region on springs.

    Attributes
    ----------
    name
        Names its parameters (``k_n_<name>``, ``k_t_<name>``).
    region
        The surface region held.
    k_n, k_t
        Normal and tangential stiffness per unit area (N/m3): the truth's,
        and the model's where not identified.
    identify
        Which of ``k_n``, ``k_t`` are parameters.
    prior
        ((stiffness, mean, std), ...) of the identified ones (N/m3).
    bounds
        ((stiffness, lower, upper), ...) of the identified ones (N/m3).
    """

    name: str
    region: Region
    k_n: float
    k_t: float = 0.0
    identify: tuple[str, ...] = ()
    prior: tuple[tuple[str, float, float], ...] = ()
    bounds: tuple[tuple[str, float, float], ...] = ()

    def value(self, which: str) -> float:
        """The stiffness ``which`` (``k_n`` or ``k_t``), N/m3."""
        return float(self.k_n if which == "k_n" else self.k_t)

    def parameter(self, which: str) -> str:
        """The parameter name of stiffness ``which``: ``k_n_<name>``."""
        return f"{which}_{self.name}"

    def bound(self, which: str) -> tuple[float, float]:
        """Bounds of stiffness ``which``: given, else 1e-3 .. 1e3 times it."""
        for key, lo, hi in self.bounds:
            if key == which:
                return lo, hi
        v = self.value(which)
        return BOUNDS[0] * v, BOUNDS[1] * v


def parse_supports(raw: Any, source: str) -> tuple[Support, ...]:
    """The ``[[support]]`` tables of a body (see the module docstring).

    Raises
    ------
    ValueError
        One line naming the file, the table and the bad value.
    """
    if not isinstance(raw, list):
        raise ValueError(f"{source}: [[support]] must be a list of tables")
    out = tuple(_support(t, i, source) for i, t in enumerate(raw))
    names = [s.name for s in out]
    for n in names:
        if names.count(n) > 1:
            raise ValueError(f"{source}: two [[support]] tables are called {n!r}")
    return out


def _support(raw: Any, i: int, source: str) -> Support:
    c = TableReader(source, f"[[support]] {i}")
    if not isinstance(raw, dict):
        raise c.error("must be a table with region and k_n")
    c.keys(raw, ("name", "region", "k_n", "k_t", "identify", "prior", "bounds"))
    if "region" not in raw or "k_n" not in raw:
        raise c.error("needs region (a surface region) and k_n (N/m3)")
    region = c.region("region", raw["region"])
    name = raw.get("name", region.name)
    if not isinstance(name, str) or not name.isidentifier():
        raise c.error(
            f"name = {name!r}: need a name (letters, digits, _); a selector "
            "region needs one"
        )
    c = TableReader(source, f"[[support]] {name!r}")
    k_n = c.number("k_n", raw["k_n"], positive=True)
    k_t = c.number("k_t", raw.get("k_t", 0.0))
    if k_t < 0:
        raise c.error(f"k_t = {k_t:g}: need >= 0 (N/m3)")
    identify = raw.get("identify", [])
    if not isinstance(identify, list) or any(k not in STIFFNESSES for k in identify):
        raise c.error(f"identify = {identify!r}: need a list of k_n, k_t")
    if len(set(identify)) != len(identify):
        raise c.error(f"identify = {identify!r}: names a stiffness twice")
    if "k_t" in identify and k_t == 0:
        raise c.error("identifies k_t but k_t = 0: give the truth's k_t > 0")
    prior = _pairs(c, "prior", raw.get("prior", {}), identify)
    for key, mean, std in prior:
        if not std > 0:
            raise c.error(f"prior.{key} = [{mean:g}, {std:g}]: need STD > 0")
    missing = [k for k in identify if k not in {p[0] for p in prior}]
    if missing:
        raise c.error(
            f"identifies {missing[0]} but has no prior.{missing[0]} = [MEAN, STD] "
            "(N/m3): a stiffness has no prior in common with a modulus"
        )
    bounds = _pairs(c, "bounds", raw.get("bounds", {}), identify)
    for key, lo, hi in bounds:
        if not 0 < lo < hi:
            raise c.error(f"bounds.{key} = [{lo:g}, {hi:g}]: need 0 < lower < upper")
    s = Support(name, region, k_n, k_t, tuple(identify), prior, bounds)
    for key, mean, _ in prior:
        lo, hi = s.bound(key)
        if not lo < mean < hi:
            raise c.error(
                f"prior.{key} mean {mean:g} lies outside its bounds [{lo:g}, {hi:g}]"
            )
    return s


def _pairs(
    c: TableReader, key: str, value: Any, identify: list[str]
) -> tuple[tuple[str, float, float], ...]:
    """A table ``{ k_n = [a, b], ... }`` of the identified stiffnesses."""
    if not isinstance(value, dict):
        raise c.error(f"{key} = {value!r}: need a table {{ k_n = [a, b], ... }}")
    out = []
    for which, pair in value.items():
        if which not in identify:
            raise c.error(
                f"{key}.{which}: only an identified stiffness has one (identify = "
                f"{identify!r})"
            )
        if not isinstance(pair, list) or len(pair) != 2:
            raise c.error(f"{key}.{which} = {pair!r}: need two numbers [a, b]")
        a, b = (c.number(f"{key}.{which}", v) for v in pair)
        out.append((which, a, b))
    return tuple(out)
