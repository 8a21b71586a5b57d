"""Execute one run: feed the observation stream to the estimator, guarded.

:func:`execute` turns a :class:`~idbench.plan.runspec.RunSpec` into one row of the
runs table and one row per step of the traces table (built by
:mod:`idbench.run.rows`). It never raises for a problem of the run: a plugin
that raises, exits, returns nonsense or overruns the timeout fails its run
only. Shared inputs come from a :class:`~idbench.run.session.Session`.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from typing import Any, cast

import numpy as np

from idbench.core.capabilities import (
    correction_of,
    diagnostics_of,
    extrapolated_of,
    innovation_of,
    n_nodes_of,
    state_of,
)
from idbench.core.interfaces import (
    Cost,
    Diverged,
    FloatArray,
    ForwardModel,
    ModelError,
    ModelFailure,
    Observation,
    Skipped,
)
from idbench.core.settings import estimator_arguments, public_settings
from idbench.observe import occlusion, surface
from idbench.observe.observed_model import model_state
from idbench.plan.config import ConfigError
from idbench.plan.runspec import RunSpec
from idbench.plan.validity import run_warning
from idbench.run import rows
from idbench.run.checked import CheckedModel
from idbench.run.session import Session
from idbench.score import metrics, targets
from idbench.store import registered, surfaces
from idbench.truth.simulate import Truth

log = logging.getLogger(__name__)


class EstimatorError(RuntimeError):
    """An estimator raised something other than a divergence or a skip.

    The message names the estimator, its plugin, the call and the step.
    """

    def __init__(self, message: str, step: int | None = None) -> None:
        super().__init__(message)
        self.step = step


class RunTimeout(BaseException):
    """A run overran its ``timeout``.

    A BaseException, so broad ``except Exception`` blocks in plugin code
    cannot swallow it.
    """


@contextlib.contextmanager
def _deadline(seconds: float | None) -> Iterator[None]:
    """Interrupt the run after ``seconds`` of wall time, even mid-step.

    Uses ``SIGALRM``, so it works where the run executes in a main thread on
    POSIX (serial and process-pool runs); elsewhere (Dask worker threads) the
    harness's check between steps is the only limit.
    """
    usable = (
        seconds is not None
        and hasattr(signal, "setitimer")
        and threading.current_thread() is threading.main_thread()
    )
    if not usable:
        yield
        return

    def expire(signum: int, frame: Any) -> None:
        raise RunTimeout(f"run exceeded --timeout {seconds:g} s (stopped mid-step)")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, float(seconds))  # type: ignore[arg-type]
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


_SIGINT = {"received": False}


@contextlib.contextmanager
def _noting_sigint() -> Iterator[None]:
    """Note a real Ctrl-C (SIGINT) while a run executes in the main thread.

    So that a ``KeyboardInterrupt`` that plugin code raises itself is told apart
    from the user's: the first fails the run, the second stops the sweep.
    """
    _SIGINT["received"] = False
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    if previous == signal.SIG_IGN:  # a worker: its parent handles Ctrl-C
        yield
        return

    def note(signum: int, frame: Any) -> None:
        _SIGINT["received"] = True
        if callable(previous):
            previous(signum, frame)
        else:
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, note)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _blame(who: str, call: str, step: int | None = None) -> Iterator[None]:
    """Re-raise an unexpected exception of an estimator as :class:`EstimatorError`.

    ``sys.exit()`` and a ``KeyboardInterrupt`` raised by the plugin itself (not
    by a real Ctrl-C) fail the run too, instead of ending the sweep.
    """
    at = f" at step {step}" if step is not None else ""
    try:
        yield
    except (Diverged, ModelFailure, Skipped, ConfigError, ModelError):
        raise
    except SystemExit as exc:
        raise EstimatorError(
            f"{who} called sys.exit({exc.code!r}) in {call}{at}", step=step
        ) from None
    except KeyboardInterrupt:
        if _SIGINT["received"]:
            raise
        raise EstimatorError(
            f"{who} raised KeyboardInterrupt in {call}{at} (no Ctrl-C was pressed)",
            step=step,
        ) from None
    except Exception as exc:
        raise EstimatorError(
            f"{who} raised in {call}{at}: {type(exc).__name__}: {exc}", step=step
        ) from exc


def _checked(who: str, est: Any, p: int, k: int) -> tuple[FloatArray, FloatArray]:
    """The mean and std (p,) of an estimator's answer, or EstimatorError."""
    mean = np.asarray(est.mean, dtype=float)
    std = np.asarray(est.std, dtype=float)
    if std.ndim == 0:
        std = np.full(p, float(std))
    for what, value in (("mean", mean), ("std", std)):
        if value.shape != (p,):
            raise EstimatorError(
                f"{who} returned a {what} of shape {value.shape} at step {k}; "
                f"expected ({p},), one value per parameter",
                step=k,
            )
    if np.any(std < 0):
        raise EstimatorError(
            f"{who} returned a negative std {std.tolist()} at step {k}; a std is "
            ">= 0 (NaN: the estimator has none)",
            step=k,
        )
    if not isinstance(est.cost, Cost):
        raise EstimatorError(
            f"{who} returned cost {est.cost!r} at step {k}; expected an idbench.Cost",
            step=k,
        )
    counts = (est.cost.forward_solves, est.cost.newton_its, est.cost.linear_solves)
    if not all(_count(c) for c in counts):
        raise EstimatorError(
            f"{who} returned cost {est.cost!r} at step {k}; its counts must be "
            "numbers >= 0",
            step=k,
        )
    state = state_of(est)
    if state is not None and not np.all(np.isfinite(np.asarray(state, dtype=float))):
        raise EstimatorError(
            f"{who} returned a non-finite state at step {k} (the model state it "
            "reports must be finite)",
            step=k,
        )
    return mean, std


def _count(value: Any) -> bool:
    """Whether ``value`` is a usable work count: a finite number >= 0."""
    return (
        isinstance(value, int | float | np.integer | np.floating)
        and not isinstance(value, bool)
        and bool(np.isfinite(value))
        and bool(value >= 0)
    )


def execute(
    spec: RunSpec, session: Session, phase: Callable[[str], None] | None = None
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Run one identification and score it.

    Never raises for a problem of the run itself: the status column says
    ``ok``, ``diverged``, ``failed`` or ``skipped`` and ``error`` says why.
    ``phase("estimator")`` is called when the estimator's own work (what
    ``timeout`` limits) begins, ``phase("scoring")`` when it ends.

    Returns
    -------
    tuple
        The run's row (dict) and its trace rows (one dict per step).
    """
    row: dict[str, Any] = rows.base_row(spec)
    traces: list[dict[str, Any]] = []
    t_start = time.perf_counter()
    try:
        with _noting_sigint():
            _run(spec, session, row, traces, phase)
    except RunTimeout as exc:
        row.update(status="failed", error=str(exc))
    except Skipped as exc:
        row.update(status="skipped", error=str(exc))
    except (Diverged, ModelFailure) as exc:
        row.update(status="diverged", error=str(exc), failed_step=exc.step)
    except ModelError as exc:  # the model's fault, named (not the estimator's)
        row.update(
            status="failed",
            error=str(exc),
            failed_step=np.nan if exc.step is None else exc.step,
        )
    except EstimatorError as exc:
        row.update(
            status="failed",
            error=str(exc),
            failed_step=np.nan if exc.step is None else exc.step,
            traceback=traceback.format_exc(),
        )
    except (KeyboardInterrupt, SystemExit):
        raise
    except ConfigError as exc:
        row.update(status="failed", error=f"{type(exc).__name__}: {exc}")
    except Exception as exc:
        row.update(
            status="failed",
            error=f"{type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(),
        )
    if _SIGINT["received"]:  # a Ctrl-C that plugin code caught and turned
        raise KeyboardInterrupt  # into something else still stops the sweep
    row["wall_s"] = time.perf_counter() - t_start
    if surfaces.ROW_KEY in row:  # what the run shows, for the results folder
        row[surfaces.ROW_KEY] = row[surfaces.ROW_KEY].arrays()
    return row, traces


def _run(
    spec: RunSpec,
    session: Session,
    row: dict[str, Any],
    traces: list[dict[str, Any]],
    phase: Callable[[str], None] | None = None,
) -> None:
    # the estimator gets a private copy of the model, checked after the run
    # (idbench.run.isolation): what it does to it cannot reach later runs
    master, model = session.lend(spec, spec.mesh)
    who = (
        f"estimator {spec.estimator!r} "
        f"(plugin {session.registry.estimators[spec.estimator].plugin!r})"
    )
    try:
        _run_on(spec, session, (master, model), who, row, traces, phase)
    except BaseException as exc:
        _check_returned(session, master, model, who, exc)
        raise
    _check_returned(session, master, model, who, None)


def _check_returned(
    session: Session,
    master: ForwardModel,
    model: ForwardModel,
    who: str,
    failure: BaseException | None,
) -> None:
    """EstimatorError if the run changed its model (or the master: discarded)."""
    changed = session.returned(master, model)
    if changed:
        raise EstimatorError(
            f"{who} changed the model it was given ({', '.join(changed)}); "
            "the run's results cannot be trusted"
        ) from failure


def _run_on(
    spec: RunSpec,
    session: Session,
    models: tuple[ForwardModel, ForwardModel],
    who: str,
    row: dict[str, Any],
    traces: list[dict[str, Any]],
    phase: Callable[[str], None] | None = None,
) -> None:
    """:func:`_run`'s work with the lent ``models`` (master, copy)."""
    master, model = models
    metrics_model = session.model(spec, spec.mesh, role="metrics")
    nodes = n_nodes_of(master)
    row["model_nodes"] = np.nan if nodes is None else nodes
    row["truth_nodes"] = session.truth(spec).nodes
    row.update(rows.empty_parameter_columns(spec))
    row.update(rows.load_columns(master, session.truth(spec)))
    fit = session.registration(spec)
    if fit is not None:  # a camera's clouds, moved onto this mesh's surface
        row.update(registered.columns(fit))
    refined = session.refinement(spec)
    if refined is not None:  # that pose refined with the model
        row.update(refined.columns())

    cls = session.registry.estimator(spec.estimator)
    with _blame(who, "its constructor"):
        try:
            estimator = cls(**estimator_arguments(cls, spec.settings, spec.seed))
        except TypeError as exc:
            allowed = ", ".join(public_settings(cls))
            raise ConfigError(
                f"estimator {spec.estimator!r}: {exc}; allowed settings: {allowed}"
            ) from None
    lent = model  # the run's own copy: its diagnostics, whatever wraps it
    if correction_of(estimator) == "approximation-error" and not (
        spec.observed_otherwise()  # then corrected on its frames (see below)
    ):
        # the physical parameter: the coarse model corrected by its calibration
        model = session.corrected(spec, model)
        metrics_model = session.corrected(spec, metrics_model)
        row["calibration_cost"] = model.discrepancy.cost
    truth = session.truth(spec)
    stream = session.observations(spec)
    refused = occlusion.refusal(spec.estimator, estimator, stream)
    if refused:  # NaN entries an estimator off idbench.Filter does not mask
        raise Skipped(refused)
    named = _model_who(spec, session)
    try:
        direct = session.direct(spec)
    except ModelError as exc:  # the model run with the true values
        raise ModelError(f"{named} {exc}", exc.step) from None
    # its answers' shapes checked: a model's fault names the model
    m = None if spec.setup.data else int(np.shape(truth.observations)[-1])
    checked = CheckedModel(model, named, m)
    row[surfaces.ROW_KEY] = recorder = surfaces.Recorder(
        metrics_model, spec.setup.steps, _view_keys(spec),
        session.observation_model(spec),
        session.frames(spec) if spec.observed_otherwise() or spec.setup.data else None,
        truth.targets if targets.has_targets(metrics_model, truth) else None,
    )  # fmt: skip
    if phase is not None:
        phase("estimator")
    with _deadline(spec.timeout):  # the estimator's own work, not shared inputs
        t_start = time.perf_counter()
        with _blame(who, "start()"):
            seen = session.estimator_model(spec, cast(ForwardModel, checked))
            if correction_of(estimator) == "prior-mean":  # + mu_k, a fine mesh's
                seen = session.mean_corrected(spec, seen)
            elif correction_of(estimator) == "approximation-error" and (
                spec.observed_otherwise()
            ):  # + mu_k + G_k (ln theta - xi_0), and Sigma_k, on its frames
                seen = session.mean_corrected(spec, seen, linear=True)
            estimator.start(seen, session.prior(master, spec))  # h(x) of its obs.
        if checked.fault is not None:  # even if the estimator caught it
            raise checked.fault
        est, means, stds, last = _estimate(
            spec, estimator, who, stream, truth, direct, traces,
            (checked, metrics_model), t_start, recorder,
        )  # fmt: skip
    if phase is not None:
        phase("scoring")
    if spec.estimator == spec.setup.reference and not spec.settings:
        # this run *is* the reference fit on its data: no need to fit it again
        # (unless it changed its model: then it is no one's reference)
        _check_returned(session, master, model, who, None)
        if session.known_reference(spec) is None:
            session.remember_reference(spec, means[-1])
    row.update(rows.final_columns(spec, session, means, stds, traces, est))
    if spec.setup.data:
        row["heldout_final_mm"] = traces[-1]["heldout_mm"]
        if "heldout_points_mm" in traces[-1]:
            row["heldout_points_final_mm"] = traces[-1]["heldout_points_mm"]
    if targets.has_targets(metrics_model, truth):
        columns, region = targets.final_scores(
            metrics_model, estimator, last, means[-1], stds[-1],
            truth.targets[-1],  # type: ignore[index]
        )  # fmt: skip
        row.update(columns)
        recorder.region(region)  # the predicted 95% regions, for the view
    if "calibration_cost" in row:  # corrected: the grid's predictive uncertainty
        row.update(
            targets.grid_columns(metrics_model, estimator, last, means[-1],
                                 stds[-1], truth.grid[-1])
        )  # fmt: skip
    row["warning"] = run_warning(
        model.parameters, stream, truth, spec.noise, means[-1],
        np.array([row[f"{n}_ref"] for n in spec.setup.names]),
    )  # fmt: skip
    inconsistent = metrics.inconsistency(row["nis"], row["nis_dof"])
    if inconsistent:  # a filter whose innovations do not match its noise
        row["warning"] = "; ".join(w for w in (row["warning"], inconsistent) if w)
    if "calibration_cost" in row:  # corrected: its predictions beyond the
        # calibrated load states, the estimator's and the scores' (any estimator)
        beyond = extrapolated_of(model) + extrapolated_of(metrics_model)
        row["extrapolated"] = beyond
        if beyond:
            note = (f"the correction extrapolated ({beyond} predictions beyond "
                    "the calibrated load states)")  # fmt: skip
            row["warning"] = "; ".join(w for w in (row["warning"], note) if w)
    columns, note = diagnostics_of(lent)  # a model's report on its own run
    row.update(columns)
    row["warning"] = "; ".join(w for w in (row["warning"], note) if w)


def _model_who(spec: RunSpec, session: Session) -> str:
    """The run's model as its faults name it: model, plugin and mesh."""
    name = spec.setup.model
    plugin = session.registry.models[name].plugin
    return f"model {name!r} (plugin {plugin!r}) on mesh {spec.mesh!r}"


def _view_keys(spec: RunSpec) -> dict[str, str]:
    """The keys a run's stored surfaces name (see :mod:`idbench.store.surfaces`)."""
    truth = "" if spec.setup.data else spec.truth_product_key(spec.scenario)
    mesh = spec.model_key(spec.mesh, spec.scenario, "est")
    return {"run_id": spec.run_id, "mesh_key": mesh, "truth_key": truth}


def _estimate(
    spec: RunSpec,
    estimator: Any,
    who: str,
    stream: list[Observation | None],
    truth: Truth,
    direct: FloatArray,
    traces: list[dict[str, Any]],
    models: tuple[CheckedModel, ForwardModel],
    t_start: float,
    recorder: surfaces.Recorder,
) -> tuple[Any, FloatArray, FloatArray, FloatArray]:
    """Feed the stream to the estimator; score and trace every step.

    Returns the last :class:`~idbench.core.interfaces.Estimate`, the means and the
    stds (K, p), and the last step's model state (what it was scored with).
    The shape error uses the estimator's own state where it has one, else one
    forward solve with the current estimate (not counted).
    """
    checked, metrics_model = models  # bounds from the metrics model (not lent out)
    p = metrics_model.parameters.p
    shadow = metrics_model.reset()
    means = np.full((spec.setup.steps, p), np.nan)
    stds = np.full((spec.setup.steps, p), np.nan)
    solves_before = 0
    newton_before = 0
    scored = targets.has_targets(metrics_model, truth)
    state = shadow
    for k, obs in enumerate(stream, start=1):
        t0 = time.perf_counter()
        with _blame(who, "update()", k):
            est = estimator.update(k, obs)
            if checked.fault is not None:  # even if the estimator caught it
                raise checked.fault
            mean, std = _checked(who, est, p, k)
        dt = time.perf_counter() - t0
        if not metrics_model.parameters.contains(mean):
            raise Diverged(
                f"the parameter estimate {mean} is non-finite or outside the "
                "bounds",
                step=k,
            )
        means[k - 1], stds[k - 1] = mean, std
        own = state_of(est)
        if own is not None:  # the model's part (see observed_model)
            state = model_state(own, shadow.size)
        else:
            shadow = metrics_model.step(mean, k, shadow)
            state = shadow
        recorder.step(k, state, obs)
        innovation = innovation_of(est, estimator)
        trace = rows.step_row(
            spec, k, obs, est, mean, std, metrics_model.grid(state), truth, direct,
            innovation,
        )  # fmt: skip
        if scored:
            trace["tre_mm"] = targets.step_tre_mm(
                metrics_model,
                state,
                truth.targets[k - 1],  # type: ignore[index]
            )
        if spec.setup.data:  # a recording: its held-out marker tracks
            trace["heldout_mm"] = targets.heldout_mm(
                metrics_model, state, truth.observations[k - 1]
            )
            if truth.held_points is not None:  # and its held-out points
                trace["heldout_points_mm"] = surface.heldout_points_mm(
                    metrics_model, state, truth.held_points[k - 1]
                )
        trace.update(
            n_solves=est.cost.forward_solves - solves_before,
            newton_its=est.cost.newton_its - newton_before,
            wall_s=dt,
        )
        solves_before = est.cost.forward_solves
        newton_before = est.cost.newton_its
        traces.append(trace)
        if spec.timeout is not None and time.perf_counter() - t_start > spec.timeout:
            raise RunTimeout(f"run exceeded --timeout {spec.timeout:g} s at step {k}")

    return est, means, stds, state
