"""A fault is blamed on the party that caused it: a model's on the model.

A model plugin whose ``observe()`` or ``step()`` returns the wrong shape fails
its runs naming the model and its plugin, not the estimator that received
it; a non-finite state is the model's failed solve (diverged), named too.
"""

from __future__ import annotations

import pytest

from idbench.plan.config import CompareConfig
from idbench.run.compare import compare

BAD_MODELS = '''
    import numpy as np

    import idbench


    class Bad:
        """u_k = (k/K) c / E on 4 nodes; observes 3; one fault on mesh "m"."""

        def __init__(self, spec, fault):
            self.n_steps, self.fault, self.mesh = spec.n_steps, fault, spec.mesh
            self.parameters = idbench.ParameterSpec(
                ("E",), (1.0,), (1e6,), default=(100.0,))
            self.c = np.arange(1.0, 5.0)

        def reset(self):
            return np.zeros(4)

        def step(self, theta, k, state, *, substeps=1):
            u = (k / self.n_steps) * self.c / float(theta[0])
            if self.mesh == "m" and k >= 2:
                if self.fault == "short-state":
                    return u[:3]
                if self.fault == "nan-state":
                    return np.full(4, np.nan)
            return u

        def observe(self, state):
            y = np.asarray(state, dtype=float)[:3]
            if self.mesh == "m" and self.fault == "long-observe":
                return np.concatenate([y, [0.0]])
            if self.mesh == "m" and self.fault == "odd-observe" and y[0] > 0:
                return y[:2]
            return y

        def grid(self, state):
            return np.asarray(state, dtype=float)[:3].reshape(1, 3)

        def cost(self):
            return idbench.Cost(0, 0, 0)

        def describe(self):
            return {"model": "bad", "fault": self.fault, "mesh": self.mesh}


    FAULTS = ("short-state", "nan-state", "long-observe", "odd-observe")


    @idbench.hookimpl
    def register_scenarios(register):
        register(idbench.Scenario("pull", {"force": 1.0}))


    @idbench.hookimpl
    def register_models(register):
        for fault in FAULTS:
            register(f"bad-{fault}", lambda spec, f=fault: Bad(spec, f))
'''

ESTIMATORS = ("ro-ukf", "ukf", "enkf", "etkf", "rls", "lms", "batch-ls")


@pytest.fixture
def bad(install):
    install("badmodels", BAD_MODELS)


def runs_of(model: str, tmp_path):
    config = CompareConfig(
        model=model, truth_mesh="t", meshes=("m",), scenarios=("pull",),
        estimators=ESTIMATORS, steps=3, seeds=1, prior=(80.0, 40.0),
        noise=(1e-4,),
    )  # fmt: skip
    runs, _ = compare(config, tmp_path / model)
    return runs.set_index("estimator")


@pytest.mark.parametrize(
    ("fault", "words"),
    [
        ("short-state", "returned a state of shape (3,) from step() at step 2; "
                        "expected (4,)"),
        ("long-observe", "returned 4 values from observe(); expected 3"),
        ("odd-observe", "returned 2 values from observe(); expected 3"),
    ],
)  # fmt: skip
def test_a_model_of_the_wrong_shape_is_named_not_the_estimator(
    bad, tmp_path, fault, words
):
    runs = runs_of(f"bad-{fault}", tmp_path)
    for estimator, row in runs.iterrows():
        assert row["status"] == "failed", (estimator, row["error"])
        assert f"model 'bad-{fault}' (plugin 'badmodels')" in row["error"], (
            estimator, row["error"])  # fmt: skip
        assert words in row["error"], (estimator, row["error"])
        assert f"estimator {estimator!r}" not in row["error"], row["error"]


def test_a_non_finite_state_is_the_models_failed_solve(bad, tmp_path):
    runs = runs_of("bad-nan-state", tmp_path)
    for estimator, row in runs.iterrows():
        assert row["status"] == "diverged", (estimator, row["error"])
        assert row["failed_step"] == 2, (estimator, row["failed_step"])
        assert "model 'bad-nan-state' (plugin 'badmodels')" in row["error"], (
            estimator, row["error"])  # fmt: skip
        assert "non-finite state" in row["error"], row["error"]
