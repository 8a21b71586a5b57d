"""The ``solid`` model's settings, and the scenarios its bodies define.

Every ``[[manipulation]]`` of a body is a scenario whose load names it:
``{"body": "liver", "manipulation": "grasp-lift"}`` (``body`` omitted: the
model's ``body`` setting). The plugin registers the shipped examples'
manipulations and those of the body files listed in ``$IDBENCH_BODIES``
(separated by the OS path separator, ``:`` on Linux). A body given as the
``body`` setting needs neither: its settings propose its manipulations as
scenarios and its meshes as the comparison's defaults
(:meth:`SolidSettings.proposed_scenarios`,
:meth:`SolidSettings.proposed_defaults`).
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from typing import Any, ClassVar

from idbench import ModelDefaults, Scenario
from idbench_fem.bodies.description import Body
from idbench_fem.fem.materials import LAWS
from idbench_fem.fem.solver import BACKENDS

log = logging.getLogger(__name__)

BODIES_ENV = "IDBENCH_BODIES"
KERNELS = ("auto", "general")
DEFAULT_BODY = "liver"
"""The default ``body``: the registered defaults (``SOLID_DEFAULTS``) are its."""


@dataclass(frozen=True)
class SolidSettings:
    """Settings of the ``solid`` model (``--model-option NAME=VALUE``).

    Attributes
    ----------
    body
        The body description: a TOML path or a shipped example (``liver``,
        ``kidney``). Its manipulations are scenarios and, when the comparison
        names none, its first manipulation, model meshes and truth are the
        comparison's; a scenario of another body is refused.
    law
        Material law override (``svk`` or ``neo-hookean``; None: the body's).
    nu
        Poisson's ratio override (None: the body's).
    reference
        Mesh spec on which markers are snapped and shape-error points are
        placed, shared by every mesh of a comparison (None: the body's truth).
        Give the comparison's truth mesh when it is not the body's.
    rtol
        Newton tolerance, relative to the step's external force (None: 1e-8,
        as the beam's).
    atol
        Newton's absolute floor, relative to the end force (None: 1e-12).
    max_iterations
        Newton iteration limit (None: 25).
    solver
        ``"pardiso"`` or ``"scipy"`` (None: ``$IDBENCH_SOLVER`` or the best).
    kernel
        ``"auto"`` (SVK through the beam's assembler, other laws through the
        general one) or ``"general"`` (always the general-law assembler).
    load_scale
        Multiplies every manipulation's end load (e.g. to keep SVK in the
        range it can follow).
    processes
        Processes that solve a batched step's sigma points (None: 1; see the
        beam's setting of that name). Not part of the run's identity.
    chord_ratio
        A Newton update that cut the residual at least this much keeps its
        factorization (a chord step), in [0, 1) (None: 1e-2; 0: plain Newton).
    sensitivity_refine
        Refine sensitivities with one step of iterative refinement (None: on).
    field_cells, field_length, field_std, field_seed
        A modulus field (:mod:`idbench_fem.bodies.field`): E per cell of
        ``field_cells`` k-means cells (or ``"known"``), the prior's
        correlation length (m) and std of ln E, the k-means seed; each
        overrides the body's ``[field]`` (None: the body's; no field if it
        has none and ``field_cells`` is None).
    path_reuse
        A step that continues the previous one starts from the path's
        extrapolation and keeps its factorization (chords, refactoring by the
        rule of :mod:`idbench_fem.fem.path_steps`), and ``step_many``
        accelerates its sigma points' chords
        (:func:`~idbench_fem.fem.chords.accelerated_chords`); results equal
        plain Newton to the tolerance (None: on; False: plain Newton from the
        given state and plain chords, as the study's beam).
    """

    body: str = DEFAULT_BODY
    law: str | None = None
    nu: float | None = None
    reference: str | None = None
    rtol: float | None = None
    atol: float | None = None
    max_iterations: int | None = None
    solver: str | None = None
    kernel: str = "auto"
    load_scale: float = 1.0
    processes: int | None = None
    chord_ratio: float | None = None
    sensitivity_refine: bool | None = None
    path_reuse: bool | None = None
    field_cells: int | str | None = None
    field_length: float | None = None
    field_std: float | None = None
    field_seed: int | None = None

    EXECUTION: ClassVar[tuple[str, ...]] = ("processes",)
    """Settings that change where work runs, not results (left out of run ids)."""

    def __post_init__(self) -> None:
        if not isinstance(self.body, str) or not self.body:
            raise ValueError(f"body {self.body!r}: need a body TOML path or name")
        if self.law is not None and self.law not in LAWS:
            raise ValueError(f"law {self.law!r}: allowed: {', '.join(LAWS)}")
        if self.nu is not None and not (_number(self.nu) and -1 < self.nu < 0.5):
            raise ValueError(f"nu {self.nu!r}: must be a number in (-1, 0.5)")
        check_solver_settings(self)
        if not (_number(self.load_scale) and self.load_scale > 0):
            raise ValueError(f"load_scale {self.load_scale!r}: need a number > 0")
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel {self.kernel!r}: allowed: {', '.join(KERNELS)}")
        c = self.chord_ratio
        if c is not None and not (_number(c) and 0 <= c < 1):
            raise ValueError(f"chord_ratio {c!r}: must be in [0, 1) (0: plain Newton)")
        r = self.sensitivity_refine
        if r is not None and not isinstance(r, bool):
            raise ValueError(f"sensitivity_refine {r!r}: need true or false")
        reuse = self.path_reuse
        if reuse is not None and not isinstance(reuse, bool):
            raise ValueError(f"path_reuse {reuse!r}: need true or false")
        check_field_settings(self)

    def proposed_scenarios(self) -> list[Scenario]:
        """The body's manipulations as scenarios (their loads name ``body``).

        None for a shipped body: the plugin registers its manipulations, and
        a registry built by hand (a study giving them other transfer targets)
        keeps its own.

        Raises
        ------
        ValueError
            The body file is missing or invalid (one line).
        """
        from idbench_fem.bodies.catalog import SHIPPED, get_body

        if self.body in SHIPPED:
            return []
        return body_scenarios(get_body(self.body), self.body)

    def proposed_defaults(self) -> ModelDefaults | None:
        """The comparison the body proposes, None for the default body.

        Its first manipulation, its model meshes (a mesh named ``*-nN`` by its
        node count N, another by its file name stem), its truth, and a prior
        of (E/2, E/2) with E the body's; ``--quick``: the first two model
        meshes against the finest model mesh (the truth if there are two or
        fewer). The default body (the liver) keeps the registered defaults.
        """
        if self.body == DEFAULT_BODY:
            return None
        from idbench_fem.bodies.catalog import get_body, mesh_spec

        body = get_body(self.body)
        meshes = tuple(mesh_spec(body, p) for p in body.mesh.models)
        truth = mesh_spec(body, body.mesh.truth)
        E = body.material.E
        finest = meshes[-1] if len(meshes) > 2 else truth
        quick = {"meshes": meshes[:2], "truth_mesh": finest}
        return ModelDefaults(
            truth_mesh=truth,
            meshes=meshes,
            scenarios=(body.manipulations[0].name,),
            prior=(E / 2, E / 2),
            quick=quick,
        )

    def identity(self) -> list[Any]:
        """What of these settings identifies the data (seeds the noise).

        ``solver`` and ``kernel`` (the same numbers to the Newton tolerance)
        and ``processes`` (where work runs) are left out; true values
        (``--true E=...``) are part of a run anyway.
        """
        out = [self.body, self.law, self.nu, self.reference, self.rtol, self.atol,
               self.max_iterations]  # fmt: skip
        if self.load_scale != 1.0:
            out.append(self.load_scale)
        named = ("chord_ratio", "sensitivity_refine", "path_reuse", *FIELD_SETTINGS)
        extra = [
            [name, getattr(self, name)]
            for name in named
            if getattr(self, name) is not None
        ]
        return [*out, *extra]


FIELD_SETTINGS = ("field_cells", "field_length", "field_std", "field_seed")


def check_field_settings(settings: Any) -> None:
    """Check the field options (each None when not given).

    Raises
    ------
    ValueError
        One line naming the bad value and what is allowed.
    """
    cells = settings.field_cells
    whole = isinstance(cells, int) and not isinstance(cells, bool) and cells >= 1
    if cells is not None and not (whole or cells == "known"):
        raise ValueError(f"field_cells {cells!r}: need a whole number >= 1 or 'known'")
    for name in ("field_length", "field_std"):
        v = getattr(settings, name)
        if v is not None and not (_number(v) and v > 0):
            raise ValueError(f"{name} {v!r}: need a number > 0")
    seed = settings.field_seed
    if seed is not None and (
        not isinstance(seed, int) or isinstance(seed, bool) or seed < 0
    ):
        raise ValueError(f"field_seed {seed!r}: need a whole number >= 0")


def check_solver_settings(settings: Any) -> None:
    """Check the Newton and solver settings the solid and the beam share.

    ``rtol`` and ``atol`` (a number > 0), ``max_iterations`` and ``processes``
    (a whole number >= 1), ``solver`` (one of
    :data:`idbench_fem.fem.solver.BACKENDS`), each None when not given.

    Raises
    ------
    ValueError
        For the first bad value, in one line naming it and what is allowed.
    """
    for name in ("rtol", "atol"):
        v = getattr(settings, name)
        if v is not None and not (_number(v) and v > 0):
            raise ValueError(f"{name} {v!r}: need a number > 0")
    for name in ("max_iterations", "processes"):
        n = getattr(settings, name)
        if n is not None and (not isinstance(n, int) or isinstance(n, bool) or n < 1):
            raise ValueError(f"{name} {n!r}: need a whole number >= 1")
    if settings.solver is not None and settings.solver not in BACKENDS:
        raise ValueError(f"solver {settings.solver!r}: allowed: {', '.join(BACKENDS)}")


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def describe_manipulation(body: Body, name: str) -> str:
    """One line for listings: kind and magnitude of a manipulation."""
    m = body.manipulation(name)
    if m.kind == "pressure":
        return f"dead pressure {m.pressure:g} Pa"
    if m.displacement is not None:
        size = math.sqrt(sum(v * v for v in m.displacement))
        return f"grasp moved {1000 * size:.3g} mm (displacement-controlled)"
    assert m.vector is not None
    size = math.sqrt(sum(v * v for v in m.vector))
    unit = {"traction": "Pa", "gravity": "m/s2", "grasp": "N"}[m.kind]
    return f"{m.kind} {size:.3g} {unit}"


def body_scenarios(body: Body, spec: str) -> list[Scenario]:
    """One scenario per manipulation of ``body`` (``spec``: how loads name it).

    The transfer target is the manipulation's ``transfer`` if given, else the
    next manipulation of the body (cyclically); none for a single one.
    """
    names = [m.name for m in body.manipulations]
    out = []
    for i, m in enumerate(body.manipulations):
        transfer = m.transfer or (names[(i + 1) % len(names)] if len(names) > 1 else "")
        what = f"{describe_manipulation(body, m.name)} ({spec})"
        out.append(
            Scenario(m.name, {"body": spec, "manipulation": m.name}, transfer, what)
        )
    return out


def registered_bodies() -> list[str]:
    """Body specs whose manipulations the plugin registers: shipped, then env."""
    from idbench_fem.bodies.catalog import SHIPPED

    extra = [p for p in os.environ.get(BODIES_ENV, "").split(os.pathsep) if p.strip()]
    return [*SHIPPED, *(os.path.abspath(os.path.expanduser(p)) for p in extra)]


def all_scenarios(taken: set[str]) -> list[Scenario]:
    """Scenarios of every registered body, skipping names already ``taken``.

    A body that cannot be read, or a duplicate name, is logged and skipped
    (one bad file must not disable the plugin).
    """
    from idbench_fem.bodies.catalog import get_body

    out: list[Scenario] = []
    seen = set(taken)
    for spec in registered_bodies():
        try:
            body = get_body(spec)
        except ValueError as exc:
            log.warning("%s: %s", BODIES_ENV, exc)
            continue
        for sc in body_scenarios(body, spec):
            if sc.name in seen:
                log.warning(
                    "%s: scenario %r of %s skipped: the name is taken",
                    BODIES_ENV, sc.name, spec,
                )  # fmt: skip
                continue
            seen.add(sc.name)
            out.append(sc)
    return out
