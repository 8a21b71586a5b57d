"""Protocols and value types shared by the core, the models and the estimators.

The core knows nothing of finite elements or filters. A *forward model* advances
a load path one quasi-static step at a time, for given parameters, from a given
state; an *estimator* consumes one observation (or none) per load step and
reports its current estimate. Both are structural (:class:`typing.Protocol`):
anything with the right methods works.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from idbench.core.scenario import Scenario

FloatArray = NDArray[np.float64]


class ConfigError(ValueError):
    """A setting is invalid; the message names the value and what is allowed."""


class ModelFailure(RuntimeError):
    """A forward solve did not converge (or produced an inverted element).

    Parameters
    ----------
    message
        What went wrong.
    step
        The load-step index ``k`` (1..K) at which it happened.
    """

    def __init__(self, message: str, step: int | None = None) -> None:
        super().__init__(message if step is None else f"step {step}: {message}")
        self.step = step


class ModelError(RuntimeError):
    """A model broke the protocol: an answer of the wrong shape.

    Not a failed solve (:class:`ModelFailure`): a fault of the model's code,
    charged to it. The message says which call returned what (the run room
    adds the model's name and plugin).
    """

    def __init__(self, message: str, step: int | None = None) -> None:
        super().__init__(message)
        self.step = step


class Diverged(RuntimeError):
    """An estimator's state became non-finite or left the parameter bounds."""

    def __init__(self, message: str, step: int | None = None) -> None:
        super().__init__(message if step is None else f"step {step}: {message}")
        self.step = step


class Skipped(RuntimeError):
    """An estimator refuses a run up front (e.g. it would exceed a cost budget)."""


@dataclass(frozen=True)
class ParameterSpec:
    """The unknown parameters of a model.

    Attributes
    ----------
    names
        One name per parameter, e.g. ``("E",)`` or ``("E_region0", "E_region1")``;
        the tables' columns are named after them (``E_final``, ``k_final``).
    lower, upper
        Bounds per parameter; an estimate outside them is a divergence.
    default
        True values a comparison uses when it is not given them (``--true``),
        or None: then they must be given.
    priors
        ((name, mean, std), ...): parameters with a prior of their own, in
        natural units (a stiffness of another unit than a modulus, say); the
        comparison's prior is every other parameter's (:meth:`prior`).
    """

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    default: tuple[float, ...] | None = None
    priors: tuple[tuple[str, float, float], ...] = ()

    def __post_init__(self) -> None:
        if not self.names:
            raise ValueError("a model needs at least one parameter")
        if not len(self.names) == len(self.lower) == len(self.upper):
            raise ValueError("names, lower and upper must have the same length")
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"parameter names {self.names} repeat a name")
        if self.default is not None and len(self.default) != len(self.names):
            raise ValueError("default must have one value per parameter")
        for n, lo, hi in zip(self.names, self.lower, self.upper, strict=True):
            if not lo < hi:
                raise ValueError(f"parameter {n!r}: lower {lo} must be < upper {hi}")
        for n, mean, std in self.priors:
            if n not in self.names or not (np.isfinite(mean) and np.isfinite(std)):
                raise ValueError(f"prior of {n!r}: no such parameter or not finite")
            if not std > 0:
                raise ValueError(f"prior of {n!r}: std {std} must be > 0")

    @property
    def p(self) -> int:
        """Number of parameters."""
        return len(self.names)

    def prior(self, mean: float, std: float) -> Prior:
        """The prior: (mean, std) for every parameter but those of ``priors``."""
        own = {n: (m, s) for n, m, s in self.priors}
        pairs = [own.get(n, (mean, std)) for n in self.names]
        return Prior(
            tuple(float(m) for m, _ in pairs), tuple(float(s) for _, s in pairs)
        )

    def contains(self, theta: FloatArray) -> bool:
        """Whether ``theta`` (p,) is finite and inside the bounds."""
        theta = np.asarray(theta, dtype=float)
        return bool(
            np.all(np.isfinite(theta))
            and np.all(theta > np.asarray(self.lower))
            and np.all(theta < np.asarray(self.upper))
        )


@dataclass(frozen=True)
class Cost:
    """Work done by a model, cumulative since it was built.

    Attributes
    ----------
    forward_solves
        Calls to :meth:`ForwardModel.step` (one load step each).
    newton_its
        Newton iterations summed over those calls.
    linear_solves
        Back-substitutions, including those for sensitivities.
    """

    forward_solves: int = 0
    newton_its: int = 0
    linear_solves: int = 0

    def __sub__(self, other: Cost) -> Cost:
        return Cost(
            self.forward_solves - other.forward_solves,
            self.newton_its - other.newton_its,
            self.linear_solves - other.linear_solves,
        )

    def __add__(self, other: Cost) -> Cost:
        return Cost(
            self.forward_solves + other.forward_solves,
            self.newton_its + other.newton_its,
            self.linear_solves + other.linear_solves,
        )


@dataclass(frozen=True)
class Prior:
    """Gaussian prior on the parameters, in their natural (not log) units.

    Attributes
    ----------
    mean, std
        Per parameter, shape (p,).
    """

    mean: tuple[float, ...]
    std: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.mean) != len(self.std):
            raise ValueError("prior mean and std must have the same length")
        if any(not np.isfinite(s) or s <= 0 for s in self.std):
            raise ValueError(f"prior std must be positive and finite, got {self.std}")
        if any(not np.isfinite(m) for m in self.mean):
            raise ValueError(f"prior mean must be finite, got {self.mean}")

    @classmethod
    def broadcast(cls, mean: float, std: float, p: int) -> Prior:
        """The same prior for each of ``p`` parameters."""
        return cls((float(mean),) * p, (float(std),) * p)


@dataclass(frozen=True)
class Observation:
    """What an estimator sees at one load step.

    Attributes
    ----------
    values
        Marker displacements, shape (m,), flattened ``[p0x, p0y, p0z, p1x, ...]``.
    noise_std
        Standard deviation of the additive Gaussian noise on each value: a
        float (the same for all), or an array (m,) of one per value (a
        combined observation, e.g. ``cloud+force``); filters build a diagonal
        R from it (:meth:`idbench.Filter.noise_var`).
    step
        Load-step index ``k`` (1..K).

    Notes
    -----
    With an observation model other than markers (:mod:`idbench.observe.kinds`)
    ``values`` is that model's y (for ``cloud``: zeros, one per point, the
    prediction being each point's distance to the model's surface).
    """

    values: FloatArray
    noise_std: float | FloatArray
    step: int


@dataclass(frozen=True)
class Estimate:
    """An estimator's answer after a load step.

    Attributes
    ----------
    mean
        Parameter estimate, shape (p,), natural units.
    std
        Its standard deviation, shape (p,); NaN where the estimator has none.
    cost
        Model work done by the estimator since :meth:`Estimator.start`.
    state
        The estimator's own model state at this step (free displacements), or
        None if it keeps none; used for the shape error.

    Notes
    -----
    Optional: an estimator (or the Estimate it returns) may expose
    ``innovation = (nu, S)`` after an observed step: the innovation
    nu = y - y_hat (m,) of the forecast and its covariance S = H P H^T + R
    (m, m). The harness then writes the normalised innovation squared
    nu^T S^-1 nu in the traces' ``nis`` column (NaN otherwise).
    """

    mean: FloatArray
    std: FloatArray
    cost: Cost
    state: FloatArray | None = None


@runtime_checkable
class ForwardModel(Protocol):
    """A quasi-static load path on a discretised body, parameterised by theta.

    The model is stateless between calls: every state is passed in and returned
    (a flat float array, e.g. the free displacements), so several sigma points
    can advance from the same step.

    Optional members the core uses when present, each declared as a protocol
    below: ``n_nodes`` (:class:`NodeCountModel`), ``probes``
    (:class:`ProbedModel`), ``sensitivity`` (:class:`SensitiveModel`),
    ``step_many`` (:class:`BatchModel`), ``bounds`` and ``volume``
    (:class:`BoundingBoxModel`, :class:`VolumeModel`): with them (and
    ``n_nodes``) a truth that is another body than a model mesh, or not
    finer, is refused (:mod:`idbench.plan.validity`); ``mesh`` and
    ``displacement_field`` (:class:`FieldModel`) and ``cell_data``
    (:class:`CellDataModel`) for ``idbench simulate``; ``surface``
    (:class:`SurfaceModel`, for the ``cloud`` observation) and ``reaction``
    (:class:`ReactionModel`, for ``force``) and ``targets``
    (:class:`TargetModel`, hidden targets scored by their TRE);
    ``marker_points`` and ``target_points`` (:class:`PlacedPointsModel`,
    where a report draws the markers and the targets);
    ``observation_cov``, ``grid_cov``, ``targets_cov`` and ``extrapolated``
    (:class:`DiscrepancyModel`, a model corrected by its calibration) and
    ``load_scaling`` (:class:`LoadScalingModel`) and ``load_figures``
    (:class:`LoadFiguresModel`, each run's load against the truth's). The core
    looks them up in one place, :mod:`idbench.core.capabilities`;
    :func:`idbench.registry.testing.check_model` checks them.

    A model is built once per process and each run works with
    ``copy.copy`` of it (:mod:`idbench.run.isolation`): define ``__copy__`` if a
    shallow copy would share state that runs write (caches, counters), and
    make the arrays the copies share read-only.
    """

    parameters: ParameterSpec
    n_steps: int

    def reset(self) -> FloatArray:
        """Return the unloaded state, shape (n,)."""
        ...

    def step(
        self, theta: FloatArray, k: int, state: FloatArray, *, substeps: int = 1
    ) -> FloatArray:
        """Solve load step ``k`` (1..K) with parameters ``theta`` from ``state``.

        Raises :class:`ModelFailure` when the solve does not converge.
        """
        ...

    def observe(self, state: FloatArray) -> FloatArray:
        """Marker displacements at ``state``, shape (m,)."""
        ...

    def grid(self, state: FloatArray) -> FloatArray:
        """Displacements of the shape-error points, shape (g, d)."""
        ...

    def cost(self) -> Cost:
        """Cumulative work done since the model was built."""
        ...

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable description of everything the results depend on.

        It keys the truth cache and the run ids, and a results folder
        records it (a resume from another description is refused), so it
        includes a digest of the content of every file the model read (a
        mesh, a body description), not only the file's name; execution
        settings are left out.
        """
        ...


@runtime_checkable
class Estimator(Protocol):
    """Identifies a model's parameters from a stream of observations.

    Implementations are dataclasses whose fields are their settings; ``start``
    resets all run state, so one instance can serve several runs in sequence.
    :class:`idbench.Filter` is a base that implements this protocol around an
    estimator's own ``begin`` and ``assimilate`` (and documents the optional
    members below as defaulted class attributes); subclassing it is optional.

    Optional: ``estimate_solves(n_state, p, steps) -> int``, the forward model
    steps a run is expected to take (0 for a run :meth:`start` would skip).
    The sweep sums it for ``--dry-run`` and starts the costliest runs first,
    so that no long run is left alone at the end of a parallel sweep.
    """

    def start(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run on ``model`` from ``prior``.

        May raise :class:`Skipped` to refuse the run with a reason.
        """
        ...

    def update(self, k: int, observation: Observation | None) -> Estimate:
        """Advance to load step ``k`` (1..K), assimilating ``observation`` if any."""
        ...


@dataclass(frozen=True)
class ModelSpec:
    """Everything a model factory needs to build a forward model.

    Attributes
    ----------
    mesh
        The model's discretisation, a string the model interprets (a mesh
        spec or a path).
    scenario
        The load path; the model interprets ``scenario.load``.
    n_steps
        Number of load steps K.
    markers
        Number of observation points M (the sparsity axis ``obs_points``).
    settings
        The model's own settings: an instance of the settings dataclass it
        registered (None: its defaults). A factory may also accept a plain
        mapping of them, for scripts and tests.
    """

    mesh: str
    scenario: Scenario
    n_steps: int = 20
    markers: int = 2
    settings: Any = None


@dataclass(frozen=True)
class ModelDefaults:
    """What a model plugin proposes for a comparison nobody configured.

    Registered with the model (``register(name, factory, defaults=...)``); the
    command line and :class:`idbench.plan.config.CompareConfig` fill every value the
    user does not give from the chosen model's defaults.

    Attributes
    ----------
    truth_mesh, meshes, scenarios
        The truth discretisation, the model discretisations and the scenario
        names of the default comparison.
    prior
        Prior (mean, std) of every parameter, natural units.
    quick
        Overrides for ``--quick`` (e.g. ``{"truth_mesh": ..., "meshes": [...]}``).
    shorthands
        Extra ``idbench compare`` options that set one of the model's settings,
        or (target ``"true.NAME"``) the true value of parameter NAME: option
        name (without ``--``) -> (target, help text), e.g.
        ``{"nu": ("nu", "Poisson ratio"), "E-true": ("true.E", "true E (Pa)")}``.
    primary
        Whether this is the model ``idbench compare`` uses when none is named
        and several are registered.
    mesh_help
        How the model reads a mesh spec, one line (``compare --help`` and
        ``idbench info`` show it); empty: not said.
    """

    truth_mesh: str
    meshes: tuple[str, ...]
    scenarios: tuple[str, ...]
    prior: tuple[float, float]
    quick: dict[str, Any] = field(default_factory=dict, hash=False)
    shorthands: dict[str, tuple[str, str]] = field(default_factory=dict, hash=False)
    primary: bool = False
    mesh_help: str = ""
