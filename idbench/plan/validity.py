"""Whether a run's result can mean anything: refusals up front, flags per run.

What the input decides is refused before the sweep (:func:`check_prior`,
:func:`check_truth_mesh`), with one :class:`~idbench.plan.config.ConfigError` line;
what only the run shows is flagged in its row's ``warning`` column
(:func:`run_warning`), and the summary lists the flagged rows.

The mesh checks use optional model members, when both models have them:
``n_nodes`` (int), ``bounds`` (array (2, d): the lower and upper corner of
the undeformed body's bounding box) and ``volume`` (float, the body's
volume). A model without them is not checked.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from idbench.core.capabilities import bounds_of, n_nodes_of, reduces_of, volume_of
from idbench.core.interfaces import FloatArray, Observation, ParameterSpec
from idbench.plan.config import ConfigError
from idbench.truth.simulate import Truth

BOX_TOLERANCE = 0.1
"""How far a model mesh's bounding box may lie from the truth's: a share of
the truth's extent along each axis (coarse meshes of curved bodies are a
little smaller)."""

VOLUME_TOLERANCE = 0.25
"""How far a model mesh's volume may lie from the truth's, relative."""

BOUND_TOLERANCE = 1e-3
"""An estimate or reference within this share of a parameter bound is "at" it."""


def check_prior(
    parameters: ParameterSpec, prior: tuple[float, float], model: str
) -> None:
    """Refuse a prior mean outside the parameter bounds (every run would fail).

    ``prior`` is every parameter's but those with a prior of their own (the
    model's :attr:`~idbench.ParameterSpec.priors`, checked too).

    Raises
    ------
    ConfigError
        Naming the prior mean and the bounds.
    """
    mean = np.asarray(parameters.prior(float(prior[0]), float(prior[1])).mean)
    if not parameters.contains(mean):
        ranges = ", ".join(
            f"{n}: {lo:g}..{hi:g}"
            for n, lo, hi in zip(
                parameters.names, parameters.lower, parameters.upper, strict=True
            )
        )
        raise ConfigError(
            f"prior mean {prior[0]:g} lies outside the parameter bounds of model "
            f"{model!r} ({ranges}); give --prior MEAN,STD with MEAN inside them"
        )


def check_truth_mesh(
    truth: Any, truth_mesh: str, model: Any, mesh: str, role: str = "truth"
) -> None:
    """Refuse a truth that is not finer than ``mesh`` or is another body.

    The truth must have more nodes than every model mesh (the same mesh spec,
    an "inverse crime" check, is allowed; a reduced-order model, as many as
    the mesh it reduces), and, where both models expose
    ``bounds`` and ``volume``, the same bounding box (within
    :data:`BOX_TOLERANCE` of its extent) and volume (within
    :data:`VOLUME_TOLERANCE`). With ``role = "calibration"`` the same
    checks for a calibration mesh, whose same mesh spec is refused too (its
    discrepancy would be zero).

    Raises
    ------
    ConfigError
        Naming both meshes and what differs.
    """
    if mesh == truth_mesh and role == "truth":
        return
    pair = f"{role} mesh {truth_mesh!r} and model mesh {mesh!r}"
    if mesh == truth_mesh:
        raise ConfigError(
            f"{role} mesh {truth_mesh!r} is model mesh {mesh!r} itself; the "
            f"{role} mesh must be a finer mesh of the same body"
        )
    n_truth, n_model = n_nodes_of(truth), n_nodes_of(model)
    equal_ok = reduces_of(model) is not None  # it approximates that mesh
    if n_truth is not None and n_model is not None and (
        n_truth < n_model or (n_truth == n_model and not equal_ok)
    ):
        raise ConfigError(
            f"{role} mesh {truth_mesh!r} ({n_truth} nodes) is not finer than model "
            f"mesh {mesh!r} ({n_model} nodes); the {role} mesh must have more nodes "
            "than every model mesh"
        )
    box_t, box_m = _bounds(truth), _bounds(model)
    if box_t is not None and box_m is not None and box_t.shape == box_m.shape:
        size = np.maximum(box_t[1] - box_t[0], np.finfo(float).tiny)
        off = np.max(np.abs(box_m - box_t), axis=0) / size
        axis = int(np.argmax(off))
        if off[axis] > BOX_TOLERANCE:
            raise ConfigError(
                f"{pair} are not the same body: their bounding boxes differ by "
                f"{off[axis]:.0%} of the {role}'s extent along axis {axis} ({role} "
                f"{_box(box_t)}, model {_box(box_m)}; allowed {BOX_TOLERANCE:.0%})"
            )
    v_t, v_m = volume_of(truth), volume_of(model)
    if v_t is not None and v_m is not None and float(v_t) > 0:
        rel = abs(float(v_m) / float(v_t) - 1.0)
        if rel > VOLUME_TOLERANCE:
            raise ConfigError(
                f"{pair} are not the same body: volumes {float(v_t):.4g} and "
                f"{float(v_m):.4g} differ by {rel:.0%} (allowed "
                f"{VOLUME_TOLERANCE:.0%})"
            )


def _bounds(model: Any) -> FloatArray | None:
    value = bounds_of(model)
    if value is None:
        return None
    box = np.asarray(value, dtype=float)
    return box if box.ndim == 2 and len(box) == 2 and np.isfinite(box).all() else None


def _box(box: FloatArray) -> str:
    return " x ".join(f"[{lo:.4g}, {hi:.4g}]" for lo, hi in box.T)


def run_warning(
    parameters: ParameterSpec,
    stream: list[Observation | None],
    truth: Truth,
    noise: float,
    final: FloatArray,
    ref: FloatArray,
) -> str:
    """Why an ``ok`` run's result may mean nothing (empty: no reason found).

    Flags: no observation in the run (the estimate is the prior); the
    observation's signal (the largest noise-free marker displacement at an
    observed step) below the noise sigma; the final estimate or the
    reference fit at (within :data:`BOUND_TOLERANCE` of) a parameter bound,
    where a fit pinned by the bound is no effective value.
    """
    out = []
    observed = [k for k, obs in enumerate(stream) if obs is not None]
    if not observed:
        out.append("no observation in the run: the estimate is the prior")
    else:
        signal = float(np.max(np.abs(truth.observations[observed])))
        if signal < noise:
            out.append(
                f"signal below the noise: the largest marker displacement "
                f"observed is {signal:.3g}, the noise sigma {noise:.3g}"
            )
    for what, value in (("final estimate", final), ("reference fit", ref)):
        at = _at_bound(parameters, value)
        if at:
            out.append(f"{what} at the parameter bound ({at})")
    return "; ".join(out)


def _at_bound(parameters: ParameterSpec, value: FloatArray) -> str:
    """The parameters of ``value`` at a bound, as ``name = value, lower bound``."""
    hits = []
    for n, v, lo, hi in zip(
        parameters.names, value, parameters.lower, parameters.upper, strict=True
    ):
        for bound, side in ((lo, "lower"), (hi, "upper")):
            scale = abs(bound) if bound != 0 else abs(hi - lo)
            near = abs(v - bound) <= BOUND_TOLERANCE * scale
            if np.isfinite([v, scale]).all() and near:
                hits.append(f"{n} = {v:.6g}, {side} bound {bound:g}")
    return ", ".join(hits)
