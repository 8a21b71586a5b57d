"""A base for estimators: write the maths, get the run scaffolding.

:class:`Filter` implements the :class:`~idbench.Estimator` protocol (as DAPPER's
``da_method`` wraps ``assimilate``): it owns ``start`` and ``update`` and does,
once for all, the run check, the step check, the cost bookkeeping, the turning
of a failed linear solve into :class:`~idbench.Diverged` and the final
finite/bounds check, and the masking of occluded (NaN) observation entries
(:mod:`idbench.observe.occlusion`: the analysis sees the visible entries only). A
subclass writes only ``begin`` (set up a run) and ``assimilate`` (advance to
step k, assimilate the observation), working on xi = transform(theta)
(:mod:`idbench.estimate.transforms`) and returning an :class:`Analysis`. Estimators
that do not subclass it keep working: the protocol is the contract.

A subclass is checked when it is defined (:meth:`Filter.__init_subclass__`):
one that lacks a method, takes the wrong arguments or declares settings that
cannot be dataclass fields raises TypeError naming itself, so a broken
estimator plugin fails when it is imported. A base for other estimators that
is none itself says so: ``class EnsembleFilter(Filter, abstract=True)``.
"""

from __future__ import annotations

import inspect
import math
from abc import abstractmethod
from dataclasses import MISSING, dataclass, field
from typing import Any, ClassVar

import numpy as np

from idbench.core.capabilities import is_placeholder, observation_cov_of
from idbench.core.interfaces import (
    Cost,
    Diverged,
    Estimate,
    FloatArray,
    ForwardModel,
    Observation,
    Prior,
)
from idbench.core.settings import (
    check_choice,
    has_default,
    is_classvar,
    undeclared_settings,
)
from idbench.estimate.transforms import TRANSFORMS, IdentityTransform
from idbench.observe.occlusion import BoolArray, MaskedModel, restrict
from idbench.observe.occlusion import visible as visible_mask

CORRECTIONS = ("none", "approximation-error", "prior-mean")
"""Values of the ``correction`` setting."""


@dataclass(frozen=True)
class Analysis:
    """What :meth:`Filter.assimilate` returns for one load step.

    Attributes
    ----------
    xi
        Parameter estimate in the transformed space, (p,).
    cov
        Its covariance (p, p), or None if the estimator has none (then the
        reported std is NaN).
    state
        The estimator's own model state at this step (used for the shape
        error), or None.
    finite
        Further arrays that must be finite (covariances, ensembles, states);
        a non-finite one is a divergence.
    """

    xi: FloatArray
    cov: FloatArray | None = None
    state: FloatArray | None = None
    finite: tuple[FloatArray, ...] = ()


@dataclass(frozen=True)
class Run:
    """What :class:`Filter` keeps about its current run.

    Attributes
    ----------
    model
        The forward model of the run.
    cost0
        The model's cost when the run started (the cost is counted from it).
    """

    model: ForwardModel
    cost0: Cost


class _Conventions:
    """The optional members the core looks for on an estimator, with defaults.

    Declared, with the defaults the core takes without them, in
    :data:`idbench.core.members.ESTIMATOR_OPTIONAL`; given here as class
    attributes outside the dataclass, so that none of them is a setting; see
    :class:`Filter` for their meaning.
    """

    abstract: ClassVar[bool] = False
    reference: ClassVar[bool] = False
    by_default: ClassVar[bool] = True
    handles_nan: ClassVar[bool] = False
    seed: int | None = None
    innovation: tuple[FloatArray, FloatArray] | None = None

    def estimate_solves(self, n_state: int, p: int, steps: int) -> int:
        """Forward model steps a run is expected to take (default: one a step).

        Parameters
        ----------
        n_state
            Size of the model state (e.g. the free displacements).
        p
            Number of parameters.
        steps
            Load steps K of the run.

        Returns
        -------
        int
            A guess, for planning only: ``idbench compare --dry-run`` sums it
            and the sweep starts the costliest runs first; 0 for a run
            :meth:`Filter.start` would skip.
        """
        return steps


@dataclass
class Filter(_Conventions):
    """Base of an estimator: the run scaffolding around ``begin`` and ``assimilate``.

    A subclass is a dataclass whose fields are its settings (each with a
    default); it implements :meth:`begin` and :meth:`assimilate`. Validate
    settings in ``__post_init__`` (call ``super().__post_init__()``), raising
    ValueError naming the value and what is allowed. The class is checked
    when it is defined (:meth:`__init_subclass__`).

    Attributes
    ----------
    abstract
        Class keyword, default False: ``class Base(Filter, abstract=True)``
        declares a base for other estimators that is none itself. It need not
        implement :meth:`begin` and :meth:`assimilate` (nor the methods of its
        own it marks ``@abc.abstractmethod``, which its concrete subclasses
        must implement), and it cannot be registered.
    transform
        ``"log"`` (xi = ln theta, default) or ``"identity"``.
    sigma_floor
        Lower bound (m) on the observation noise std used in R.
    reference
        Class attribute, default False: True marks the estimator whose fit on
        a run's data is that run's reference value (``E_ref``); one
        registered estimator has it.
    by_default
        Class attribute, default True: False leaves the estimator out of a
        comparison that names none (the estimators of parameter fields).
    seed
        Default None: the estimator draws no random numbers. One that does
        declares a field ``seed: int = 0``; the harness then gives each run
        its seed (unless the user set one), so draws differ between seeds and
        repeat with them.
    innovation
        Default None (reset by :meth:`start`): after an observed step, a
        filter may set ``(nu, S)``, the innovation nu = y - y_hat (m,) of the
        forecast and its covariance S = H P H^T + R (m, m); the traces'
        ``nis`` column is then nu^T S^-1 nu (over the visible entries of an
        occluded observation).
    handles_nan
        Class attribute: True when the estimator takes observations with NaN
        (occluded) entries. The protocol's default is False (the harness
        refuses such a run in one line); :class:`Filter` is True: it masks
        them (see :meth:`update`).
    visible
        During :meth:`assimilate`: None when every entry of the observation is
        visible, else the mask (m,) of its visible entries (the observation
        given and :attr:`model` already restricted to them). An estimator
        that keeps past observations (batch least squares) keeps their masks
        and sees them through :class:`idbench.observe.occlusion.MaskedModel` of
        ``self.run.model``.
    correction
        ``"none"`` (default: the model is trusted, the estimate is the mesh's
        effective parameter) or ``"approximation-error"`` (the physical
        parameter, through the model corrected by an offline calibration
        against a finer mesh of the same body). With the latter the harness
        hands the filter the corrected model
        (:mod:`idbench.calibrate.discrepancy`), whose
        ``observe`` adds the mean discrepancy mu and whose
        ``observation_cov(state)`` is its covariance Sigma: the observation
        model is y = h(x) + mu + e, e ~ N(0, R + Sigma), and the estimate is
        the physical (tissue's) parameter. A filter reads R + Sigma from
        :meth:`noise_cov`. ``"prior-mean"``: the model's h(x) carries
        the mean approximation error at the prior mean, frame by frame, from
        one path on a finer mesh (:mod:`idbench.calibrate.prior_mean`); the
        filter changes nothing.
    """

    handles_nan: ClassVar[bool] = True

    transform: str = "log"
    sigma_floor: float = 1e-6
    correction: str = "none"
    _run: Run | None = field(default=None, init=False, repr=False, compare=False)
    _view: MaskedModel | None = field(
        default=None, init=False, repr=False, compare=False
    )
    visible: BoolArray | None = field(
        default=None, init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        check_choice("transform", self.transform, tuple(TRANSFORMS))
        floor = self.sigma_floor
        if not (isinstance(floor, int | float) and math.isfinite(floor) and floor > 0):
            raise ValueError(
                f"sigma_floor = {floor!r} is not allowed; it must be finite > 0"
            )
        check_choice("correction", self.correction, CORRECTIONS)

    def __init_subclass__(cls, *, abstract: bool = False, **kwargs: Any) -> None:
        """Check a subclass when it is defined (as DAPPER checks its methods).

        Raises
        ------
        TypeError
            Naming the class and what is wrong: a method marked
            ``@abc.abstractmethod`` (:meth:`begin`, :meth:`assimilate`, or one
            of an abstract base) not implemented (unless ``abstract=True``);
            one of those or :meth:`estimate_solves` not a method that takes
            the arguments the base passes; an ``__init__`` of its own (the
            settings are dataclass fields); a setting without a default; a
            public class attribute neither annotated (a field) nor
            ``ClassVar``; a base whose settings are no dataclass fields (not
            decorated with ``@dataclass``).
        """
        super().__init_subclass__(**kwargs)
        cls.abstract = abstract
        wrong = subclass_problems(cls)
        if wrong:
            raise TypeError(
                f"estimator class {cls.__name__} ({cls.__module__}): "
                + "; ".join(wrong)
            )

    # --- what a subclass writes --------------------------------------------

    @abstractmethod
    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """Set up the run's own state (the estimator's part of :meth:`start`).

        May raise :class:`~idbench.Skipped` to refuse the run with a reason.
        """
        raise NotImplementedError

    @abstractmethod
    def assimilate(self, k: int, observation: Observation | None) -> Analysis:
        """Advance to step ``k``, assimilate ``observation`` if any; the analysis."""
        raise NotImplementedError

    # --- the protocol ------------------------------------------------------

    def start(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run on ``model`` from ``prior`` (cost counted from here)."""
        corrected = self.correction == "approximation-error"
        if corrected and observation_cov_of(model) is None:
            raise ValueError(
                f"correction = {self.correction!r} needs a corrected model (one "
                "with observation_cov); idbench compare provides it"
            )
        self._run = Run(model, model.cost())
        self.innovation = None
        self.begin(model, prior)

    def update(self, k: int, observation: Observation | None) -> Estimate:
        """Advance to load step ``k`` and assimilate ``observation`` if any.

        An observation with NaN (occluded) values is assimilated with its
        visible values only: :meth:`assimilate` is given the observation of
        those (values and noise std) and, while it runs, :attr:`model` is the
        run's model restricted to them (:class:`~idbench.observe.occlusion.MaskedModel`:
        h(x), the sensitivity rows, a corrected model's Sigma); one all NaN is
        no observation (and leaves :attr:`innovation` None).

        Raises
        ------
        ValueError
            If ``k`` is outside 1..K or the observation is for another step.
        Diverged
            A linear solve failed, or the estimate is non-finite or out of
            bounds, or an array of :attr:`Analysis.finite` is non-finite.
        """
        run = self.run
        n_steps = run.model.n_steps
        if not 1 <= k <= n_steps:
            raise ValueError(f"step k = {k} is outside 1..{n_steps}")
        if observation is not None and observation.step != k:
            raise ValueError(
                f"observation for step {observation.step} given at step {k}"
            )
        mask = None if observation is None else visible_mask(observation)
        if mask is not None and not mask.any():  # every entry occluded
            observation, mask = None, None
            self.innovation = None  # none of this step's (not the last one's)
        elif mask is not None:
            observation = restrict(observation, mask)  # type: ignore[arg-type]
            self._view = MaskedModel(run.model, mask)
        self.visible = mask
        try:
            result = self.assimilate(k, observation)
        except np.linalg.LinAlgError as exc:
            raise Diverged(f"linear algebra failed: {exc}", step=k) from exc
        finally:
            self._view, self.visible = None, None
        self.check_estimate(result.xi, k, *result.finite)
        mean = self.to_theta(result.xi)
        if result.cov is None:
            std = np.full_like(mean, np.nan)
        else:
            with np.errstate(invalid="ignore"):
                std_xi = np.sqrt(np.diag(result.cov))
            std = self.transformation.std(mean, std_xi)
        state = result.state
        return Estimate(
            mean=mean,
            std=std,
            cost=run.model.cost() - run.cost0,
            state=None if state is None else np.array(state, dtype=float),
        )

    # --- helpers for the subclass ------------------------------------------

    @property
    def run(self) -> Run:
        """The current run (RuntimeError before :meth:`start`)."""
        if self._run is None:
            raise RuntimeError("call start() before update()")
        return self._run

    @property
    def model(self) -> ForwardModel:
        """The current run's model (RuntimeError before :meth:`start`).

        While an occluded observation is assimilated: that model restricted
        to the observation's visible entries (see :meth:`update`).
        """
        if self._view is not None:
            return self._view  # type: ignore[return-value]
        return self.run.model

    @property
    def transformation(self) -> IdentityTransform:
        """The transform object of the ``transform`` setting."""
        return TRANSFORMS[self.transform]

    def to_xi(self, theta: FloatArray) -> FloatArray:
        """Natural parameters (p,) -> xi (p,)."""
        return self.transformation.to_xi(theta)

    def to_theta(self, xi: FloatArray) -> FloatArray:
        """Xi (p,) -> natural parameters (p,)."""
        return self.transformation.to_theta(xi)

    def dtheta_dxi(self, xi: FloatArray) -> FloatArray:
        """Diagonal of d theta / d xi, shape (p,)."""
        return self.transformation.dtheta_dxi(xi)

    def prior_xi(self, prior: Prior) -> tuple[FloatArray, FloatArray]:
        """Prior mean (p,) and covariance (p, p) of xi, for the current run's model."""
        return self.transformation.prior_xi(prior, self.model.parameters.p)

    def noise_var(self, observation: Observation) -> float | FloatArray:
        """Observation noise variance R_ii = max(noise_std, sigma_floor)^2.

        A float when the observation has one ``noise_std``; an array (m,)
        when it has one per value (a combined observation, e.g. cloud+force):
        R is then diagonal with these entries (:func:`noise_matrix`).
        """
        if np.ndim(observation.noise_std) == 0:
            return float(max(observation.noise_std, self.sigma_floor)) ** 2
        std = np.asarray(observation.noise_std, dtype=float)
        return np.maximum(std, self.sigma_floor) ** 2

    def extra_cov(self, state: FloatArray) -> FloatArray | None:
        """Sigma (m, m) of the corrected model at ``state``; None uncorrected.

        None unless ``correction`` is ``"approximation-error"`` (the model
        then has ``observation_cov``, see :meth:`start`).
        """
        if self.correction != "approximation-error":
            return None
        cov = observation_cov_of(self.model)
        if cov is None:  # start() refuses such a model
            raise ValueError("a corrected run's model lost its observation_cov")
        return np.asarray(cov(state), dtype=float)

    def noise_cov(
        self, observation: Observation, state: FloatArray, extra: float = 0.0
    ) -> FloatArray:
        """R + Sigma (m, m): (noise_var + extra) I plus :meth:`extra_cov` at ``state``.

        ``extra`` is a further variance on the diagonal (a filter's own
        model-error setting).
        """
        m = np.asarray(observation.values).size
        r = noise_matrix(self.noise_var(observation) + extra, m)
        sigma = self.extra_cov(state)
        return r if sigma is None else r + sigma

    def check_estimate(self, xi: FloatArray, k: int, *finite: FloatArray) -> None:
        """Raise :class:`~idbench.Diverged` at step k for a bad estimate.

        Bad: theta(xi) non-finite or outside the model's bounds, or one of
        the ``finite`` arrays (covariances, states) non-finite.
        """
        theta = self.to_theta(xi)
        if not np.all(np.isfinite(theta)):
            raise Diverged(f"the parameter estimate is non-finite: {theta}", step=k)
        for arr in finite:
            if not np.all(np.isfinite(arr)):
                raise Diverged(
                    "the filter's updated state is non-finite (its covariance or "
                    f"model state; the parameter estimate {theta} is finite)",
                    step=k,
                )
        spec = self.model.parameters
        if not spec.contains(theta):
            raise Diverged(
                f"the parameter estimate {theta} left the bounds "
                f"[{spec.lower}, {spec.upper}]",
                step=k,
            )


def noise_matrix(var: float | FloatArray, m: int) -> FloatArray:
    """R (m, m) from a variance: ``var * I`` for a float, ``diag(var)`` for (m,)."""
    if np.ndim(var) == 0:
        return var * np.eye(m)
    return np.diag(np.broadcast_to(np.asarray(var, dtype=float), (m,)))


CALLED = ("begin", "assimilate", "estimate_solves")
"""The methods :class:`Filter` calls on a subclass, with its own arguments."""


def subclass_problems(cls: type[Filter]) -> list[str]:
    """What is wrong with a subclass of :class:`Filter` (empty: nothing).

    See :meth:`Filter.__init_subclass__`.
    """
    out = []
    missing = [] if cls.abstract else unimplemented(cls)
    if missing:
        out.append(
            f"lacks {', '.join(missing)} (implement them, or declare a base for "
            f"other estimators: class {cls.__name__}(Filter, abstract=True))"
        )
    for name in CALLED:
        if name in vars(cls):
            out.extend(_signature_problem(name, vars(cls)[name]))
    out.extend(_settings_problems(cls))
    for base in cls.__mro__[1:-1]:
        unfielded = undeclared_settings(base) if issubclass(base, Filter) else []
        if unfielded:
            out.append(
                f"base {base.__name__} is not a dataclass (settings "
                f"{', '.join(unfielded)} are no fields): decorate it with @dataclass"
            )
    return out


def unimplemented(cls: type) -> list[str]:
    """The methods marked ``@abc.abstractmethod`` that ``cls`` does not implement."""
    marked = {n for b in cls.__mro__ for n, v in vars(b).items() if is_placeholder(v)}
    found = {n: next(vars(b)[n] for b in cls.__mro__ if n in vars(b)) for n in marked}
    return sorted(n for n, v in found.items() if is_placeholder(v))


def _signature_problem(name: str, method: Any) -> list[str]:
    """Why ``method`` cannot stand for :class:`Filter`'s ``name`` (empty: it can)."""
    if not inspect.isfunction(method):
        return [f"{name} is no method ({type(method).__name__})"]
    base = vars(Filter).get(name) or vars(_Conventions)[name]
    args = list(inspect.signature(base).parameters)
    try:
        inspect.signature(method).bind(*args)
    except TypeError:
        return [f"{name} must take ({', '.join(args)}) as the base calls it"]
    return []


def _settings_problems(cls: type) -> list[str]:
    """Why the settings a class declares cannot all be dataclass fields."""
    own = vars(cls)
    annotated = own.get("__annotations__", {})
    conventions = [n for n, hint in vars(_Conventions)["__annotations__"].items()
                   if is_classvar(hint)]  # fmt: skip
    out = []
    if "__init__" in own:
        out.append(
            "defines __init__: its settings must be dataclass fields (validate "
            "them in __post_init__)"
        )
    for name, hint in annotated.items():
        setting = not name.startswith("_") and not is_classvar(hint)
        if setting and not has_default(own.get(name, MISSING)):
            out.append(f"setting {name!r} has no default")
    for name, value in own.items():
        method = callable(value) or isinstance(value, property | classmethod)
        known = name.startswith("_") or name in annotated or name in conventions
        if not (method or known):
            out.append(
                f"{name} = {value!r} is no dataclass field: annotate it (a "
                "setting) or declare it ClassVar"
            )
    return out
