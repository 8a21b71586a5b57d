"""A calibration is what it claims: a finer mesh of the same body, flagged beyond.

A calibration mesh that is not finer than a model mesh (or is it), or of
another body, is refused before any run in one line; every corrected run
whose predictions (the estimator's, or the scores' at its estimates) leave
the calibrated load states has them counted in its row's ``extrapolated``
column and says so in its ``warning``, whatever the estimator.
"""

from __future__ import annotations

import pytest
from support.helpers import write_box_mesh

from idbench.cli.commands import main
from idbench.plan.config import CompareConfig
from idbench.run.compare import compare

STILL = '''
    from dataclasses import dataclass

    import numpy as np

    import idbench


    @dataclass
    class Still:
        """Answers the prior at every step: never asks its model anything."""

        correction: str = "none"

        def start(self, model, prior):
            self.mean = np.asarray(prior.mean, dtype=float)

        def update(self, k, observation):
            return idbench.Estimate(self.mean, np.full_like(self.mean, 500.0),
                                    idbench.Cost())


    @idbench.hookimpl
    def register_estimators(register):
        register("still", Still)
'''


def refused(tmp_path, capsys, *extra: str) -> str:
    toml = tmp_path / "c.toml"
    toml.write_text('[estimators.rls]\ncorrection = "approximation-error"\n')
    out = tmp_path / "out"
    argv = ["compare", "--truth-mesh", "12x3x3", "--meshes", "6x2x2", "--steps",
            "3", "--seeds", "1", "--estimators", "rls", "--config", str(toml),
            "--out", str(out), *extra]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert not out.exists()
    return err


@pytest.mark.parametrize(
    ("mesh", "words"),
    [
        ("4x1x1", "calibration mesh '4x1x1' (20 nodes) is not finer than model "
                  "mesh '6x2x2' (63 nodes)"),
        ("6x2x2", "calibration mesh '6x2x2' is model mesh '6x2x2' itself"),
    ],
)  # fmt: skip
def test_a_calibration_mesh_not_finer_is_refused(tmp_path, capsys, mesh, words):
    assert words in refused(tmp_path, capsys, "--calibration-mesh", mesh)


def test_a_calibration_mesh_of_another_body_is_refused(tmp_path, capsys):
    other = tmp_path / "long.vtu"
    write_box_mesh(other, 13, 0.4, 0.03)  # twice the beam's length
    err = refused(tmp_path, capsys, "--calibration-mesh", str(other))
    assert "are not the same body" in err and "calibration" in err, err


def test_every_estimator_is_flagged_where_its_predictions_extrapolate(install):
    install("still", STILL)
    est = ("still", "rls", "ro-ukf")
    config = CompareConfig(
        scenarios=("bend-z",), meshes=("6x2x2",), truth_mesh="9x2x2",
        estimators=est, seeds=1, steps=4,
        calibration={"scaled_steps": 12, "scenarios": ["bend-y"]},
        estimator_settings={e: {"correction": "approximation-error"} for e in est},
    )  # fmt: skip
    runs, _ = compare(config, None)
    runs = runs.set_index("estimator")
    assert (runs["status"] == "ok").all(), runs["error"]
    for name, row in runs.iterrows():
        assert row["extrapolated"] > 0, name
        assert "the correction extrapolated" in row["warning"], (name, row["warning"])


def test_a_run_within_its_calibration_counts_none():
    config = CompareConfig(
        scenarios=("bend-y",), meshes=("6x2x2",), truth_mesh="9x2x2",
        estimators=("rls",), seeds=1, steps=4, calibration={"scaled_steps": 12},
        estimator_settings={"rls": {"correction": "approximation-error"}},
    )  # fmt: skip
    runs, _ = compare(config, None)
    assert runs["extrapolated"].tolist() == [0]
    assert "extrapolated" not in runs["warning"].iloc[0]
