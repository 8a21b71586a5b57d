"""The physical-stiffness study runs in --quick mode and shows its claim."""

from __future__ import annotations


def test_the_corrected_filter_covers_e_true_where_the_uncorrected_cannot(
    study, tmp_path
):
    module = study("physical_stiffness")
    runs = module.compute(quick=True, out=tmp_path)
    table = module.summarise(runs).set_index(["body", "mode"])
    modes = ("uncorrected", "used", "not used")
    assert set(table.index) == {(b, m) for b in ("beam", "liver") for m in modes}
    for body in ("beam", "liver"):
        plain = table.loc[(body, "uncorrected")]
        # uncorrected: the mesh's effective E, confidently wrong about the tissue
        assert plain["cover95_true"] == 0
        assert plain["median_abs_err"] > 0.1
        # corrected, on the paths' own directions and on a design of others
        for mode in ("used", "not used"):
            row = table.loc[(body, mode)]
            assert row["cover95_true"] > plain["cover95_true"], (body, mode)
            assert row["median_abs_err"] < 0.25 * plain["median_abs_err"], (body, mode)
    module.plot(runs, tmp_path / "physical_stiffness.png")
    assert (tmp_path / "physical_stiffness.png").stat().st_size > 1000
