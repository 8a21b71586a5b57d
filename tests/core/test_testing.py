"""idbench.registry.testing's checks: pass on good plugins, catch bad ones."""

from __future__ import annotations

import numpy as np
import pytest
from support.toymodels import LinearToy, SensitiveLinearToy

import idbench
from idbench.registry.testing import check_batch_model, check_estimator, check_model


@pytest.fixture(scope="module")
def registry():
    return idbench.build_registry(idbench.get_plugin_manager(autoload=False))


def test_beam_model_conforms(registry):
    spec = idbench.ModelSpec(
        mesh="6x2x2", scenario=registry.scenario("bend-y"), n_steps=4, markers=2
    )
    check_model(registry.model("svk-beam")(spec), np.array([5000.0]))


def test_wrong_sensitivity_is_caught():
    model = SensitiveLinearToy(p=1)
    check_model(model, np.array([2.0]))  # the exact one passes
    good = model.sensitivity
    model.sensitivity = lambda theta, k, state: 1.1 * good(theta, k, state)
    with pytest.raises(AssertionError, match="finite differences"):
        check_model(model, np.array([2.0]))


def test_nondeterministic_model_is_caught():
    model = LinearToy(p=1)
    rng = np.random.default_rng(0)
    step = model.step
    model.step = lambda theta, k, state, substeps=1: (
        step(theta, k, state) + rng.normal(scale=1e-12, size=state.shape)
    )
    with pytest.raises(AssertionError, match="deterministic"):
        check_model(model, np.array([2.0]))


@pytest.mark.parametrize("name", ["ro-ukf", "rls", "lms", "batch-ls"])
def test_builtin_estimators_conform(registry, name):
    check_estimator(
        registry.estimator(name),
        LinearToy(p=2),
        idbench.Prior((1.0, 2.0), (1.0, 1.0)),
        transform="identity",
    )


def test_beam_settings_and_probes_conform(registry):
    from idbench.registry.testing import check_model_settings, check_optional_members

    check_model_settings(registry.models["svk-beam"].settings)
    spec = idbench.ModelSpec(mesh="4x1x1", scenario=registry.scenario("bend-y"),
                             n_steps=2)  # fmt: skip
    model = registry.model("svk-beam")(spec)
    state = model.step(np.array([5000.0]), 1, model.reset())
    check_optional_members(model, state)
    assert set(model.probes(state)) == {"tip_x", "tip_y", "tip_z"}


def test_bad_probes_and_sizes_are_caught():
    from idbench.registry.testing import check_optional_members

    model = LinearToy(p=1)
    state = model.step(np.array([2.0]), 1, model.reset())
    model.probes = lambda s: {"shape_error": 1.0}
    with pytest.raises(AssertionError, match="shadows"):
        check_optional_members(model, state)
    model.probes = lambda s: {"end": np.array([1.0, 2.0])}
    with pytest.raises(AssertionError, match="finite scalar"):
        check_optional_members(model, state)
    del model.probes
    model.n_nodes = 0
    with pytest.raises(AssertionError, match="n_nodes"):
        check_optional_members(model, state)


def test_wrong_step_many_is_caught():
    model = LinearToy(p=1)

    def step_many(thetas, k, states):
        model._solves += len(thetas)
        return np.stack([(k / model.n_steps) * model.A @ t for t in thetas])

    model.step_many = step_many
    check_batch_model(model, np.array([[1.0], [2.0]]))  # the exact one passes
    model.step_many = lambda thetas, k, states: 1.001 * step_many(thetas, k, states)
    with pytest.raises(AssertionError, match="differs from step"):
        check_batch_model(model, np.array([[1.0], [2.0]]))


def test_step_many_that_miscounts_is_caught():
    model = LinearToy(p=1)
    model.step_many = lambda thetas, k, states: np.stack(
        [(k / model.n_steps) * model.A @ t for t in thetas]
    )
    with pytest.raises(AssertionError, match="forward solves"):
        check_batch_model(model, np.array([[1.0], [2.0]]))


def test_execution_must_name_fields():
    import dataclasses
    from typing import ClassVar

    from idbench.registry.testing import check_model_settings

    @dataclasses.dataclass
    class Good:
        workers: int = 1
        EXECUTION: ClassVar[tuple[str, ...]] = ("workers",)

    @dataclasses.dataclass
    class Bad:
        workers: int = 1
        EXECUTION: ClassVar[tuple[str, ...]] = ("threads",)

    check_model_settings(Good)
    with pytest.raises(AssertionError, match="threads"):
        check_model_settings(Bad)


def test_optional_members_are_declared_and_looked_up_in_one_place():
    """Every optional member has its protocol; only capabilities.py looks them up."""
    import ast
    from pathlib import Path

    from idbench.core import capabilities

    for name, protocol in capabilities.OPTIONAL.items():
        assert getattr(idbench, protocol.__name__) is protocol  # public API
        assert name in dir(protocol), f"{protocol.__name__} does not declare {name}"
    core = Path(idbench.__file__).parent
    found = []
    for path in core.rglob("*.py"):
        if path.name == "capabilities.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id in ("getattr", "hasattr")
                and len(node.args) >= 2
                and isinstance(node.args[1], ast.Constant)
                and node.args[1].value in capabilities.OPTIONAL
            ):
                found.append(f"{path.relative_to(core)}:{node.lineno}")
    assert not found, f"optional model members looked up by name: {found}"


def test_capabilities_give_each_member_or_none():
    from idbench.core import capabilities as cap

    model = SensitiveLinearToy(p=1)
    assert cap.probes_of(model) is None and cap.n_nodes_of(model) is None
    assert cap.sensitivity_of(model) is not None and cap.step_many_of(model) is None
    assert cap.field_model(model) is None and set(cap.present(model)) == {"sensitivity"}
    model.probes = lambda s: {"end": 1.0}
    model.n_nodes, model.volume = 7, 2.0
    assert cap.probes_of(model) is model.probes and cap.n_nodes_of(model) == 7
    assert cap.volume_of(model) == 2.0 and cap.bounds_of(model) is None
    model.mesh = lambda: (np.zeros((4, 3)), np.array([[0, 1, 2, 3]]))
    assert cap.field_model(model) is None  # no displacement_field yet
    model.displacement_field = lambda state: np.zeros((4, 3))
    assert cap.field_model(model) is model
    model.cell_data = "not a method"
    assert cap.cell_data_of(model) is None and "cell_data" in cap.given(model)
    with pytest.raises(KeyError, match="no optional model member"):
        cap.member(model, "tip")


def test_check_optional_members_checks_each_declared_member():
    from idbench.registry.testing import check_optional_members

    model = LinearToy(p=1)
    state = model.step(np.array([2.0]), 1, model.reset())
    model.probes = {"end": 1.0}  # a value, not a method
    with pytest.raises(AssertionError, match="probes must be a method"):
        check_optional_members(model, state)
    del model.probes
    model.mesh = lambda: (np.zeros((4, 3)), np.array([[0, 1, 2, 3]]))
    with pytest.raises(AssertionError, match=r"FieldModel: it lacks displacement_f"):
        check_optional_members(model, state)
    model.displacement_field = lambda state: np.zeros((4, 3))
    check_optional_members(model, state)
    model.cell_data = lambda: {"region": np.zeros(3)}
    with pytest.raises(AssertionError, match="one value per tetrahedron"):
        check_optional_members(model, state)


def test_the_beam_has_its_members_declared(registry):
    from idbench.core import capabilities

    spec = idbench.ModelSpec(mesh="4x1x1", scenario=registry.scenario("bend-y"),
                             n_steps=2)  # fmt: skip
    model = registry.model("svk-beam")(spec)
    has = set(capabilities.present(model))
    assert {"n_nodes", "probes", "sensitivity", "mesh", "displacement_field"} <= has
    for name in has:
        assert isinstance(model, capabilities.OPTIONAL[name]), name


def test_a_view_passes_exactly_the_wrapped_models_members():
    """Wrappers delegate the protocol and the declared optional members only."""
    from idbench.core import capabilities as cap
    from idbench.core.view import Delegated, ModelView
    from idbench.registry.testing import WithoutStepMany

    declared = {n for n, v in vars(ModelView).items() if isinstance(v, Delegated)}
    assert declared == set(cap.OPTIONAL)
    model = SensitiveLinearToy(p=1)
    model.step_many = lambda thetas, k, states: states
    model.volume = 2.0
    view = ModelView(model)
    assert isinstance(view, idbench.ForwardModel)
    assert set(cap.present(view)) == set(cap.present(model))
    assert cap.volume_of(view) == 2.0 and cap.bounds_of(view) is None
    assert not hasattr(view, "bounds") and not hasattr(view, "A")  # no proxy
    looped = WithoutStepMany(model)
    assert cap.step_many_of(looped) is None and not hasattr(looped, "step_many")
    assert set(cap.present(looped)) == set(cap.present(model)) - {"step_many"}
    u = looped.step(np.array([2.0]), 1, looped.reset())
    np.testing.assert_array_equal(looped.observe(u), model.observe(u))
    assert looped.describe() == model.describe() and looped.n_steps == model.n_steps
    check_model(looped, np.array([2.0]))


def test_placed_points_are_one_a_marker_and_one_a_target(registry):
    from idbench.core import capabilities as cap
    from idbench.registry.testing import check_optional_members

    spec = idbench.ModelSpec(mesh="4x1x1", scenario=registry.scenario("bend-y"),
                             n_steps=2, markers=3)  # fmt: skip
    beam = registry.model("svk-beam")(spec)
    assert isinstance(beam, idbench.PlacedPointsModel)
    assert cap.marker_points_of(beam).shape == (3, 3)
    assert cap.target_points_of(beam).shape == (1, 3)  # the beam's default target
    model = LinearToy(p=1)  # observe: 3 values, two points would need 6
    state = model.step(np.array([2.0]), 1, model.reset())
    model.marker_points = np.zeros((2, 3))
    with pytest.raises(AssertionError, match="lacks target_points"):
        check_optional_members(model, state)
    model.target_points = np.zeros((0, 3))
    with pytest.raises(AssertionError, match="one point per three values"):
        check_optional_members(model, state)
    model.H = np.ones((6, model.A.shape[0]))  # two markers
    check_optional_members(model, state)
    model.target_points = np.zeros((1, 3))  # a target it does not move
    with pytest.raises(AssertionError, match=r"targets\(state\) 0"):
        check_optional_members(model, state)
