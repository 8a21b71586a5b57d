"""The physical-stiffness study runs in --quick mode and shows its claim."""

from __future__ import annotations


def test_the_corrected_filter_covers_e_true_where_the_uncorrected_cannot(
    study, tmp_path
):
    module = study("physical_stiffness")
    runs = module.compute(quick=True, out=tmp_path)
    table = module.summarise(runs).set_index("mode")
    assert set(table.index) == {"uncorrected", "used", "not used"}
    # uncorrected: the mesh's effective E, confidently wrong about the tissue
    assert table.loc["uncorrected", "cover95_true"] == 0
    assert table.loc["uncorrected", "median_abs_err"] > 0.1
    # corrected (calibrated on the path's direction): the tissue's E
    assert table.loc["used", "cover95_true"] > table.loc["uncorrected", "cover95_true"]
    assert table.loc["used", "median_abs_err"] < 0.1 * table.loc[
        "uncorrected", "median_abs_err"
    ]
    module.plot(runs, tmp_path / "physical_stiffness.png")
    assert (tmp_path / "physical_stiffness.png").stat().st_size > 1000
