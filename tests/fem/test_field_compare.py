"""A field comparison end to end: planned, run, scored as a map, reported.

The cantilever as a body with a stiff inclusion field; its 12x3x3 mesh is
the truth, a 6x2x2 one the model, 24 cells. Estimators of fields run, the
full UKF skips it saying so, each run's row has the map metrics, and the
report draws maps and lists the map metrics instead of 24 x 7 columns.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.bodies import FIELD_MARKERS, write_beam_body

from idbench import ConfigError
from idbench.cli.commands import main
from idbench.plan.config import CompareConfig
from idbench.run.compare import compare

FIELD = """
[field]
cells = 24
length = 0.05
std = 0.5
[[field.inclusion]]
region = { sphere = { centre = [0.1, 0.015, 0.015], radius = 0.03 } }
contrast = 3.0
"""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("field")
    path, _ = write_beam_body(tmp, spec="12x3x3", markers=FIELD_MARKERS)
    write_beam_body(tmp, spec="6x2x2")  # the model's mesh file, beside it
    path.write_text(path.read_text() + FIELD)
    config = CompareConfig(
        model="solid", model_settings={"solid": {"body": str(path)}},
        scenarios=("end",), meshes=(str(tmp / "beam-6x2x2.vtu"),),
        truth_mesh="truth", estimators=("map-laplace", "local-etkf", "ukf"),
        estimator_settings={"local-etkf": {"members": 16, "init": "random",
                                           "localization": 0.1}},
        reference="map-laplace", steps=3, seeds=1, obs_points=(6,),
        prior=(5000.0, 2500.0),
    )  # fmt: skip
    out = tmp / "out"
    table, _ = compare(config, out)
    return table.set_index("estimator"), out


def test_field_estimators_run_and_the_full_ukf_skips_saying_so(runs):
    table, _ = runs
    assert table.loc["map-laplace", "status"] == "ok"
    assert table.loc["local-etkf", "status"] == "ok"
    assert table.loc["ukf", "status"] == "skipped"
    assert "field of 24 parameters" in table.loc["ukf", "error"]


def test_a_field_run_is_scored_as_a_map(runs):
    table, _ = runs
    row = table.loc["map-laplace"]
    for column in ("field_error", "field_rms_log", "inclusion_dice", "field_cover95"):
        assert np.isfinite(row[column]), column
    assert 0 <= row["field_cover95"] <= 1 and 0 <= row["inclusion_dice"] <= 1
    assert row["E_cell000_true"] > 0 and row["field_cells"].startswith("{")


def test_the_report_of_a_field_draws_maps_and_lists_map_metrics(runs, capsys):
    _, out = runs
    assert main(["report", str(out)]) == 0
    text = (out / "report.html").read_text()
    assert 'id="fig-maps"' in text
    assert "inclusion Dice" in text
    assert "E_cell003" not in text.split("<h2>Manifest")[0]


def _corrected(tmp, mesh: str, calibration: str):
    path = tmp / "beam-12x3x3-svk.toml"
    config = CompareConfig(
        model="solid", model_settings={"solid": {"body": str(path)}},
        scenarios=("end",), meshes=(mesh,), truth_mesh="truth",
        estimators=("map-laplace",),
        estimator_settings={"map-laplace": {"correction": "prior-mean"}},
        calibration={"mesh": calibration}, reference="map-laplace", steps=3,
        seeds=1, obs_points=(6,), prior=(5000.0, 2500.0),
    )  # fmt: skip
    table, _ = compare(config, None)
    return table.iloc[0]


def test_the_prior_mean_correction_adds_the_finer_mesh_offsets(runs):
    table, out = runs
    tmp = out.parent
    coarse = str(tmp / "beam-6x2x2.vtu")
    with pytest.raises(ConfigError, match=r"is model mesh .* itself"):
        _corrected(tmp, coarse, coarse)  # offsets of zero: refused at the door
    plain = table.loc["map-laplace"]
    cells = [c for c in table.columns if c.startswith("E_cell") and
             c.endswith("_final") and "_std" not in c]  # fmt: skip
    fine = _corrected(tmp, coarse, "truth")  # the 12x3x3 mesh's offsets
    assert fine["status"] == "ok"
    # the coarse mesh is too stiff (locking): corrected, it finds stiffer cells
    assert np.mean(np.log(fine[cells].astype(float) / plain[cells].astype(float))) > 0
