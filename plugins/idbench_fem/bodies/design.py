"""A body's offline design (``[design]``): fine-mesh paths over loads and moduli.

Reduced models of a fine mesh (their snapshots) and the approximation-error
correction (its calibration) need the same thing offline: paths of the fine
model over manipulations and moduli. A body describes them once::

    [design]
    manipulations = ["push-a", "sag"]   # optional: the paths' loads (below, or
                              # the body's own); default: every one below
    moduli = { E = [1000.0, 16000.0] }  # Pa, a range per parameter (E: all)
    steps = 30                # load steps of each fine path
    paths = 1                 # moduli per manipulation (p > 1: their ratios)

    [[design.manipulation]]   # loads of the design only (not scenarios),
    name = "push-a"           # the same tables as [[manipulation]]
    kind = "pressure"
    region = { sphere = { centre = [0.09, 0.0, 0.004], radius = 0.03 } }
    pressure = 400.0

With dead loads and a law linear in its moduli, the state at load fraction t
and moduli theta equals the state at t / c and c theta: a path at theta holds
every c theta with c >= 1 along its ramp. So the paths start at the soft end
of the range: with one parameter, one path per manipulation at the lowest E
covers the whole range (more would repeat it); with several, ``paths``
points of the box (Halton, in log moduli, the soft corner first) give the
ratios between the moduli, each moved along its ray to the soft end. The
fine paths are cached by content like truths (``idbench.fine_path``), so a
calibration of the same paths reuses them. The identified stiffnesses of a
body's springs (``[[support]]``) are parameters like the moduli and take
ranges too; a known spring does not scale with theta, so with known springs
the argument above holds only approximately (the reduction's error
estimate measures what it costs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies.manipulations import Manipulation, parse_manipulation
from idbench_fem.bodies.reader import TableReader

if TYPE_CHECKING:
    from idbench_fem.bodies.description import Body

FloatArray = NDArray[np.float64]

KEYS = ("manipulations", "moduli", "steps", "paths", "manipulation")
"""The keys of ``[design]``."""


@dataclass(frozen=True)
class Design:
    """The parsed ``[design]`` table (see the module).

    Attributes
    ----------
    manipulations
        Names of the paths' loads, in order (own or the body's).
    own
        The design's own manipulations (``[[design.manipulation]]``).
    moduli
        (parameter name, lowest, highest) per parameter, in the models' order:
        the moduli (``E`` in the table: the same range for every modulus),
        then the identified springs' stiffnesses (N/m3).
    steps
        Load steps of each fine path.
    paths
        Moduli per manipulation (used with two or more parameters).

    The fine mesh is the one reduced (or calibrated against): the same
    design serves every fine mesh of the body.
    """

    manipulations: tuple[str, ...]
    own: tuple[Manipulation, ...]
    moduli: tuple[tuple[str, float, float], ...]
    steps: int = 30
    paths: int = 1

    def thetas(self) -> FloatArray:
        """The moduli (P, p) of the paths of each manipulation, soft ends first."""
        lo = np.array([m[1] for m in self.moduli])
        hi = np.array([m[2] for m in self.moduli])
        if len(lo) == 1 or self.paths == 1:
            return lo[None, :]
        from scipy.stats import qmc

        unit = qmc.Halton(d=len(lo), scramble=False).random(self.paths)
        unit[0] = 0.0  # the soft corner
        points = np.exp(np.log(lo) + unit * (np.log(hi) - np.log(lo)))
        # each along its ray to the soft end: the least ratio to lo becomes 1
        points /= np.min(points / lo, axis=1, keepdims=True)
        _, first = np.unique(np.round(np.log(points), 12), axis=0, return_index=True)
        return np.asarray(points[np.sort(first)])

    def body(self, body: Body) -> Body:
        """``body`` with the design's loads as its manipulations (its fine models).

        The body's manipulations the design does not use are left out, so a
        body built in memory per scenario (the beam) keys the same paths.
        """
        used = tuple(m for m in body.manipulations if m.name in self.manipulations)
        return replace(body, manipulations=(*used, *self.own))

    @property
    def n_paths(self) -> int:
        """Fine paths of the design: manipulations times moduli."""
        return len(self.manipulations) * len(self.thetas())

    def describe(self) -> dict[str, Any]:
        """What the design's paths depend on (with the fine models' descriptions)."""
        return {
            "manipulations": list(self.manipulations),
            "thetas": self.thetas().tolist(),
            "steps": self.steps,
        }


def spring_parameters(body: Body, known: bool = False) -> tuple[str, ...]:
    """The identified spring stiffnesses of ``body``, in the models' order.

    They follow the moduli among a model's parameters
    (:func:`idbench_fem.models.supported.springs_of`); a design gives each
    a range as it does each modulus. ``known``: the known ones too (a range
    given for one of them is left unused, so a body's copy with its springs
    known keeps its design).
    """
    return tuple(
        s.parameter(which)
        for s in body.supports
        for which in ("k_n", "k_t")
        if (known or which in s.identify) and s.value(which) != 0.0
    )


def parse_design(
    raw: Any,
    source: str,
    body: Body,
) -> Design:
    """Parse ``[design]`` of ``body``.

    Raises
    ------
    ValueError
        One line naming the bad value and what is allowed.
    """
    c = TableReader(source, "[design]")
    if not isinstance(raw, dict):
        raise c.error(f"= {raw!r}: need a table")
    c.keys(raw, KEYS)
    tables = raw.get("manipulation", [])
    if not isinstance(tables, list):
        raise c.error("manipulation must be a list of tables ([[design.manipulation]])")
    own = tuple(
        parse_manipulation(t, i, f"{source} [design]") for i, t in enumerate(tables)
    )
    body_names = [m.name for m in body.manipulations]
    own_names = [m.name for m in own]
    for m in own:
        if m.name in body_names or own_names.count(m.name) > 1:
            raise c.error(f"manipulation {m.name!r}: the name is taken")
        if m.driven:
            raise c.error(
                f"manipulation {m.name!r}: a design's loads are forces (a "
                "displacement-controlled grasp is not one)"
            )
    names = raw.get("manipulations", own_names)
    if (
        not isinstance(names, list | tuple)
        or not names
        or not all(isinstance(n, str) for n in names)
    ):
        raise c.error(f"manipulations = {names!r}: need a list of manipulation names")
    known = {**{m.name: m for m in body.manipulations}, **{m.name: m for m in own}}
    for n in names:
        if n not in known:
            raise c.error(
                f"manipulations: no manipulation {n!r} (the body's and the "
                f"design's: {', '.join(known)})"
            )
        if known[n].driven:
            raise c.error(f"manipulations: {n!r} is displacement-controlled")
    moduli = raw.get("moduli")
    stiffnesses = spring_parameters(body)
    params = (*body.parameter_names, *stiffnesses)
    if isinstance(moduli, dict):  # a known spring's range serves no path
        springs = spring_parameters(body, known=True)
        moduli = {k: v for k, v in moduli.items() if k in params or k not in springs}
    if isinstance(moduli, dict) and set(moduli) - set(stiffnesses) == {"E"}:
        moduli = {**dict.fromkeys(body.parameter_names, moduli["E"]),
                  **{k: v for k, v in moduli.items() if k != "E"}}  # fmt: skip
    if not isinstance(moduli, dict) or set(moduli) != set(params):
        raise c.error(
            f"moduli = {moduli!r}: need a range [lowest, highest] (Pa; N/m3 for "
            f"a spring's stiffness) for each parameter: {', '.join(params)}"
        )
    ranges = []
    for name in params:
        pair = moduli[name]
        if not isinstance(pair, list) or len(pair) != 2:
            raise c.error(f"moduli.{name} = {pair!r}: need [lowest, highest]")
        lo, hi = (c.number(f"moduli.{name}", v, positive=True) for v in pair)
        if not lo < hi:
            raise c.error(f"moduli.{name} = {pair!r}: need lowest < highest")
        ranges.append((name, lo, hi))
    steps, paths = raw.get("steps", 30), raw.get("paths", 1)
    for key, value, least in (("steps", steps, 2), ("paths", paths, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < least:
            raise c.error(f"{key} = {value!r}: need a whole number >= {least}")
    design = Design(tuple(names), own, tuple(ranges), int(steps), int(paths))
    if design.n_paths > 200 or not math.isfinite(design.n_paths):
        raise c.error(f"has {design.n_paths} fine paths: at most 200")
    return design
