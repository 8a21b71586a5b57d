"""Run a grid of identification runs and score each one.

A run is (scenario, model mesh, estimator and its settings, sparsity, seed).
Runs are independent: :func:`execute` turns a :class:`RunSpec` into one row
of the runs table and one row per step of the traces table. Expensive shared
inputs (the truth, the reference fit, the direct simulation) are memoised in a
:class:`Session`, one per process, and the truth is also cached on disk.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from idbench import metrics
from idbench.config import CompareConfig, ConfigError, public_settings
from idbench.files import stable_hash
from idbench.interfaces import (
    Cost,
    Diverged,
    FloatArray,
    ForwardModel,
    ModelFailure,
    ModelSpec,
    Observation,
    Prior,
    Skipped,
)
from idbench.plugins import Registry, build_registry
from idbench.scenario import Sparsity
from idbench.truth import Truth, simulate_path, simulate_truth

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

    def note(signum: int, frame: Any) -> None:
        _SIGINT["received"] = True
        if callable(previous):
            previous(signum, frame)
        elif previous != signal.SIG_IGN:
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
    except (Diverged, ModelFailure, Skipped, ConfigError):
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
    if not isinstance(est.cost, Cost):
        raise EstimatorError(
            f"{who} returned cost {est.cost!r} at step {k}; expected an idbench.Cost",
            step=k,
        )
    return mean, std


@dataclass(frozen=True)
class RunSpec:
    """Everything one run depends on; small and picklable.

    ``run_id`` is a hash of all fields, so serial, parallel and distributed
    executions of the same sweep agree on it.
    """

    scenario: str
    mesh: str
    estimator: str
    settings: tuple[tuple[str, Any], ...]
    seed: int
    obs_every: int
    obs_points: int
    noise: float
    truth_mesh: str
    steps: int
    E_true: float
    nu: float
    prior: tuple[float, float]
    model: str = "svk-beam"
    parameters: str = "E"
    model_options: tuple[tuple[str, Any], ...] = ()
    grid: tuple[int, int, int] = (20, 4, 4)
    reference: str = "batch-ls"
    timeout: float | None = None

    @property
    def run_id(self) -> str:
        """Deterministic hash of the run description."""
        fields = dataclasses.asdict(self)
        fields.pop("timeout")
        return stable_hash(fields)

    @property
    def sparsity(self) -> Sparsity:
        """The run's sparsity settings."""
        return Sparsity(self.obs_every, self.obs_points, self.noise)

    def data_key(self) -> tuple[Any, ...]:
        """What the observation stream depends on (not estimator or model mesh)."""
        return (
            self.model,
            self.scenario,
            self.truth_mesh,
            self.steps,
            self.E_true,
            self.nu,
            self.parameters,
            self.model_options,
            self.grid,
            self.obs_every,
            self.obs_points,
            self.noise,
            self.seed,
        )


def expand(config: CompareConfig) -> list[RunSpec]:
    """The runs of a comparison, in a stable order."""
    runs = []
    for scenario in config.scenarios:
        for mesh in config.meshes:
            for sp in config.sparsities():
                for estimator in config.estimators:
                    settings = config.estimator_settings.get(estimator, {})
                    for seed in range(config.seeds):
                        runs.append(
                            RunSpec(
                                scenario=scenario,
                                mesh=mesh,
                                estimator=estimator,
                                settings=tuple(sorted(settings.items())),
                                seed=seed,
                                obs_every=sp.obs_every,
                                obs_points=sp.obs_points,
                                noise=float(sp.noise),
                                truth_mesh=config.truth_mesh,
                                steps=config.steps,
                                E_true=float(config.E_true),
                                nu=float(config.nu),
                                prior=(float(config.prior[0]), float(config.prior[1])),
                                model=config.model,
                                parameters=config.parameters,
                                model_options=tuple(
                                    sorted(config.model_options.items())
                                ),
                                grid=tuple(config.grid),  # type: ignore[arg-type]
                                reference=config.reference,
                                timeout=config.timeout,
                            )
                        )
    return runs


class Session:
    """Per-process memo of models, truths, reference fits and direct runs."""

    def __init__(self, registry: Registry | None = None) -> None:
        self.registry = registry or build_registry()
        self._models: dict[Any, ForwardModel] = {}
        self._truths: dict[Any, Truth] = {}
        self._refs: dict[Any, FloatArray] = {}
        self._direct: dict[Any, FloatArray] = {}

    def model(
        self, spec: RunSpec, mesh: str, scenario: str | None = None, role: str = "est"
    ) -> ForwardModel:
        """The forward model of ``mesh`` on ``scenario`` (one per role)."""
        scenario = scenario or spec.scenario
        key = (
            spec.model,
            mesh,
            scenario,
            spec.steps,
            spec.nu,
            spec.obs_points,
            spec.grid,
            spec.parameters,
            spec.model_options,
            role,
        )
        if key not in self._models:
            ms = ModelSpec(
                mesh=mesh,
                scenario=self.registry.scenario(scenario),
                n_steps=spec.steps,
                nu=spec.nu,
                markers=spec.obs_points,
                grid=spec.grid,
                parameters=spec.parameters,
                options=spec.model_options,
            )
            self._models[key] = self.registry.model(spec.model)(ms)
        return self._models[key]

    def theta_true(self, model: ForwardModel, spec: RunSpec) -> FloatArray:
        """True parameters: E_true for every parameter (inclusions: options)."""
        factor = dict(spec.model_options).get("true_factors")
        theta = np.full(model.parameters.p, spec.E_true)
        if factor is not None:
            try:
                factors = np.asarray(factor, dtype=float)
                theta = theta * np.broadcast_to(factors, theta.shape)
            except (ValueError, TypeError):
                raise ConfigError(
                    f"model option true_factors {factor!r}: need one number per "
                    f"parameter ({model.parameters.p})"
                ) from None
        return theta

    def truth(self, spec: RunSpec, scenario: str | None = None) -> Truth:
        """The truth of ``scenario`` (default: the run's), from the disk cache."""
        scenario = scenario or spec.scenario
        model = self.model(spec, spec.truth_mesh, scenario, role="truth")
        key = (id(model), scenario)
        if key not in self._truths:
            self._truths[key] = simulate_truth(model, self.theta_true(model, spec))
        return self._truths[key]

    def observations(self, spec: RunSpec) -> list[Observation | None]:
        """The noisy, sparse observation stream of a run (seeded from its data)."""
        truth = self.truth(spec)
        seq = np.random.SeedSequence([spec.seed, int(stable_hash(spec.data_key()), 16)])
        rng = np.random.default_rng(seq)
        noise = rng.normal(0.0, 1.0, truth.observations.shape) * spec.noise
        stream: list[Observation | None] = []
        for k in range(1, spec.steps + 1):
            if spec.sparsity.observed(k):
                values = truth.observations[k - 1] + noise[k - 1]
                stream.append(Observation(values, spec.noise, k))
            else:
                stream.append(None)
        return stream

    def prior(self, model: ForwardModel, spec: RunSpec) -> Prior:
        """The run's prior, the same for every parameter."""
        return Prior.broadcast(spec.prior[0], spec.prior[1], model.parameters.p)

    @staticmethod
    def reference_key(spec: RunSpec) -> tuple[Any, ...]:
        """What E_ref depends on: runs with the same key share one fit."""
        return (spec.data_key(), spec.mesh, spec.reference, spec.prior)

    def known_reference(self, spec: RunSpec) -> FloatArray | None:
        """E_ref of ``spec``'s data if this session has it, else None."""
        return self._refs.get(self.reference_key(spec))

    def remember_reference(self, spec: RunSpec, value: FloatArray) -> None:
        """Seed E_ref of ``spec``'s data (computed by another worker)."""
        self._refs[self.reference_key(spec)] = np.asarray(value, dtype=float)

    def reference(self, spec: RunSpec) -> FloatArray:
        """E_ref: the reference estimator fitted on the run's own data."""
        key = self.reference_key(spec)
        if key not in self._refs:
            model = self.model(spec, spec.mesh, role="ref")
            p = model.parameters.p
            try:
                est = self.registry.estimator(spec.reference)()
                est.start(model, self.prior(model, spec))
                e = None
                for k, obs in enumerate(self.observations(spec), start=1):
                    e = est.update(k, obs)
                self._refs[key] = (
                    np.asarray(e.mean, dtype=float) if e else np.full(p, np.nan)
                )
            except Exception as exc:
                log.warning("reference fit failed for %s: %s", spec.mesh, exc)
                self._refs[key] = np.full(p, np.nan)
        return self._refs[key]

    def direct(self, spec: RunSpec, scenario: str | None = None) -> FloatArray:
        """Grid displacements (K, G, 3) of the model mesh run with E_true."""
        scenario = scenario or spec.scenario
        model = self.model(spec, spec.mesh, scenario, role="metrics")
        key = (id(model), scenario)
        if key not in self._direct:
            states = simulate_path(model, self.theta_true(model, spec))
            self._direct[key] = np.array([model.grid(s) for s in states])
        return self._direct[key]


def execute(
    spec: RunSpec, session: Session, started: Callable[[], None] | None = None
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Run one identification and score it.

    Never raises for a problem of the run itself: the status column says
    ``ok``, ``diverged``, ``failed`` or ``skipped`` and ``error`` says why.
    ``started`` is called when the estimator's own work (what ``timeout``
    limits) begins.

    Returns
    -------
    tuple
        The run's row (dict) and its trace rows (one dict per step).
    """
    row: dict[str, Any] = base_row(spec)
    traces: list[dict[str, Any]] = []
    t_start = time.perf_counter()
    try:
        with _noting_sigint():
            _run(spec, session, row, traces, started)
    except RunTimeout as exc:
        row.update(status="failed", error=str(exc))
    except Skipped as exc:
        row.update(status="skipped", error=str(exc))
    except (Diverged, ModelFailure) as exc:
        row.update(status="diverged", error=str(exc), failed_step=exc.step)
    except EstimatorError as exc:
        row.update(
            status="failed",
            error=str(exc),
            failed_step=np.nan if exc.step is None else exc.step,
            traceback=traceback.format_exc(),
        )
    except (KeyboardInterrupt, SystemExit):
        raise
    except (ConfigError, KeyError) as exc:
        row.update(status="failed", error=f"{type(exc).__name__}: {exc}")
    except Exception as exc:
        row.update(
            status="failed",
            error=f"{type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(),
        )
    row["wall_s"] = time.perf_counter() - t_start
    return row, traces


def base_row(spec: RunSpec) -> dict[str, Any]:
    """The columns every run row has, whatever its status."""
    return {
        "run_id": spec.run_id,
        "model": spec.model,
        "scenario": spec.scenario,
        "estimator": spec.estimator,
        "settings": json.dumps(dict(spec.settings), sort_keys=True),
        "mesh": spec.mesh,
        "model_nodes": np.nan,
        "truth_mesh": spec.truth_mesh,
        "truth_nodes": np.nan,
        "seed": spec.seed,
        "obs_every": spec.obs_every,
        "obs_points": spec.obs_points,
        "noise": spec.noise,
        "steps": spec.steps,
        "nu": spec.nu,
        "prior_mean": spec.prior[0],
        "prior_std": spec.prior[1],
        "status": "ok",
        "error": "",
        "failed_step": np.nan,
        "traceback": "",
    }


def _run(
    spec: RunSpec,
    session: Session,
    row: dict[str, Any],
    traces: list[dict[str, Any]],
    started: Callable[[], None] | None = None,
) -> None:
    model = session.model(spec, spec.mesh)
    metrics_model = session.model(spec, spec.mesh, role="metrics")
    names = model.parameters.names
    row["model_nodes"] = getattr(model, "n_nodes", np.nan)
    truth_model = session.model(spec, spec.truth_mesh, role="truth")
    row["truth_nodes"] = getattr(truth_model, "n_nodes", np.nan)
    theta_true = session.theta_true(model, spec)
    for n, t in zip(names, theta_true, strict=True):
        row[f"{n}_true"] = float(t)
        row[f"{n}_final"] = np.nan
        row[f"{n}_std_final"] = np.nan
        row[f"{n}_ref"] = np.nan

    cls = session.registry.estimator(spec.estimator)
    who = (
        f"estimator {spec.estimator!r} "
        f"(plugin {session.registry.estimators[spec.estimator].plugin!r})"
    )
    with _blame(who, "its constructor"):
        try:
            estimator = cls(**dict(spec.settings))
        except TypeError as exc:
            allowed = ", ".join(public_settings(cls))
            raise ConfigError(
                f"estimator {spec.estimator!r}: {exc}; allowed settings: {allowed}"
            ) from None
    truth = session.truth(spec)
    stream = session.observations(spec)
    direct = session.direct(spec)
    if started is not None:
        started()
    with _deadline(spec.timeout):  # the estimator's own work, not shared inputs
        t_start = time.perf_counter()
        with _blame(who, "start()"):
            estimator.start(model, session.prior(model, spec))
        est, means, stds = _estimate(
            spec, estimator, who, stream, truth, direct, traces,
            (model, metrics_model), t_start,
        )  # fmt: skip

    final_mean, final_std = means[-1], stds[-1]
    ref = session.reference(spec)
    for j, n in enumerate(names):
        row[f"{n}_final"] = float(final_mean[j])
        row[f"{n}_std_final"] = float(final_std[j])
        row[f"{n}_ref"] = float(ref[j])
    settle = metrics.settling_step(means, ref)
    row["settling_step"] = settle if settle is not None else np.nan
    used = metrics.observations_used(settle, spec.obs_every)
    row["settling_obs"] = used if used is not None else np.nan
    last = traces[-1]
    row["shape_error_final"] = last["shape_error"]
    row["shape_error_mean_final"] = last["shape_error_mean"]
    row["shape_error_direct"], row["shape_error_direct_mean"] = metrics.shape_error(
        direct[-1], truth.grid[-1]
    )
    row.update(_transfer(spec, session, final_mean))
    row["n_solves"] = est.cost.forward_solves
    row["newton_its"] = est.cost.newton_its
    row["wall_s_step"] = float(np.mean([t["wall_s"] for t in traces]))


def _estimate(
    spec: RunSpec,
    estimator: Any,
    who: str,
    stream: list[Observation | None],
    truth: Truth,
    direct: FloatArray,
    traces: list[dict[str, Any]],
    models: tuple[ForwardModel, ForwardModel],
    t_start: float,
) -> tuple[Any, FloatArray, FloatArray]:
    """Feed the stream to the estimator; score and trace every step.

    Returns the last :class:`~idbench.interfaces.Estimate`, the means and the
    stds (K, p).
    """
    model, metrics_model = models
    names = model.parameters.names
    shadow = metrics_model.reset()
    means = np.full((spec.steps, len(names)), np.nan)
    stds = np.full((spec.steps, len(names)), np.nan)
    solves_before = 0
    newton_before = 0
    for k, obs in enumerate(stream, start=1):
        t0 = time.perf_counter()
        with _blame(who, "update()", k):
            est = estimator.update(k, obs)
            mean, std = _checked(who, est, len(names), k)
        dt = time.perf_counter() - t0
        if not model.parameters.contains(mean):
            raise Diverged(f"estimate {mean} non-finite or outside bounds", step=k)
        means[k - 1], stds[k - 1] = mean, std
        if est.state is not None:
            state = est.state
        else:
            shadow = metrics_model.step(mean, k, shadow)
            state = shadow
        se_sum, se_mean = metrics.shape_error(
            metrics_model.grid(state), truth.grid[k - 1]
        )
        trace: dict[str, Any] = {
            "run_id": spec.run_id,
            "step": k,
            "load": k / spec.steps,
            "observed": obs is not None,
        }
        for j, n in enumerate(names):
            trace[n] = mean[j]
            trace[f"{n}_std"] = std[j]
        trace.update(
            shape_error=se_sum,
            shape_error_mean=se_mean,
            shape_error_direct=metrics.shape_error(direct[k - 1], truth.grid[k - 1])[0],
            n_solves=est.cost.forward_solves - solves_before,
            newton_its=est.cost.newton_its - newton_before,
            wall_s=dt,
            tip_x=truth.tip[k - 1, 0],
            tip_y=truth.tip[k - 1, 1],
            tip_z=truth.tip[k - 1, 2],
        )
        solves_before = est.cost.forward_solves
        newton_before = est.cost.newton_its
        traces.append(trace)
        if spec.timeout is not None and time.perf_counter() - t_start > spec.timeout:
            raise RunTimeout(f"run exceeded --timeout {spec.timeout:g} s at step {k}")

    return est, means, stds


def _transfer(spec: RunSpec, session: Session, theta: FloatArray) -> dict[str, Any]:
    """Shape error on the scenario's transfer path with the identified value."""
    target = session.registry.scenario(spec.scenario).transfer
    out: dict[str, Any] = {
        "transfer_scenario": target or "",
        "transfer_error": np.nan,
        "transfer_error_direct": np.nan,
    }
    if not target or target not in session.registry.scenarios:
        return out
    model = session.model(spec, spec.mesh, target, role="metrics")
    truth = session.truth(spec, target)
    states = simulate_path(model, theta)
    out["transfer_error"] = metrics.shape_error(model.grid(states[-1]), truth.grid[-1])[
        0
    ]
    direct = session.direct(spec, target)
    out["transfer_error_direct"] = metrics.shape_error(direct[-1], truth.grid[-1])[0]
    return out
