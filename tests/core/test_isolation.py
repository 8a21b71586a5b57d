"""Runs are isolated from each other: a plugin cannot corrupt the model of later runs.

Each run gets a private copy of its model (:mod:`idbench.run.isolation`); the FE
models' constants are read-only; after a run the copy and the master are
checked against the master's fingerprint. A hostile estimator's run fails,
naming it, and every other run gives the numbers it gives without it:
serially, in forked worker processes (``jobs=2``) and with a timeout. A run's
numbers depend on the run only, not on what ran before it in the session.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from idbench.plan.check import plan
from idbench.plan.config import CompareConfig
from idbench.registry.registry import build_registry
from idbench.run.compare import compare, prepare
from idbench.run.harness import execute
from idbench.run.isolation import changes, fingerprint, private_copy
from idbench.run.session import Session

HOSTILE = '''
    """Estimators that write into the model they are given, then answer the prior."""
    from dataclasses import dataclass

    import numpy as np

    import idbench


    def float_arrays(model):
        return [(k, v) for k, v in vars(model).items()
                if isinstance(v, np.ndarray) and v.dtype.kind == "f"]


    @dataclass
    class Base:
        def start(self, model, prior):
            self.mean = np.asarray(prior.mean, dtype=float)
            self.misbehave(model.model)  # through the harness's checked view

        def update(self, k, observation):
            return idbench.Estimate(self.mean, np.full_like(self.mean, 1.0),
                                    idbench.Cost())

        def estimate_solves(self, n_state, p, steps):
            return 10**9  # dispatched first: later runs follow it on its worker


    @dataclass
    class Scales(Base):  # (a) scales the model's arrays in place
        def misbehave(self, model):
            for _, value in float_arrays(model):
                value *= 1.5


    @dataclass
    class Shortens(Base):  # (b) a shorter load path
        def misbehave(self, model):
            model.n_steps = 2


    @dataclass
    class Replaces(Base):  # (c) replaces attributes with other arrays
        def misbehave(self, model):
            for name, value in float_arrays(model):
                setattr(model, name, 1.5 * value)


    @dataclass
    class Deep(Base):  # (d) writes into what the model holds (its assembler)
        def misbehave(self, model):
            for _, value in float_arrays(model._asm):
                value *= 1.5


    @dataclass
    class Sparse(Base):  # (e) scales the observation operator's entries
        def misbehave(self, model):
            for value in vars(model).values():
                if hasattr(value, "indptr"):
                    value.data *= 1.5


    @idbench.hookimpl
    def register_estimators(register):
        register("scales", Scales)
        register("shortens", Shortens)
        register("replaces", Replaces)
        register("deep", Deep)
        register("sparse", Sparse)
'''

CASES = {  # estimator: words its run's error must hold
    "scales": "read-only",
    "shortens": "changed the model it was given (describe, n_steps)",
    "replaces": "changed the model it was given (array _f_end, array _factors, array",
    "deep": "read-only",
    "sparse": "read-only",
}
MODES = {"serial": {"jobs": 1}, "forked": {"jobs": 2}, "timeout": {"jobs": 1}}
SMALL: dict[str, Any] = {
    "truth_mesh": "10x2x2",
    "meshes": ("4x1x1",),
    "steps": 3,
    "seeds": 2,
}
COLUMNS = ("E_final", "E_ref", "shape_error_final", "transfer_error")


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Any:
    """The rls runs of the sweep without a hostile plugin."""
    with pytest.MonkeyPatch.context() as mp:  # the tests' cache (conftest)
        mp.setenv("IDBENCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "c"))
        runs, _ = compare(CompareConfig(**SMALL, estimators=("rls",)), None)
    return runs.set_index(["estimator", "seed"]).sort_index()


@pytest.mark.parametrize("mode", list(MODES))
@pytest.mark.parametrize("hostile", list(CASES))
def test_a_plugin_that_writes_into_its_model_fails_its_run_only(
    install, tmp_path, clean, hostile, mode
):
    install("hostile", HOSTILE)
    timeout = 120.0 if mode == "timeout" else None
    config = CompareConfig(**SMALL, estimators=(hostile, "rls"), timeout=timeout)
    runs, _ = compare(config, tmp_path, jobs=MODES[mode]["jobs"])
    runs = runs.set_index(["estimator", "seed"]).sort_index()
    bad = runs.loc[hostile]
    assert (bad["status"] == "failed").all(), bad[["status", "error"]]
    for error in bad["error"]:
        assert f"estimator {hostile!r} (plugin 'hostile')" in error
        assert CASES[hostile] in error
    good = runs.loc["rls"]
    assert (good["status"] == "ok").all(), good[["status", "error"]]
    for col in COLUMNS:  # as without the hostile plugin: bitwise
        np.testing.assert_array_equal(good[col], clean.loc["rls"][col], err_msg=col)


def test_a_changed_master_is_discarded_and_built_anew():
    session = Session(build_registry())
    config = CompareConfig(**SMALL, estimators=("rls",))
    spec = plan(config, session).runs[0]
    master, copy = session.lend(spec, spec.mesh)
    assert session.returned(master, copy) == []
    assert session.model(spec, spec.mesh) is master
    object.__setattr__(master, "n_steps", 2)  # as through a shared object
    assert session.returned(master, copy) == ["describe", "n_steps"]
    rebuilt = session.model(spec, spec.mesh)
    assert rebuilt is not master and rebuilt.n_steps == SMALL["steps"]


def test_a_copy_keeps_its_assignments_and_its_caches_to_itself():
    session = Session(build_registry())
    spec = plan(CompareConfig(**SMALL, estimators=("ro-ukf",)), session).runs[0]
    master = session.model(spec, spec.mesh)
    before = fingerprint(master)
    copy: Any = private_copy(master)
    thetas = np.array([[2000.0], [2500.0], [3000.0]])
    copy.step_many(thetas, 1, np.zeros((3, copy.n_state)))
    copy.n_steps = 2
    assert master.n_steps == SMALL["steps"]
    assert getattr(master, "_batch_anchor", None) is None  # the copy's own
    assert copy._solver is master._solver  # shared, built once
    assert changes(before, fingerprint(master)) == []
    assert changes(before, fingerprint(copy)) == ["describe", "n_steps"]
    with pytest.raises(ValueError, match="read-only"):
        copy._load_weights *= 2


LATE = '''
    """An ensemble estimator whose members start moving at step 2 (legitimately)."""
    from dataclasses import dataclass

    import numpy as np

    import idbench


    @dataclass
    class Late:
        fail_at: int = 0  # > 0: raise at that step (after advancing the step before)
        together_from: int = 2  # the first step that advances members together

        def start(self, model, prior):
            self.model = model
            self.thetas = np.array([[m] for m in (0.8, 1.0, 1.25)]) * prior.mean
            self.states = np.zeros((3, model.reset().size))

        def update(self, k, observation):
            if k == self.fail_at:
                raise RuntimeError("gives up")
            if k < self.together_from:  # one member at a time: step
                self.states = np.array([self.model.step(t, 1, s)
                                        for t, s in zip(self.thetas, self.states)])
            else:
                self.states = self.model.step_many(self.thetas, k, self.states)
            if observation is not None:
                y = np.array([self.model.observe(s) for s in self.states])
                d = np.linalg.norm(y - observation.values, axis=1)
                self.best = self.thetas[int(np.argmin(d))]
            mean = getattr(self, "best", self.thetas[1])
            tip = float(self.states[1].sum())  # carries the state into the answer
            return idbench.Estimate(mean * (1 + 1e-3 * tip), np.ones(1), idbench.Cost())


    @dataclass
    class Quits(Late):  # together from step 1, gives up at step 2
        fail_at: int = 2
        together_from: int = 1


    @idbench.hookimpl
    def register_estimators(register):
        register("late", Late)
        register("quits", Quits)
'''


def _rows(session: Session, specs: list[Any]) -> dict[str, dict[str, Any]]:
    return {s.run_id: execute(s, session)[0] for s in specs}


def _fresh(config: CompareConfig) -> tuple[Session, list[Any]]:
    session = Session(build_registry())
    runs = plan(config, session).runs
    prepare(runs, session)
    return session, runs


@pytest.mark.parametrize(
    "estimators",
    [("rls", "ro-ukf", "enkf", "batch-ls"), ("quits", "late")],
    ids=["built-in", "a-run-that-stops-early-first"],
)
def test_a_run_gives_the_same_numbers_alone_and_after_other_runs(
    install, estimators
):
    install("late", LATE)
    config = CompareConfig(**{**SMALL, "steps": 4, "seeds": 1}, estimators=estimators)
    _, runs = _fresh(config)
    alone = {}
    for spec in runs:
        session, _ = _fresh(config)
        alone.update(_rows(session, [spec]))
    session, _ = _fresh(config)
    after = _rows(session, runs)  # each after the ones before it, one session
    for spec in runs:
        a, b = alone[spec.run_id], after[spec.run_id]
        assert a["status"] == b["status"], (spec.estimator, a["error"], b["error"])
        for col in COLUMNS:  # bitwise (a failed run has NaN or none)
            x, y = a.get(col, np.nan), b.get(col, np.nan)
            assert x == y or (np.isnan(x) and np.isnan(y)), (spec.estimator, col, x, y)


def test_the_fingerprint_names_what_changed():
    class Toy:
        def __init__(self) -> None:
            from idbench import ParameterSpec

            self.parameters = ParameterSpec(("k",), (0.0,), (10.0,))
            self.n_steps = 4
            self.weights = np.ones(3)

        def describe(self) -> dict[str, Any]:
            return {"n_steps": self.n_steps}

    toy: Any = Toy()
    before = fingerprint(toy)
    toy.cache = np.zeros(2)  # a cache added on first use is no change
    assert changes(before, fingerprint(toy)) == []
    toy.weights[0] = 2.0
    assert changes(before, fingerprint(toy)) == ["array weights"]
    assert isinstance(private_copy(toy), Toy)
