"""Conformance checks for plugin authors: call them from your own tests.

Each check raises :class:`AssertionError` with a message saying what is wrong.

>>> from idbench.registry.testing import check_model
>>> check_model(make_model(spec), theta)   # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from idbench.core.capabilities import (
    OPTIONAL,
    bounds_of,
    cell_data_of,
    field_model,
    given,
    load_figures_of,
    marker_points_of,
    member,
    n_nodes_of,
    present,
    probes_of,
    sensitivity_of,
    settings_member,
    target_points_of,
    volume_of,
)
from idbench.core.interfaces import (
    Cost,
    Estimate,
    FloatArray,
    ForwardModel,
    ParameterSpec,
    Prior,
)
from idbench.core.optional import BatchModel
from idbench.core.view import Absent, ModelView


def check_model(
    model: ForwardModel,
    theta: FloatArray,
    *,
    steps: int = 2,
    fd_rel_step: float = 1e-6,
    fd_rtol: float = 1e-4,
) -> None:
    """Check a forward model against the protocol.

    Checks the attributes and shapes, that ``reset`` gives a zero state, that
    two runs of the first ``steps`` load steps are bitwise equal (determinism),
    that ``cost()`` counts the step calls, and, if the model has
    ``sensitivity``, that it matches central finite differences of
    ``observe(step(...))`` to ``fd_rtol`` (relative to its largest entry).

    Parameters
    ----------
    model
        The model under test.
    theta
        A valid parameter vector, shape (p,).
    steps
        Load steps to run (<= ``model.n_steps``).
    fd_rel_step, fd_rtol
        Finite-difference relative step and tolerance.
    """
    theta = np.atleast_1d(np.asarray(theta, dtype=float))
    assert isinstance(model, ForwardModel), "model lacks ForwardModel methods"
    assert isinstance(model.parameters, ParameterSpec), (
        "parameters must be ParameterSpec"
    )
    assert theta.shape == (model.parameters.p,), "theta shape != (p,)"
    assert model.parameters.contains(theta), f"theta {theta} is outside the bounds"
    assert isinstance(model.n_steps, int) and model.n_steps >= 1, "n_steps must be >= 1"
    steps = min(steps, model.n_steps)
    u0 = model.reset()
    assert u0.ndim == 1 and np.all(u0 == 0), "reset() must give a flat zero state"
    c0 = model.cost()
    assert isinstance(c0, Cost), "cost() must return idbench.Cost"

    def run() -> list[FloatArray]:
        states, u = [], model.reset()
        for k in range(1, steps + 1):
            u = model.step(theta, k, u)
            states.append(u)
        return states

    first, second = run(), run()
    assert model.cost().forward_solves - c0.forward_solves == 2 * steps, (
        "cost().forward_solves must count step() calls"
    )
    for a, b in zip(first, second, strict=True):
        assert a.shape == u0.shape, "step() changed the state's shape"
        assert np.array_equal(a, b), "two identical runs differ: not deterministic"
    y = model.observe(first[-1])
    assert y.ndim == 1 and np.all(np.isfinite(y)), "observe() must be a finite (m,)"
    g = model.grid(first[-1])
    assert g.ndim == 2 and g.shape[1] == 3, "grid() must have shape (G, 3)"
    desc = model.describe()
    assert isinstance(desc, dict), "describe() must return a dict"
    check_optional_members(model, first[-1])
    sens = sensitivity_of(model)
    if sens is None:
        return
    k = steps
    prev = first[-2] if steps > 1 else model.reset()
    J = np.asarray(sens(theta, k, first[-1]))
    assert J.shape == (y.size, theta.size), "sensitivity() must have shape (m, p)"
    fd = np.empty_like(J)
    for j in range(theta.size):
        h = fd_rel_step * abs(theta[j])
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        yp = model.observe(model.step(tp, k, prev))
        ym = model.observe(model.step(tm, k, prev))
        fd[:, j] = (yp - ym) / (2 * h)
    scale = max(np.abs(fd).max(), np.finfo(float).tiny)
    err = np.abs(J - fd).max() / scale
    assert err <= fd_rtol, f"sensitivity differs from finite differences by {err:.2e}"


def check_optional_members(model: ForwardModel, state: FloatArray) -> None:
    """Check the optional members a model has.

    See :data:`idbench.core.capabilities.OPTIONAL`.

    Each one it has must make it an instance of the protocol that declares it
    (a method callable, ``mesh`` with ``displacement_field``);
    ``probes(state)`` must map names to finite scalars (they become traces
    columns, so they must not shadow the core's); ``n_nodes`` must be a whole
    number >= 1; ``bounds`` a finite (2, d) box, ``volume`` a number > 0;
    ``cell_data()`` arrays of one value per tetrahedron of ``mesh()``;
    ``parameters.default``, if set, must lie inside the bounds;
    ``surface(state)`` must give finite vertices (V, 3) and triangles (T, 3)
    indexing them; ``reaction(theta, k, state)`` a finite vector;
    ``targets(state)`` finite displacements (T, 3) (T = 0: none);
    ``marker_points`` finite positions (M, 3), one a marker of
    ``observe(state)`` (3M values), and ``target_points`` (T, 3), one a
    target of ``targets(state)``;
    ``load_figures()`` finite numbers >= 0 by name (each a column
    ``load_NAME_ratio``);

    ``max_markers`` a whole number >= 1; ``inputs`` member names.
    """
    usable = present(model)
    for name in given(model):
        assert name in usable, f"{name} must be a method (it is not callable)"
        protocol = OPTIONAL[name]
        lacks = [n for n, p in OPTIONAL.items() if p is protocol and n not in usable]
        assert isinstance(model, protocol) and not lacks, (
            f"model has {name} but is no idbench.{protocol.__name__}: it lacks "
            f"{', '.join(lacks) or 'a ForwardModel member'}"
        )
    targets = member(model, "targets")
    if targets is not None:
        moved = np.asarray(targets(state), dtype=float)
        assert moved.ndim == 2 and moved.shape[1] == 3, (
            "targets(state) must be displacements (T, 3) (T = 0: none)"
        )
        assert np.all(np.isfinite(moved)), "targets(state) must be finite"
    check_points(model, state)
    surface = member(model, "surface")
    if surface is not None:
        vertices, triangles = surface(state)
        vertices, triangles = np.asarray(vertices), np.asarray(triangles)
        assert vertices.ndim == 2 and vertices.shape[1] == 3, "surface vertices (V, 3)"
        assert np.all(np.isfinite(vertices)), "surface vertices must be finite"
        assert triangles.ndim == 2 and triangles.shape[1] == 3, "triangles (T, 3)"
        assert np.issubdtype(triangles.dtype, np.integer), "triangles are indices"
        assert triangles.min() >= 0 and triangles.max() < len(vertices), (
            "triangles index vertices that do not exist"
        )
    reaction = member(model, "reaction")
    theta = np.asarray(model.parameters.default or model.parameters.upper, float)
    if reaction is not None and model.parameters.contains(theta):
        force = np.asarray(reaction(theta, 1, state), dtype=float)
        assert force.ndim == 1 and np.all(np.isfinite(force)), (
            "reaction(theta, k, state) must be a finite vector"
        )
    probes = probes_of(model)
    if probes is not None:
        named = probes(state)
        assert isinstance(named, dict), "probes() must return a dict"
        reserved = {"run_id", "step", "load", "observed", "shape_error",
                    "shape_error_mean", "shape_error_direct", "n_solves", "tre_mm",
                    "newton_its", "wall_s", *model.parameters.names}  # fmt: skip
        for name, value in named.items():
            assert isinstance(name, str) and name, f"probe name {name!r}"
            assert name not in reserved, f"probe {name!r} shadows a traces column"
            assert np.ndim(value) == 0 and np.isfinite(value), (
                f"probe {name!r} must be a finite scalar, got {value!r}"
            )
    figures = load_figures_of(model)
    if figures is not None:
        named = figures()
        assert isinstance(named, dict), "load_figures() must return a dict"
        for name, value in named.items():
            assert isinstance(name, str) and name.isidentifier(), (
                f"load figure name {name!r} must be an identifier"
            )
            assert np.ndim(value) == 0 and np.isfinite(value) and value >= 0, (
                f"load figure {name!r} must be a finite number >= 0, got {value!r}"
            )
    n_nodes = n_nodes_of(model)
    if n_nodes is not None:
        assert isinstance(n_nodes, int | np.integer) and n_nodes >= 1, (
            f"n_nodes must be a whole number >= 1, got {n_nodes!r}"
        )
    limit = member(model, "max_markers")
    if limit is not None:
        assert isinstance(limit, int | np.integer) and limit >= 1, (
            f"max_markers must be a whole number >= 1, got {limit!r}"
        )
    inputs = member(model, "inputs")
    if inputs is not None:
        assert all(isinstance(n, str) for n in inputs), (
            f"inputs must name model members (strings), got {inputs!r}"
        )
    bounds = bounds_of(model)
    if bounds is not None:
        box = np.asarray(bounds, dtype=float)
        assert box.ndim == 2 and len(box) == 2 and np.isfinite(box).all(), (
            f"bounds must be a finite (2, d) array (lower, upper corner), got {box!r}"
        )
        assert np.all(box[0] <= box[1]), "bounds: the lower corner is above the upper"
    volume = volume_of(model)
    if volume is not None:
        assert np.ndim(volume) == 0 and np.isfinite(volume) and volume > 0, (
            f"volume must be a finite number > 0, got {volume!r}"
        )
    field, cells = field_model(model), cell_data_of(model)
    if field is not None:
        points, tets = (np.asarray(a) for a in field.mesh())
        assert points.ndim == 2 and points.shape[1] == 3, "mesh() points must be (N, 3)"
        assert tets.ndim == 2 and tets.shape[1] == 4, "mesh() cells must be (T, 4)"
        u = np.asarray(field.displacement_field(state))
        assert u.shape == points.shape, "displacement_field() must be (N, 3)"
        for name, values in (cells() if cells is not None else {}).items():
            assert np.shape(values) == (len(tets),), (
                f"cell_data() {name!r} must have one value per tetrahedron"
            )
    default = model.parameters.default
    if default is not None:
        assert model.parameters.contains(np.asarray(default, dtype=float)), (
            f"parameters.default {default} lies outside the bounds"
        )


def check_points(model: ForwardModel, state: FloatArray) -> None:
    """Check ``marker_points`` and ``target_points``.

    See :class:`~idbench.core.optional.PlacedPointsModel`: finite (M, 3) and
    (T, 3), M markers in ``observe(state)`` and T targets in
    ``targets(state)`` (T = 0 without ``targets``).
    """
    markers, targets = marker_points_of(model), target_points_of(model)
    if markers is None or targets is None:
        return
    for name in ("marker_points", "target_points"):
        points = np.asarray(member(model, name), dtype=float)
        assert points.ndim == 2 and points.shape[1] == 3, f"{name} must be (n, 3)"
        assert np.all(np.isfinite(points)), f"{name} must be finite"
    m = np.asarray(model.observe(state)).size
    assert markers.size == m, (
        f"marker_points has {len(markers)} points, observe(state) {m} values: "
        "one point per three values"
    )
    moved = member(model, "targets")
    t = 0 if moved is None else len(np.asarray(moved(state)).reshape(-1, 3))
    assert len(targets) == t, (
        f"target_points has {len(targets)} points, targets(state) {t}"
    )


def check_model_settings(cls: type) -> None:
    """Check a model's settings class.

    It must be a dataclass with a default for every field, whose
    ``EXECUTION`` (if any) names some of its fields.
    """
    assert dataclasses.is_dataclass(cls), "model settings must be a dataclass"
    names = set()
    for f in dataclasses.fields(cls):
        has = f.default is not dataclasses.MISSING
        has = has or f.default_factory is not dataclasses.MISSING
        assert has, f"setting {f.name!r} needs a default"
        names.add(f.name)
    unknown = set(settings_member(cls, "EXECUTION")) - names
    assert not unknown, f"EXECUTION names settings that are not fields: {unknown}"
    cls()


def check_estimator(
    cls: type, model: ForwardModel, prior: Prior, **settings: Any
) -> None:
    """Check an estimator class against the protocol on ``model``.

    It must be a dataclass whose fields all have defaults, and one run over the
    model's steps (no observations) must give finite estimates of shape (p,)
    with cumulative, non-decreasing cost.
    """
    assert dataclasses.is_dataclass(cls), "an estimator class must be a dataclass"
    for f in dataclasses.fields(cls):
        has = f.default is not dataclasses.MISSING
        has = has or f.default_factory is not dataclasses.MISSING
        assert has, f"setting {f.name!r} needs a default"
    est: Any = cls(**settings)
    est.start(model, prior)
    solves = 0
    for k in range(1, model.n_steps + 1):
        e = est.update(k, None)
        assert isinstance(e, Estimate), "update() must return idbench.Estimate"
        assert np.shape(e.mean) == (model.parameters.p,), "mean must have shape (p,)"
        assert np.all(np.isfinite(e.mean)), f"non-finite estimate at step {k}"
        assert e.cost.forward_solves >= solves, "cost must be cumulative"
        solves = e.cost.forward_solves


def check_batch_model(
    model: BatchModel,
    thetas: FloatArray,
    *,
    steps: int = 2,
    rtol: float = 1e-6,
) -> None:
    """Check that ``step_many`` equals r calls of ``step`` (see :class:`BatchModel`).

    Along the first ``steps`` load steps of each row's own path (solved with
    ``step``), ``step_many(thetas, k, states)`` from the states of step k - 1
    must agree with ``step`` to ``rtol`` relative to the largest displacement
    (the results are equal to the Newton tolerance, not bitwise), also with
    the rows in reverse order and one row at a time; it must not modify its
    inputs, and ``cost().forward_solves`` must grow by r a call.

    Parameters
    ----------
    model
        The model under test (with ``step_many``).
    thetas
        Valid parameter vectors, shape (r, p), r >= 2, preferably distinct.
    steps
        Load steps to run (<= ``model.n_steps``).
    rtol
        Tolerance relative to the largest entry of the ``step`` results.
    """
    assert isinstance(model, BatchModel), "model lacks step_many (BatchModel)"
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    r, p = thetas.shape
    assert p == model.parameters.p, "thetas must have shape (r, p)"
    assert r >= 2, "give at least two rows"
    steps = min(steps, model.n_steps)
    paths = [[model.reset()] for _ in range(r)]
    for i in range(r):
        for k in range(1, steps + 1):
            paths[i].append(model.step(thetas[i], k, paths[i][-1]))
    for k in range(1, steps + 1):
        before = np.stack([paths[i][k - 1] for i in range(r)])
        ref = np.stack([paths[i][k] for i in range(r)])
        scale = max(float(np.abs(ref).max()), np.finfo(float).tiny)
        X, th = before.copy(), thetas.copy()
        c0 = model.cost()
        got = np.asarray(model.step_many(th, k, X))
        solves = model.cost().forward_solves - c0.forward_solves
        assert solves == r, f"step_many counted {solves} forward solves, not r = {r}"
        assert np.array_equal(X, before) and np.array_equal(th, thetas), (
            "step_many modified its inputs"
        )
        assert got.shape == ref.shape, "step_many must return shape (r, n)"
        err = np.abs(got - ref).max() / scale
        assert err <= rtol, f"step_many differs from step by {err:.2e} at step {k}"
        rev = np.asarray(model.step_many(th[::-1], k, X[::-1]))[::-1]
        err = np.abs(rev - ref).max() / scale
        assert err <= rtol, f"step_many depends on the row order ({err:.2e})"
        one = np.stack(
            [model.step_many(th[i : i + 1], k, X[i : i + 1])[0] for i in range(r)]
        )
        err = np.abs(one - ref).max() / scale
        assert err <= rtol, f"step_many of single rows differs by {err:.2e}"


class WithoutStepMany(ModelView):
    """A model seen without its ``step_many``: estimators loop over ``step``.

    Every other member is the wrapped model's
    (:class:`~idbench.core.view.ModelView`). Run an estimator on a
    :class:`BatchModel` and on ``WithoutStepMany(model)`` to check (or time)
    that batching changes nothing but the speed.

    Parameters
    ----------
    model
        The forward model to wrap.
    """

    step_many = Absent()
