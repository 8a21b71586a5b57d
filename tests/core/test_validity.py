"""A run whose result cannot mean anything is never ``ok``.

What the input decides is refused up front, in one line; what only the run
shows is flagged in the row's ``warning`` column and listed in the summary.
Runs on the spring chain of ``test_report_models`` (fast) and tiny beams.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import meshio
import numpy as np
import pytest
from support.helpers import registry_with
from support.springs import SpringChain, SpringPlugin

import idbench
from idbench.cli.commands import main
from idbench.core.interfaces import Observation, ParameterSpec
from idbench.plan.config import CompareConfig, ConfigError
from idbench.report.write import summary_text
from idbench.run.compare import compare, runs_of
from idbench.run.session import model_settings
from idbench.truth.simulate import Truth
from idbench_fem.bodies import box as meshes
from idbench_fem.bodies.mesh import from_arrays as solid_from_arrays

TINY = ["--truth-mesh", "12x3x3", "--meshes", "4x1x1", "--steps", "5", "--seeds",
        "1", "--estimators", "rls"]  # fmt: skip


class NanChain(SpringChain):
    """A spring chain whose fine (truth) meshes return NaN from step 2."""

    def step(self, theta: Any, k: int, state: Any, *, substeps: int = 1) -> Any:
        out = super().step(theta, k, state, substeps=substeps)
        return out * np.nan if self.n_nodes >= 40 and k >= 2 else out

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "model": "nan-chain"}


@dataclass
class Misbehaves:
    """Answers the prior, except for what ``how`` breaks from step 2."""

    how: str = "std"

    def start(self, model: Any, prior: idbench.Prior) -> None:
        self.mean = np.asarray(prior.mean, dtype=float)
        self.n = model.reset().size

    def update(self, k: int, observation: Any) -> idbench.Estimate:
        bad = k >= 2
        std = np.full_like(self.mean, -1.0 if bad and self.how == "std" else 1.0)
        cost = idbench.Cost(-3 if bad and self.how == "cost" else k)
        state = np.full(self.n, np.nan) if bad and self.how == "state" else None
        return idbench.Estimate(self.mean, std, cost, state)


class ExtraPlugin:
    @idbench.hookimpl
    def register_models(self, register):
        register("nan-chain", NanChain, defaults=idbench.ModelDefaults(
            truth_mesh="40", meshes=("5",), scenarios=("pull",), prior=(30.0, 20.0)))

    @idbench.hookimpl
    def register_estimators(self, register):
        register("misbehaves", Misbehaves)


@pytest.fixture
def registry():
    return registry_with({"springs": SpringPlugin(), "extra": ExtraPlugin()})


def chain(**kw: Any) -> CompareConfig:
    base: dict[str, Any] = {
        "model": "spring-chain", "meshes": ("5",), "truth_mesh": "40",
        "estimators": ("rls", "batch-ls"), "seeds": 1, "steps": 6,
        "obs_every": (1,), "noise": (1e-4,),
    }  # fmt: skip
    return CompareConfig(**{**base, **kw})


def one_line_error(capsys: Any, argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


# --- 1. no observation at all --------------------------------------------------


def test_a_spacing_longer_than_the_path_is_refused(capsys):
    with pytest.raises(ConfigError, match=r"obs_every 2 > steps 1"):
        CompareConfig(steps=1)
    with pytest.raises(ConfigError, match=r"obs_every 30 > steps 20"):
        CompareConfig(obs_every=(1, 30))
    err = one_line_error(
        capsys, ["compare", *TINY[:4], "--steps", "1", "--obs-every", "2",
                 "--dry-run"],
    )  # fmt: skip
    assert "obs_every 2" in err and "steps 1" in err


def test_a_run_without_observations_is_flagged():
    from idbench.plan.validity import run_warning

    params = ParameterSpec(("k",), (1e-3,), (1e6,))
    truth = Truth(np.zeros((3, 1)), np.ones((3, 2)), np.zeros((3, 1, 1)), {})
    text = run_warning(params, [None] * 3, truth, 1e-4, np.ones(1), np.ones(1))
    assert "no observation" in text
    seen = [None, Observation(np.ones(2), 1e-4, 2), None]
    assert run_warning(params, seen, truth, 1e-4, np.ones(1), np.ones(1)) == ""


# --- 2. a signal below the noise, a fit at a bound -------------------------------


def test_signal_below_the_noise_is_flagged_in_the_row_and_the_summary(
    registry, tmp_path
):
    runs, _ = compare(chain(noise=(1e-4, 10.0)), tmp_path / "out", registry=registry)
    ok = runs[runs["status"] == "ok"]
    quiet = ok[ok["noise"] == 1e-4]
    loud = ok[ok["noise"] == 10.0]
    assert len(quiet) == 2 and len(loud) == 2
    assert (quiet["warning"] == "").all()
    assert loud["warning"].str.contains("signal below the noise").all()
    text = summary_text(runs)
    assert "flagged: 2 run(s)" in text and "signal below the noise" in text
    assert "flagged" in summary_text(runs, "markdown")
    assert "flagged" not in summary_text(quiet)


def test_an_estimate_or_reference_at_a_bound_is_flagged():
    from idbench.plan.validity import run_warning

    params = ParameterSpec(("k",), (1e-3,), (1e6,))
    obs = [Observation(np.ones(2), 1e-4, 1)]
    truth = Truth(np.zeros((1, 1)), np.ones((1, 2)), np.zeros((1, 1, 1)), {})
    text = run_warning(params, obs, truth, 1e-4, np.array([50.0]), np.array([1e6]))
    assert text.startswith("reference fit at the parameter bound")
    assert "upper bound 1e+06" in text
    text = run_warning(params, obs, truth, 1e-4, np.array([1e-3]), np.array([50.0]))
    assert "final estimate at the parameter bound" in text and "lower" in text


# --- 3. a truth that is not finer, or another body --------------------------------


def test_a_truth_not_finer_than_a_model_mesh_is_refused(registry):
    match = r"truth mesh '20' \(20 nodes\) is not finer than model mesh '30'"
    with pytest.raises(ConfigError, match=match):
        runs_of(chain(meshes=("5", "30"), truth_mesh="20"), registry)
    with pytest.raises(ConfigError, match="not finer than model mesh '5'"):
        runs_of(chain(meshes=("5",), truth_mesh="4"), registry)
    # the truth's own mesh as a model mesh (an inverse-crime check) is allowed
    assert runs_of(chain(meshes=("5", "40")), registry)


def test_a_truth_of_another_body_is_refused(tmp_path):
    fine = meshes.parse("12x3x3")
    third = fine.points * np.array([1.0, 1 / 3, 1.0])  # a third of the section
    path = tmp_path / "third.vtu"
    meshio.write(path, meshio.Mesh(third, [("tetra", fine.tets)]))
    cfg = CompareConfig(truth_mesh=str(path), meshes=("4x1x1",), steps=4, seeds=1,
                        estimators=("rls",))  # fmt: skip
    with pytest.raises(ConfigError, match="are not the same body") as info:
        runs_of(cfg)
    assert "axis 1" in str(info.value) and str(path) in str(info.value)
    # the same body at another resolution passes
    same = tmp_path / "same.vtu"
    meshio.write(same, meshio.Mesh(fine.points, [("tetra", fine.tets)]))
    assert runs_of(CompareConfig(**{**cfg.to_dict(), "truth_mesh": str(same)}))


# --- 4. what estimators return ------------------------------------------------------


@pytest.mark.parametrize(
    ("how", "said"),
    [("std", "negative std"), ("cost", "returned cost"), ("state", "non-finite state")],
)
def test_nonsense_from_an_estimator_fails_its_run_naming_the_plugin(
    registry, tmp_path, how, said
):
    settings = {"misbehaves": {"how": how}}
    cfg = chain(estimators=("misbehaves", "rls"), estimator_settings=settings)
    runs, _ = compare(cfg, tmp_path / "out", registry=registry)
    row = runs.set_index("estimator").loc["misbehaves"]
    assert row["status"] == "failed"
    assert "plugin 'extra'" in row["error"] and said in row["error"]
    assert row["failed_step"] == 2
    assert runs.set_index("estimator").loc["rls", "status"] == "ok"


# --- 5. a non-finite truth fails the truth ----------------------------------------


def test_a_non_finite_truth_is_one_refusal_not_every_estimator_failing(
    registry, tmp_path
):
    cfg = chain(model="nan-chain", estimators=("rls", "batch-ls"))
    with pytest.raises(ConfigError) as info:
        compare(cfg, tmp_path / "out", registry=registry)
    text = str(info.value)
    assert "the truth (40, pull)" in text and "non-finite states" in text
    assert "step 2" in text and "estimator" not in text


# --- 6. a mesh in pieces ------------------------------------------------------------


def test_a_mesh_in_disconnected_pieces_is_refused(tmp_path, capsys):
    a = meshes.parse("4x1x1")
    shifted = a.points + np.array([0.0, 1.0, 0.0])  # a second beam beside it
    points = np.vstack([a.points, shifted])
    tets = np.vstack([a.tets, a.tets + len(a.points)])
    path = tmp_path / "two.vtu"
    meshio.write(path, meshio.Mesh(points, [("tetra", tets)]))
    with pytest.raises(ValueError, match="2 disconnected pieces"):
        meshes.parse(str(path))
    with pytest.raises(ValueError, match="2 disconnected pieces"):
        solid_from_arrays(points, tets, "two")
    err = one_line_error(
        capsys, ["compare", "--truth-mesh", "12x3x3", "--meshes", str(path),
                 "--steps", "4", "--seeds", "1", "--estimators", "rls", "--dry-run"],
    )  # fmt: skip
    assert str(path) in err and "2 disconnected pieces" in err
    meshes.parse("4x1x1")  # one piece: accepted


# --- 7. inputs that make every run fail ----------------------------------------------


def test_inputs_that_fail_every_run_are_refused_before_the_sweep(capsys, tmp_path):
    err = one_line_error(capsys, ["compare", *TINY, "--prior=-100,10", "--dry-run"])
    assert "prior mean -100" in err and "E: 1..1e+08" in err
    err = one_line_error(capsys, ["compare", *TINY, "--noise", "1e300", "--dry-run"])
    assert "noise 1e+300" in err
    err = one_line_error(capsys, ["compare", *TINY, "--noise", "nan", "--dry-run"])
    assert "noise nan" in err
    out = tmp_path / "out"
    one_line_error(capsys, ["compare", *TINY, "--prior=-100,10", "--out", str(out)])
    assert not (out / "runs.parquet").exists()


# --- 8. a model setting of the wrong type ---------------------------------------------


def test_a_model_setting_of_the_wrong_type_is_one_line(registry, capsys):
    err = one_line_error(
        capsys, ["compare", *TINY, "--model-option", "sensitivity_refine=abc",
                 "--dry-run"],
    )  # fmt: skip
    assert "sensitivity_refine 'abc'" in err and "need true or false" in err
    with pytest.raises(ConfigError, match=r"p 'abc': need a whole number, got str"):
        model_settings(registry, "spring-chain", {"p": "abc"})
    with pytest.raises(ConfigError, match=r"k inf: need a finite number"):
        model_settings(registry, "spring-chain", {"k": float("inf")})
    assert model_settings(registry, "spring-chain", {"k": 7}).k == 7.0
    assert isinstance(model_settings(registry, "spring-chain", {"k": 7}).k, float)
    # a text setting given a number on the command line (a mesh spec) is text
    solid = model_settings(idbench.build_registry(), "solid", {"reference": 200})
    assert solid.reference == "200"

