"""The stiffness-maps study in --quick mode: on the truth's own mesh the map
finds the inclusion stiffer; a coarse mesh's own error hides it, and the
prior-mean correction takes part of that error away."""

from __future__ import annotations


def test_the_inclusion_shows_on_the_truth_mesh_and_drowns_on_a_coarse_one(
    study, tmp_path
):
    module = study("stiffness_maps")
    table = module.compute(quick=True, out=tmp_path)
    assert (table["status"] == "ok").all()
    by = table.set_index(["estimator", "mesh", "corrected"])
    control = by.loc[("map-laplace", "truth's", False)]
    coarse = by.loc[("map-laplace", "500", False)]
    corrected = by.loc[("map-laplace", "500", True)]
    assert control["found_contrast"] > 1.1  # truth: 3, smoothed by the prior
    assert control["field_cover95"] >= 0.9
    assert coarse["found_contrast"] < control["found_contrast"]
    assert corrected["field_error"] < coarse["field_error"]
    module.plot(table, tmp_path / "maps.png")
    assert (tmp_path / "maps.png").stat().st_size > 10_000
    assert "| kidney | 3 |" in module.markdown(table.drop(columns=["map"]))
