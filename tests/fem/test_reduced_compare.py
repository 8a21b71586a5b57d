"""A reduced model chosen like a mesh: a comparison runs it against the full truth."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
from support.designs import write_designed_beam

import idbench
from idbench.plan.config import CompareConfig, ConfigError
from idbench.run.compare import compare
from idbench_fem.bodies.box import parse as beam_mesh


@pytest.fixture(scope="module")
def designed(tmp_path_factory):
    return write_designed_beam(tmp_path_factory.mktemp("designed"), "8x2x2")[0]


def config(body, **kw) -> CompareConfig:
    kw = {"steps": 4, "seeds": 1, "estimators": ("ro-ukf", "rls"),
          "truth_mesh": "truth", **kw}  # fmt: skip
    return CompareConfig(model="solid", scenarios=("end",),
                         model_settings={"solid": {"body": str(body)}},
                         prior=(3000.0, 2000.0), **kw)  # fmt: skip


def test_a_reduced_model_of_the_truth_mesh_runs_every_estimator(designed, tmp_path):
    runs, _ = compare(config(designed, meshes=("rom:truth:8",)), tmp_path / "o")
    assert set(runs["status"]) == {"ok"}, runs[["status", "error"]]
    # a reduction of the truth mesh: as many nodes as the truth, allowed
    assert (runs["model_nodes"] == runs["truth_nodes"]).all()
    # its own error, measured at step 4 (the last) of every run
    assert np.all(runs["reduction_residual"] > 0)
    assert np.all(np.abs(runs["E_final"] / 5000.0 - 1) < 0.05)


def test_a_reduced_model_keeps_the_mesh_checks(designed, tmp_path):
    # a reduction of the truth is allowed, not a truth coarser than what it reduces
    coarse = beam_mesh("4x2x2")
    path = tmp_path / "coarse.vtu"
    meshio.write(path, meshio.Mesh(coarse.points, [("tetra", coarse.tets)]))
    with pytest.raises(ConfigError, match="not finer"):
        compare(config(designed, meshes=("rom:truth:4",), truth_mesh=str(path)),
                tmp_path / "o")  # fmt: skip


def test_a_bad_reduced_spec_is_one_line(designed, tmp_path):
    with pytest.raises((ConfigError, ValueError)) as exc:
        compare(config(designed, meshes=("rom:truth:0",)), tmp_path / "o")
    assert "rom:MESH" in str(exc.value) and "\n" not in str(exc.value)


def test_the_solid_says_how_to_ask_for_one(capsys):
    from idbench.cli.commands import main

    assert main(["info", "solid"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "rom:MESH[:MODES[:SAMPLING]]" in text
    reg = idbench.build_registry()
    assert "rom:" in reg.models["solid"].defaults.mesh_help
