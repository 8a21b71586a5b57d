"""The organ study runs in --quick mode and shows its claim on one number."""

from __future__ import annotations

import pytest

pytest.importorskip("gmsh")


def test_organ_coarse_liver_identifies_a_low_E_and_assimilation_helps(study, tmp_path):
    module = study("organ_discretization")
    table = module.compute(quick=True, out=tmp_path)
    assert set(table["law"]) == {"svk", "neo-hookean"}
    nh = table[(table["law"] == "neo-hookean") & (table["scenario"] == "grasp-lift")]
    coarse = nh.sort_values("model_nodes").iloc[0]
    # the coarse mesh is stiffer: it identifies a low E, and assimilating the
    # markers moves the body closer to the truth than E_true does
    assert coarse["E_ratio"] < 0.9
    assert coarse["shape_error"] < 0.8 * coarse["shape_error_direct"]
    module.plot(table, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 10_000
