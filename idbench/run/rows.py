"""The rows a run writes: its runs-table row and one traces-table row per step.

Column names follow the model's parameter names (``E_final`` for a parameter
``E``, ``k_final`` for ``k``) and its probes (``tip_x`` ...); no column exists
that only one model has unless that model reports it. Each metric is defined
once, in :mod:`idbench.score.metrics`.
"""

from __future__ import annotations

import json
import logging
from typing import Any

import numpy as np

from idbench.core.capabilities import load_figures_of, parameter_field_of
from idbench.core.interfaces import Estimate, FloatArray, ForwardModel, Observation
from idbench.plan.runspec import RunSpec
from idbench.run.session import Session
from idbench.score import maps, metrics
from idbench.truth.simulate import Truth, simulate_path

log = logging.getLogger(__name__)


def base_row(spec: RunSpec) -> dict[str, Any]:
    """The columns every run row has, whatever its status."""
    s = spec.setup
    return {
        "run_id": spec.run_id,
        "model": s.model,
        "model_settings": json.dumps(dict(s.model_settings), sort_keys=True),
        "scenario": spec.scenario,
        "estimator": spec.estimator,
        "settings": json.dumps(dict(spec.settings), sort_keys=True),
        "mesh": spec.mesh,
        "model_nodes": np.nan,
        "truth_mesh": s.truth_mesh,
        "truth_nodes": np.nan,
        "seed": spec.seed,
        "obs_every": spec.obs_every,
        "obs_points": spec.obs_points,
        "noise": spec.noise,
        "observe": spec.observe,
        "steps": s.steps,
        "prior_mean": s.prior[0],
        "prior_std": s.prior[1],
        **{f"{n}_true": float(v) for n, v in s.true},
        "status": "ok",
        "error": "",
        "failed_step": np.nan,
        "traceback": "",
        "warning": "",
        "observe_kind": spec.observe_kind(),
    }


def load_columns(model: ForwardModel, truth: Truth) -> dict[str, float]:
    """The run's load against the truth's: ``load_NAME_ratio`` per figure.

    Each figure of ``model.load_figures()``
    (:class:`~idbench.core.optional.LoadFiguresModel`) over the truth
    model's (``truth.loads``); NaN where the truth's is missing, zero or not
    finite (a recording's truth has none). No columns for a model without
    load figures. They depend on the scenario and the mesh only, so a run
    that fails still has them.
    """
    figures = load_figures_of(model)
    if figures is None:
        return {}
    out: dict[str, float] = {}
    for name, value in figures().items():
        ref = truth.loads.get(name, np.nan)
        usable = np.isfinite(ref) and ref != 0
        out[f"load_{name}_ratio"] = float(value) / ref if usable else np.nan
    return out


def step_row(
    spec: RunSpec,
    k: int,
    observation: Observation | None,
    estimate: Estimate,
    mean: FloatArray,
    std: FloatArray,
    grid: FloatArray,
    truth: Truth,
    direct: FloatArray,
    innovation: Any = None,
) -> dict[str, Any]:
    """The traces row of step ``k`` (cost columns are added by the caller).

    ``grid`` is the model's shape-error point displacements at this step (its
    own state, or a forward solve with the current estimate). ``innovation``
    is the estimator's (nu, S) of this step if it exposes one (see
    :class:`~idbench.core.interfaces.Estimate`); ``nis`` is NaN without it and on
    unobserved steps.
    """
    se_sum, se_mean = metrics.shape_error(grid, truth.grid[k - 1])
    row: dict[str, Any] = {
        "run_id": spec.run_id,
        "step": k,
        "load": k / spec.setup.steps,
        "observed": observation is not None,
    }
    for j, n in enumerate(spec.setup.names):
        row[n] = mean[j]
        row[f"{n}_std"] = std[j]
    row["nis"] = _nis(innovation) if observation is not None else np.nan
    row["nis_dof"] = _size(innovation) if np.isfinite(row["nis"]) else 0
    row.update(
        shape_error=se_sum,
        shape_error_mean=se_mean,
        shape_error_direct=metrics.shape_error(direct[k - 1], truth.grid[k - 1])[0],
    )
    for name, values in truth.probes.items():
        row[name] = values[k - 1]
    return row


def _nis(innovation: Any) -> float:
    """NIS of an estimator's innovation pair; NaN if none or malformed."""
    if innovation is None:
        return np.nan
    try:
        residual, cov = innovation
        return metrics.nis(residual, cov)
    except (TypeError, ValueError) as exc:
        log.warning("innovation is not (residual, covariance): %s", exc)
        return np.nan


def _size(innovation: Any) -> int:
    """The number of observed values an innovation (nu, S) has (its NIS's dof)."""
    return int(np.size(innovation[0]))


def nis_columns(traces: list[dict[str, Any]]) -> dict[str, float]:
    """The run's NIS summed over its observed steps and its degrees of freedom.

    ``nis`` (the sum of the traces' finite ``nis``) and ``nis_dof`` (the sum
    of their ``nis_dof``, the observed values); both NaN where no step has a
    NIS (the estimator gives no innovation). See
    :func:`idbench.score.metrics.inconsistency`.
    """
    nis = np.array([t["nis"] for t in traces], dtype=float)
    seen = np.isfinite(nis)
    if not seen.any():
        return {"nis": np.nan, "nis_dof": np.nan}
    dof = np.array([t["nis_dof"] for t in traces], dtype=float)
    return {"nis": float(nis[seen].sum()), "nis_dof": float(dof[seen].sum())}


def uncertainty_columns(
    spec: RunSpec, mean: FloatArray, std: FloatArray, true: FloatArray, ref: FloatArray
) -> dict[str, Any]:
    """Coverage, NEES and CRPS of the final Gaussian estimate N(mean, std^2).

    Per parameter ``x``: ``x_cover68_true``, ``x_cover95_true`` (1/0: the
    central 68%/95% interval holds the true value; NaN without a std),
    ``x_cover68_ref``, ``x_cover95_ref`` (the same for the reference value),
    ``x_crps`` (CRPS against the true value); ``nees_true`` and ``nees_ref``;
    ``x_relerr_true`` and ``x_relerr_ref``, the relative errors mean / value - 1
    against the true (the tissue's) and the reference (the mesh's effective)
    value: the two questions an estimate may answer.
    """
    out: dict[str, Any] = {}
    cover = {
        (level, what): metrics.coverage(mean, std, value, level / 100)
        for level in (68, 95)
        for what, value in (("true", true), ("ref", ref))
    }
    crps = metrics.crps_gaussian(mean, std, true)
    for j, n in enumerate(spec.setup.names):
        for (level, what), c in cover.items():
            out[f"{n}_cover{level}_{what}"] = float(c[j])
        out[f"{n}_crps"] = float(crps[j])
        with np.errstate(divide="ignore", invalid="ignore"):
            out[f"{n}_relerr_true"] = float(mean[j] / true[j] - 1)
            out[f"{n}_relerr_ref"] = float(mean[j] / ref[j] - 1)
    out["nees_true"] = metrics.nees(mean, std, true)
    out["nees_ref"] = metrics.nees(mean, std, ref)
    return out


def posterior_columns(
    spec: RunSpec, session: Session, mean: FloatArray, std: FloatArray
) -> dict[str, Any]:
    """The reference posterior's mean and std and the distance to it.

    Only when the run asks for a posterior (``spec.posterior``): per parameter
    ``x_post_mean``, ``x_post_std``; ``posterior_converged``; ``w1_posterior``
    (Wasserstein-1 between N(mean, std^2) and the posterior, p = 1 only). A
    posterior that did not converge keeps its moments but no distance (NaN).
    """
    if spec.posterior is None:
        return {}
    post = session.posterior(spec)
    out = empty_posterior_columns(spec)
    if post is None:
        return out
    for j, n in enumerate(spec.setup.names):
        out[f"{n}_post_mean"] = float(post.mean[j])
        out[f"{n}_post_std"] = float(post.std[j])
    out["posterior_converged"] = bool(post.converged)
    if post.converged and post.grid is not None and post.density is not None:
        out["w1_posterior"] = metrics.wasserstein_to_grid(
            float(mean[0]), float(std[0]), post.grid, post.density
        )
    return out


def empty_posterior_columns(spec: RunSpec) -> dict[str, Any]:
    """NaN posterior columns (none if the run asks for no posterior)."""
    if spec.posterior is None:
        return {}
    out: dict[str, Any] = {}
    for n in spec.setup.names:
        out[f"{n}_post_mean"] = np.nan
        out[f"{n}_post_std"] = np.nan
    out["posterior_converged"] = False
    out["w1_posterior"] = np.nan
    return out


def final_columns(
    spec: RunSpec,
    session: Session,
    means: FloatArray,
    stds: FloatArray,
    traces: list[dict[str, Any]],
    estimate: Estimate,
) -> dict[str, Any]:
    """The run row's results: estimates, reference, settling, errors, cost."""
    ref = session.reference(spec)
    out: dict[str, Any] = {}
    for j, n in enumerate(spec.setup.names):
        out[f"{n}_final"] = float(means[-1, j])
        out[f"{n}_std_final"] = float(stds[-1, j])
        out[f"{n}_ref"] = float(ref[j])
    settle = metrics.settling_step(means, ref)
    true = session.theta_true(spec)
    out.update(uncertainty_columns(spec, means[-1], stds[-1], true, ref))
    out.update(posterior_columns(spec, session, means[-1], stds[-1]))
    out["settling_step"] = settle if settle is not None else np.nan
    used = metrics.observations_used(settle, spec.obs_every)
    out["settling_obs"] = used if used is not None else np.nan
    truth, direct = session.truth(spec), session.direct(spec)
    out["shape_error_final"] = traces[-1]["shape_error"]
    out["shape_error_mean_final"] = traces[-1]["shape_error_mean"]
    out["shape_error_direct"], out["shape_error_direct_mean"] = metrics.shape_error(
        direct[-1], truth.grid[-1]
    )
    out.update(transfer(spec, session, means[-1]))
    field = parameter_field_of(session.model(spec, spec.mesh))
    if field is not None:  # a map: its own metrics (idbench.score.maps)
        out.update(maps.map_columns(field, means[-1], stds[-1], true))
    out.update(nis_columns(traces))
    out["n_solves"] = estimate.cost.forward_solves
    out["newton_its"] = estimate.cost.newton_its
    out["wall_s_step"] = float(np.mean([t["wall_s"] for t in traces]))
    return out


def empty_parameter_columns(spec: RunSpec) -> dict[str, Any]:
    """NaN estimate columns, so a failed run's row has them too."""
    out: dict[str, Any] = {}
    for n in spec.setup.names:
        out[f"{n}_final"] = np.nan
        out[f"{n}_std_final"] = np.nan
        out[f"{n}_ref"] = np.nan
        for level in (68, 95):
            out[f"{n}_cover{level}_true"] = np.nan
            out[f"{n}_cover{level}_ref"] = np.nan
        out[f"{n}_crps"] = np.nan
        out[f"{n}_relerr_true"] = np.nan
        out[f"{n}_relerr_ref"] = np.nan
    out["nees_true"] = np.nan
    out["nees_ref"] = np.nan
    out.update(empty_posterior_columns(spec))
    return out


def transfer(spec: RunSpec, session: Session, theta: FloatArray) -> dict[str, Any]:
    """Shape error on the scenario's transfer path with the identified value."""
    target = session.scenario(spec, spec.scenario).transfer
    out: dict[str, Any] = {
        "transfer_scenario": target or "",
        "transfer_error": np.nan,
        "transfer_error_direct": np.nan,
    }
    if not target or spec.setup.data:  # a recording has no transfer path
        return out
    model = session.model(spec, spec.mesh, target, role="metrics")
    truth = session.truth(spec, target)
    states = simulate_path(model, theta)
    out["transfer_error"] = metrics.shape_error(
        model.grid(states[-1]), truth.grid[-1]
    )[0]
    direct = session.direct(spec, target)
    out["transfer_error_direct"] = metrics.shape_error(direct[-1], truth.grid[-1])[0]
    return out
