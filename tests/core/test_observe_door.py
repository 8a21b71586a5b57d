"""Observations that cannot identify anything are refused before any run.

Each case is one line on stderr, exit 2, nothing stored: force alone on a
force-controlled path (the force is the input), a camera inside the body,
looking away from it or seeing fewer surface pixels than the points asked
for, more markers than the model can place (refused before anything of that
size is allocated, naming the maximum), a ``[observe.NAME]`` table that
shadows a kind. A row's ``observe_kind`` is the kind that ran.
"""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import pytest
from support.helpers import tiny

from idbench.cli.commands import main
from idbench.plan.config import ConfigError
from idbench.run.compare import runs_of
from idbench.run.rows import base_row

TINY = ["--truth-mesh", "12x3x3", "--meshes", "4x1x1", "--steps", "3", "--seeds",
        "1", "--estimators", "rls"]  # fmt: skip


def refused(tmp_path: Path, capsys, *extra: str, toml: str = "") -> str:
    out = tmp_path / "out"
    config = []
    if toml:
        (tmp_path / "c.toml").write_text(toml)
        config = ["--config", str(tmp_path / "c.toml")]
    assert main(["compare", *TINY, "--out", str(out), *config, *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err and "unexpected" not in err, err
    assert not out.exists(), "nothing stored"
    return err


CASES = [
    (["--observe", "force"], "",
     ["scenario 'bend-y'", "observe 'force' uses only the model's reaction()",
      "the input, not a measurement"]),
    (["--observe", "cloud"], "[observe.cloud]\nposition = [0.1, 0.015, 0.015]\n",
     ["observe 'cloud'", "camera at [0.1, 0.015, 0.015] is inside the body"]),
    (["--observe", "cloud"],
     "[observe.cloud]\nposition = [0.1, -0.5, 0.5]\nlook_at = [0.1, -1.0, 1.0]\n",
     ["sees no part of the body (it looks away from it)"]),
    (["--observe", "cloud"], "[observe.cloud]\nresolution = [16, 12]\n",
     ["points = 500: the camera sees 16 distinct surface pixels",
      "ask for at most 16 points"]),
    (["--observe", "cloud"], "[observe.cloud]\nholes = 0.99\n",
     ["(holes = 0.99)", "ask for at most 12 points"]),
    (["--observe", "markers"], '[observe.markers]\nkind = "cloud"\n',
     ["[observe.markers] kind = 'cloud' shadows the observation model 'markers'"]),
    (["--observe", "cloud+force"], '[observe.force]\nkind = "cloud"\n',
     ["[observe.force] kind = 'cloud' shadows"]),
    (["--obs-points", "2,21"], "",
     ["obs_points = 21", "mesh '4x1x1' can place at most 20 markers"]),
]  # fmt: skip


@pytest.mark.parametrize(("extra", "toml", "words"), CASES)
def test_observations_that_cannot_work_are_one_line(
    tmp_path, capsys, extra, toml, words
) -> None:
    err = refused(tmp_path, capsys, *extra, toml=toml)
    for w in words:
        assert w in err, err


def test_markers_with_the_force_of_a_load_are_allowed():
    (spec,) = runs_of(tiny(observe=("markers+force",)))
    assert spec.observe == "markers+force"


def test_a_huge_marker_count_is_refused_before_it_is_allocated(tmp_path, capsys):
    tracemalloc.start()
    err = refused(tmp_path, capsys, "--obs-points", "100000")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert "100000 markers asked for" in err and "at most 20" in err, err
    assert peak < 50_000_000, f"{peak / 1e6:.0f} MB allocated"


def test_the_marker_limit_of_every_model_is_checked():
    with pytest.raises(ConfigError, match="at most 20 markers"):
        runs_of(tiny(meshes=("4x1x1",), truth_mesh="12x3x3", obs_points=(2, 50)))


def test_the_row_names_the_kind_that_ran():
    config = tiny(
        observe=("markers", "cloud-few", "cloud-few+force"),
        observe_settings={"cloud-few": {"kind": "cloud", "points": 20}},
    )
    kinds = {s.observe: base_row(s)["observe_kind"] for s in runs_of(config)}
    assert kinds == {"markers": "markers", "cloud-few": "cloud",
                     "cloud-few+force": "cloud+force"}  # fmt: skip
