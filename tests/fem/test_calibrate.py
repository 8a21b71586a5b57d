"""The calibrated effective-stiffness map: interpolant, exact limit, CLI."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from idbench.cli.commands import main
from idbench.plan.config import ConfigError
from idbench_fem.tools.calibrate import (
    Calibration,
    CalibrationSettings,
    calibrate,
    direction,
    evaluate,
    reference_magnitude,
)

STRETCH, BEND = 250.0, 8.9



def synthetic(angles=(0.0, 10.0, 45.0, 90.0), steps=4) -> Calibration:
    rng = np.random.default_rng(3)
    rows = []
    for a in angles:
        for k in range(1, steps + 1):
            e = 5000.0 * rng.uniform(0.3, 1.1)
            m = k / steps * reference_magnitude(a, STRETCH, BEND)
            rows.append({"angle": a, "step": k, "fraction": k / steps,
                         "magnitude": m, "E_eff": e})  # fmt: skip
    settings = CalibrationSettings(
        mesh="4x1x1", angles=angles, steps=steps,
        stretch_magnitude=STRETCH, bend_magnitude=BEND,
    )  # fmt: skip
    return Calibration(pd.DataFrame(rows), settings)


def test_interpolant_reproduces_the_table_and_never_overshoots():
    cal = synthetic()
    for row in cal.table.itertuples():
        got = cal.E_eff(direction(row.angle), row.magnitude)
        assert got == pytest.approx(row.E_eff, rel=1e-10)
    table = cal.table.pivot(index="angle", columns="fraction", values="E_eff")
    lo, hi = table.min().min(), table.max().max()
    for a in np.linspace(0, 90, 37):
        for f in np.linspace(0.0, 1.3, 14):  # outside the levels: edge values
            e = cal.E_eff(direction(a, azimuth=30.0), f * cal.magnitude_at(a))
            assert lo - 1e-9 <= e <= hi + 1e-9


def test_bad_directions_magnitudes_and_settings_are_rejected():
    cal = synthetic()
    with pytest.raises(ValueError, match="compressive"):
        cal.E_eff((-1.0, 0.0, 0.0), 10.0)
    with pytest.raises(ValueError, match="magnitude -1"):
        cal.E_eff((1.0, 0.0, 0.0), -1.0)
    with pytest.raises(ValueError, match="non-zero 3-vector"):
        cal.E_eff((0.0, 0.0), 1.0)
    for bad in ({"angles": (0.0, 0.0)}, {"angles": (0.0, 95.0)}, {"steps": 1},
                {"nu": 0.5}, {"E_true": -2.0}, {"bend_magnitude": 0.0}):  # fmt: skip
        with pytest.raises(ConfigError, match=str(next(iter(bad)))):
            CalibrationSettings(mesh="4x1x1", **bad)


def test_a_model_on_the_truth_mesh_calibrates_to_E_true(tmp_path):
    settings = CalibrationSettings(mesh="6x2x2", truth_mesh="6x2x2",
                                   angles=(0.0, 90.0), steps=2)  # fmt: skip
    cal = calibrate(settings)
    np.testing.assert_allclose(cal.table["E_eff"], 5000.0, rtol=1e-6)
    cal.save(tmp_path)
    again = Calibration.load(tmp_path)
    d = direction(30.0)
    assert again.E_eff(d, 3.0) == pytest.approx(cal.E_eff(d, 3.0), rel=1e-12)
    assert set(pd.read_csv(tmp_path / "calibration.csv").columns) >= {
        "angle", "fraction", "magnitude", "E_eff", "ratio", "tip", "tip_angle",
    }  # fmt: skip


def test_calibration_beats_one_bending_constant_when_the_beam_is_stretched():
    settings = CalibrationSettings(mesh="6x2x2", truth_mesh="18x3x3",
                                   angles=(0.0, 2.0, 90.0), steps=3)  # fmt: skip
    cal = calibrate(settings)
    ratio = cal.table.set_index(["angle", "step"])["ratio"]
    assert ratio[(90.0, 3)] < 0.8 < 0.9 < ratio[(0.0, 3)]  # bending is stiffer
    scores = evaluate(cal, ("stretch-x",), steps=4, seeds=1).set_index("method")
    err = scores["shape_error_path"]
    assert err["calibrated"] < 0.5 * err["constant"]
    assert err["calibrated"] < 1.2 * err["E_true"]  # stretching hardly locks


def test_cli_writes_the_map_and_rejects_bad_input(tmp_path, capsys):
    out = tmp_path / "cal"
    argv = ["calibrate", "--mesh", "4x1x1", "--truth-mesh", "8x2x2",
            "--steps", "2", "--angles", "0,90", "--evaluate", "none",
            "--out", str(out), "-q"]  # fmt: skip
    assert main(argv) == 0
    assert len(pd.read_parquet(out / "calibration.parquet")) == 4
    assert set(pd.read_csv(out / "collapse.csv")["coordinates"]) == {
        "angle, fraction", "tip", "tip_angle",
    }  # fmt: skip
    for bad, message in (
        (["--angles", "0,120"], "angles (0.0, 120.0)"),
        (["--evaluate", "bend-q"], "unknown scenario 'bend-q'"),
        (["--steps", "x"], "--steps: invalid int value: 'x'"),
        (["--mesh", "nowhere.msh"], "nowhere.msh"),
        (["--evaluate-angles", "120"], "--evaluate-angles 120"),
    ):
        capsys.readouterr()
        assert main([*argv, *bad]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err and err.count("\n") == 1


def test_cli_reports_a_failed_solve_in_one_line(tmp_path, capsys):
    # E = 20 Pa inverts an element of the 4x1x1 beam at the first load level
    argv = ["calibrate", "--mesh", "4x1x1", "--truth-mesh", "8x2x2", "--steps", "2",
            "--angles", "0,90", "--E-true", "20", "--evaluate", "none", "-q",
            "--out", str(tmp_path)]  # fmt: skip
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "calibration failed: step 1" in err and "Traceback" not in err
