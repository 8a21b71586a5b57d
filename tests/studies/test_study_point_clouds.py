"""The point-cloud study runs in --quick mode and shows its claim on numbers."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gmsh")


def test_clouds_identify_like_markers(study, tmp_path):
    module = study("point_clouds")
    table = module.compute(quick=True, out=tmp_path)
    assert (table["status"] == "ok").all(), table
    by = table.set_index("observe")
    assert {"markers", "cloud-points-200"} <= set(by.index)
    # a 200-point cloud without correspondence identifies about what 8 markers do
    E = by["E_ratio"]
    assert abs(E["cloud-points-200"] - E["markers"]) < 0.1
    # (the force of a force-controlled grasp, the applied load, is refused)
    assert np.isfinite(table["tre_mm"]).all() and (table["tre_mm"] > 0).all()
    module.plot(table, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 10_000
