"""The core's estimator base, :class:`idbench.Filter`, and the README's example.

A filter written against the base (the README's, extracted from it) runs
through :func:`idbench.compare` on a linear-Gaussian toy model and gives the
exact Kalman answer; the base turns a failed linear solve and a non-finite or
out-of-bounds analysis into :class:`idbench.Diverged`, counts the cost since
``start`` and refuses a wrong step; an estimator written against the bare
protocol (the README's example before the base existed) still runs.
"""

from __future__ import annotations

import re
import types
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
from support.helpers import registry_with
from support.toymodels import SensitiveLinearToy

import idbench
from idbench.core.settings import estimator_arguments, public_settings
from idbench.run.compare import compare, runs_of
from idbench.run.session import Session

DOCS = Path(__file__).resolve().parents[2] / "docs"
TUTORIAL = DOCS / "tutorials" / "estimator-plugin.md"
STEPS = 5
TRUE_E = 2.0
PRIOR = (1.0, 0.5)
NOISE = 0.2


def readme_estimator_module() -> types.ModuleType:
    """The Python example of the docs' estimator-plugin tutorial."""
    text = TUTORIAL.read_text()
    (code,) = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    module = types.ModuleType("readme_estimator_plugin")
    exec(compile(code, str(TUTORIAL), "exec"), module.__dict__)
    return module


# The example of the README before idbench.Filter: the bare Estimator protocol.
@dataclass
class PriorOnly:
    """Reports the prior at every step (one forward solve a step)."""

    scale: float = 1.0  # settings are dataclass fields with defaults

    def start(self, model, prior):  # type: ignore[no-untyped-def]
        self.model, self.mean = model, self.scale * np.asarray(prior.mean)
        self.std, self.state = np.asarray(prior.std), model.reset()
        self.cost0 = model.cost()

    def update(self, k, observation):  # type: ignore[no-untyped-def]
        self.state = self.model.step(self.mean, k, self.state)
        return idbench.Estimate(
            self.mean, self.std, self.model.cost() - self.cost0, self.state
        )


class ToyPlugin:
    """A linear-Gaussian toy model and the protocol-only estimator."""

    @idbench.hookimpl
    def register_models(self, register: Callable[..., None]) -> None:
        def factory(spec: idbench.ModelSpec) -> SensitiveLinearToy:
            return SensitiveLinearToy(n_steps=spec.n_steps, m=3, n=4)

        register("toy-linear", factory)

    @idbench.hookimpl
    def register_estimators(self, register: Callable[[str, type], None]) -> None:
        register("prior-only", PriorOnly)


@pytest.fixture
def registry() -> idbench.Registry:
    return registry_with({"toys": ToyPlugin(), "readme": readme_estimator_module()})


def toy_config(**kw: Any) -> idbench.CompareConfig:
    base: dict[str, Any] = {
        "model": "toy-linear",
        "truth_mesh": "toy",
        "meshes": ("toy",),
        "scenarios": ("bend-y",),
        "steps": STEPS,
        "seeds": 1,
        "obs_every": (1,),
        "noise": (NOISE,),
        "true": {"E": TRUE_E},
        "prior": PRIOR,
    }
    return idbench.CompareConfig(**{**base, **kw})


def exact_posterior(
    registry: idbench.Registry, config: idbench.CompareConfig
) -> tuple[float, float]:
    """Mean and std of the Gaussian posterior of E given the run's observations."""
    (spec,) = runs_of(config, registry)
    toy = SensitiveLinearToy(n_steps=STEPS, m=3, n=4)
    precision = 1.0 / PRIOR[1] ** 2
    info = PRIOR[0] / PRIOR[1] ** 2
    for obs in Session(registry).observations(spec):
        assert obs is not None
        J = toy.jac(obs.step)[:, 0]
        precision += J @ J / NOISE**2
        info += J @ obs.values / NOISE**2
    return info / precision, precision**-0.5


def test_readme_filter_gives_the_exact_kalman_answer_through_compare(
    registry, tmp_path
):
    settings = {"tiny-rls": {"transform": "identity"}}
    config = toy_config(estimators=("tiny-rls",), estimator_settings=settings)
    runs, traces = compare(config, tmp_path / "out", registry=registry)
    (row,) = runs.to_dict("records")
    assert row["status"] == "ok", row["error"]
    mean, std = exact_posterior(registry, config)
    assert abs(mean - TRUE_E) < 0.3  # the data moved it from the prior ...
    assert abs(mean - row["E_ref"]) > 1e-2  # ... which still counts (E_ref: none)
    assert row["E_final"] == pytest.approx(mean, rel=1e-10)
    assert row["E_std_final"] == pytest.approx(std, rel=1e-10)
    assert row["n_solves"] == STEPS  # one forward solve a step, counted by the base
    assert traces["nis"].isna().all()  # it sets no innovation


def test_protocol_only_estimator_of_the_old_readme_still_runs(registry, tmp_path):
    config = toy_config(
        estimators=("prior-only", "tiny-rls"),
        estimator_settings={"prior-only": {"scale": 1.5}},
    )
    runs, _ = compare(config, tmp_path / "out", registry=registry)
    rows = runs.set_index("estimator")
    assert (rows["status"] == "ok").all(), rows["error"]
    assert rows.loc["prior-only", "E_final"] == 1.5 * PRIOR[0]
    assert rows.loc["prior-only", "E_std_final"] == PRIOR[1]
    assert rows.loc["prior-only", "n_solves"] == STEPS
    assert rows.loc["tiny-rls", "E_final"] != PRIOR[0]  # log transform: learns too


# --- the base on its own ------------------------------------------------------


@dataclass
class Scripted(idbench.Filter):
    """xi stays at the prior mean; step ``bad_at`` goes wrong as ``how`` says."""

    bad_at: int = 0
    how: str = ""

    def begin(self, model: Any, prior: idbench.Prior) -> None:
        self.xi, self.P = self.prior_xi(prior)
        self.u = model.reset()

    def assimilate(self, k: int, observation: Any) -> idbench.Analysis:
        self.u = self.model.step(self.to_theta(self.xi), k, self.u)
        xi, u = self.xi, self.u
        if k == self.bad_at:
            if self.how == "linalg":
                np.linalg.cholesky(-np.eye(2))
            elif self.how == "state":
                u = np.full_like(u, np.nan)
            elif self.how == "xi":
                xi = np.full_like(xi, np.inf)
            elif self.how == "bounds":
                xi = self.to_xi(np.array([2e7]))
        return idbench.Analysis(xi, self.P, state=u, finite=(u,))


def run_scripted(est: Scripted, model: Any, steps: int) -> list[idbench.Estimate]:
    est.start(model, idbench.Prior((1e3,), (1e2,)))
    return [est.update(k, None) for k in range(1, steps + 1)]


@pytest.mark.parametrize(
    ("how", "message"),
    [
        ("linalg", "linear algebra failed"),
        ("state", r"the filter's updated state is non-finite .* is finite\)"),
        ("xi", "the parameter estimate is non-finite"),
        ("bounds", "the parameter estimate .* left the bounds"),
    ],
)
def test_base_turns_a_bad_step_into_diverged(how: str, message: str) -> None:
    model = SensitiveLinearToy(lower=1.0, upper=1e7)
    est = Scripted(bad_at=3, how=how)
    run_scripted(est, model, 2)  # steps before the bad one are fine
    with pytest.raises(idbench.Diverged, match=message) as info:
        est.update(3, None)
    assert info.value.step == 3


def test_base_counts_the_cost_since_start_and_reports_theta() -> None:
    model = SensitiveLinearToy(lower=1.0, upper=1e7)
    model.step(np.array([1.0]), 1, model.reset())  # work before the run ...
    est = Scripted(transform="log")
    estimates = run_scripted(est, model, 4)
    assert [e.cost.forward_solves for e in estimates] == [1, 2, 3, 4]  # ... not counted
    assert model.cost().forward_solves == 5
    e = estimates[-1]
    mean_xi, var_xi = np.log(1e3), np.log1p(1e-2)  # the log-normal's
    assert e.mean == pytest.approx([np.exp(mean_xi)], rel=1e-14)
    assert e.std == pytest.approx([np.exp(mean_xi) * np.sqrt(var_xi)], rel=1e-14)
    assert e.state is not None and e.state is not est.u  # a copy


def test_base_refuses_a_wrong_step() -> None:
    model = SensitiveLinearToy(n_steps=4)
    est = Scripted(transform="identity")
    with pytest.raises(RuntimeError, match="start"):
        est.update(1, None)
    est.start(model, idbench.Prior((1.0,), (1.0,)))
    obs = idbench.Observation(np.zeros(3), 1e-3, step=2)
    with pytest.raises(ValueError, match="observation for step 2 given at step 1"):
        est.update(1, obs)
    for k in (0, 5):
        with pytest.raises(ValueError, match=rf"step k = {k} is outside 1\.\.4"):
            est.update(k, None)
    assert model.cost().forward_solves == 0  # refused before any work


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"transform": "sqrt"}, "transform = 'sqrt' is not allowed; use one of"),
        ({"sigma_floor": 0.0}, "sigma_floor = 0.0 is not allowed"),
        ({"sigma_floor": float("nan")}, "sigma_floor = nan is not allowed"),
    ],
)
def test_base_refuses_bad_settings(settings: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Scripted(**settings)


def test_conventions_are_defaulted_class_attributes() -> None:
    est = Scripted()
    assert idbench.Filter.reference is False and est.reference is False
    assert est.seed is None and est.innovation is None
    assert est.estimate_solves(100, 2, 7) == 7
    assert estimator_arguments(Scripted, {}, 3) == {}  # no seed field: none given
    assert public_settings(Scripted) == [
        "transform", "sigma_floor", "correction", "bad_at", "how"
    ]


@dataclass
class Seeded(Scripted):
    """Declares a seed and sets an innovation."""

    seed: int = 0

    def assimilate(self, k: int, observation: Any) -> idbench.Analysis:
        self.innovation = (np.ones(1), np.eye(1))
        return super().assimilate(k, observation)


def test_a_seed_field_gets_the_runs_seed_and_start_resets_the_innovation() -> None:
    assert estimator_arguments(Seeded, {}, 3) == {"seed": 3}
    assert estimator_arguments(Seeded, {"seed": 9}, 3) == {"seed": 9}
    est = Seeded(**estimator_arguments(Seeded, {}, 3))
    assert est.seed == 3
    run_scripted(est, SensitiveLinearToy(lower=1.0, upper=1e7), 1)
    assert est.innovation is not None
    est.start(SensitiveLinearToy(), idbench.Prior((1.0,), (1.0,)))
    assert est.innovation is None
    assert Seeded.innovation is None  # the class default is untouched


def test_builtin_filters_use_the_core_base() -> None:
    from idbench_filters import BatchLs, Enkf, Etkf, Lms, Rls, RoUkf, Ukf

    for cls in (BatchLs, Enkf, Etkf, Lms, Rls, RoUkf, Ukf):
        assert issubclass(cls, idbench.Filter), cls
    assert BatchLs.reference is True and RoUkf.reference is False


# --- the base checks its subclasses when they are defined ---------------------


def test_a_subclass_without_its_methods_fails_at_definition() -> None:
    with pytest.raises(TypeError, match=r"NoMaths \(.*\): lacks assimilate, begin"):

        @dataclass
        class NoMaths(idbench.Filter):
            pass


def test_a_method_with_the_wrong_arguments_fails_at_definition() -> None:
    with pytest.raises(
        TypeError, match=r"Short .*assimilate must take \(self, k, observation\)"
    ):

        @dataclass
        class Short(Scripted):
            def assimilate(self, k: int) -> idbench.Analysis:  # type: ignore[override]
                raise AssertionError

    with pytest.raises(TypeError, match="estimate_solves must take"):

        class Guess(Scripted):
            def estimate_solves(self) -> int:  # type: ignore[override]
                return 0

    with pytest.raises(TypeError, match="begin is no method"):

        class NotAMethod(Scripted):
            begin = 3  # type: ignore[assignment]


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("alpha = 0.5", "alpha = 0.5 is no dataclass field: annotate it"),
        ("alpha: float", "setting 'alpha' has no default"),
        ("alpha: float = field()", "setting 'alpha' has no default"),
        ("def __init__(self, alpha=0.5):\n        self.alpha = alpha",
         "defines __init__: its settings must be dataclass fields"),
    ],
)
def test_settings_that_cannot_be_fields_fail_at_definition(
    body: str, message: str
) -> None:
    source = f"class Loose(Scripted):\n    {body}\n"
    namespace = {"Scripted": Scripted, "field": __import__("dataclasses").field}
    with pytest.raises(TypeError, match=rf"Loose \(.*{re.escape(message)}"):
        exec(source, namespace)


def test_class_constants_and_conventions_are_not_settings() -> None:
    @dataclass
    class Flagged(Scripted):
        reference = True  # a convention of the base (a ClassVar there)
        LIMIT: ClassVar[int] = 3

    assert Flagged.reference is True and "LIMIT" not in public_settings(Flagged)


def test_an_abstract_base_need_not_implement_and_its_subclasses_must() -> None:
    from abc import abstractmethod

    @dataclass
    class Base(idbench.Filter, abstract=True):
        width: int = 2

        def begin(self, model: Any, prior: idbench.Prior) -> None:
            self.xi, self.P = self.prior_xi(prior)

        @abstractmethod
        def analysis(self, xi: Any) -> Any: ...

        def assimilate(self, k: int, observation: Any) -> idbench.Analysis:
            return idbench.Analysis(self.analysis(self.xi), self.P)

    with pytest.raises(TypeError, match=r"Partial .*lacks analysis"):

        @dataclass
        class Partial(Base):
            pass

    @dataclass
    class Whole(Base):
        def analysis(self, xi: Any) -> Any:
            return xi

    assert Base.abstract is True and Whole.abstract is False
    reg = registry_with({"abstract-plug": types.SimpleNamespace(
        register_estimators=idbench.hookimpl(
            lambda register: register("base", Base)
        )
    )})  # fmt: skip
    assert "is an abstract base (" in reg.errors["abstract-plug"]
    assert "base" not in reg.estimators


def test_a_base_that_is_no_dataclass_fails_its_subclasses_and_registration() -> None:
    class Undecorated(Scripted):  # its setting would be no field
        alpha: float = 0.5

    with pytest.raises(TypeError, match="base Undecorated is not a dataclass"):

        @dataclass
        class Child(Undecorated):
            pass

    reg = registry_with({"loose-plug": types.SimpleNamespace(
        register_estimators=idbench.hookimpl(
            lambda register: register("loose", Undecorated)
        )
    )})  # fmt: skip
    message = reg.errors["loose-plug"]
    assert "plugin 'loose-plug': estimator 'loose'" in message
    assert "Undecorated.alpha" in message and "@dataclass" in message


def test_the_conventions_defaults_are_the_declared_ones() -> None:
    from idbench.core.capabilities import estimator_member
    from idbench.core.members import ESTIMATOR_OPTIONAL

    for name, declared in ESTIMATOR_OPTIONAL.items():
        assert estimator_member(PriorOnly(), name) == declared.default, name
        if name in ("correction", "ensemble", "estimate_solves", "handles_nan"):
            continue  # a setting of the base, none, a method; it masks NaN
        assert getattr(idbench.Filter, name) == declared.default, name
    assert estimator_member(Scripted(), "handles_nan") is True
