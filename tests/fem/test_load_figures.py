"""The same load on every mesh, or a measured difference.

On a coarse mesh of a curved body (the synthetic organ, 150 against 1,200
nodes) a pressure inside a sphere captures less area, and so less force,
than on the truth; the solid model reports its load figures, runs store
their ratios to the truth's, the summary flags them, and ``conserve =
"resultant"`` gives every mesh the truth's resultant.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.helpers import ORGAN_BODY, organ_body

import idbench
from idbench.plan.config import CompareConfig
from idbench.report.text import summary_text
from idbench.run.compare import compare
from idbench_fem.bodies.description import parse_body
from idbench_fem.models.solid import make_model, scenario_of


@pytest.fixture(scope="module")
def body(tmp_path_factory):
    return organ_body(tmp_path_factory.mktemp("organ"))


def models(body, name):
    out = {}
    for mesh in ("150", "1200"):
        spec = idbench.ModelSpec(mesh, scenario_of(str(body), name), n_steps=2)
        out[mesh] = make_model(spec)
    return out


def ratios(body, name):
    coarse, fine = (m.load_figures() for m in models(body, name).values())
    return {k: coarse[k] / fine[k] if fine[k] else np.nan for k in fine}


def test_a_pressure_in_a_sphere_captures_less_on_a_coarse_mesh(body):
    r = ratios(body, "push")
    assert r["area"] < 0.9 and r["resultant"] < 0.9
    assert 0.9 < r["volume"] < 0.99 and r["mass"] == pytest.approx(r["volume"])
    assert r["fixed_area"] != pytest.approx(1.0, abs=0.02)


def test_conserve_gives_every_mesh_the_truths_resultant(body):
    plain = models(body, "push")
    kept = models(body, "push-conserved")
    assert kept["1200"].load_factor == 1.0  # the reference itself: exactly
    assert kept["150"].load_factor == pytest.approx(
        plain["1200"].load_figures()["resultant"]
        / plain["150"].load_figures()["resultant"], rel=1e-12
    )
    r = ratios(body, "push-conserved")
    assert abs(r["resultant"] - 1) < 1e-9
    assert r["area"] == pytest.approx(ratios(body, "push")["area"], rel=1e-12)
    # the truth's nodal loads are untouched by conserve
    f = [m.external_force(2) for m in (plain["1200"], kept["1200"])]
    assert np.array_equal(f[0], f[1])
    loaded = plain["150"].external_force(2) != 0
    scaled = kept["150"].external_force(2)[loaded] / plain["150"].external_force(2)[
        loaded
    ]
    assert np.allclose(scaled, kept["150"].load_factor, rtol=1e-12)


def test_conserved_gravity_keeps_the_truths_mass(body):
    r = ratios(body, "sag")
    assert abs(r["resultant"] - 1) < 1e-9 and abs(r["mass"] - 1) < 1e-9
    assert r["volume"] < 0.99 and r["area"] != r["area"]  # no loaded area: NaN


def test_a_grasp_is_the_same_force_on_every_mesh(body):
    assert abs(ratios(body, "lift")["resultant"] - 1) < 1e-12


def test_runs_store_the_ratios_and_the_summary_flags_the_push(body, tmp_path):
    config = CompareConfig(
        model="solid", model_settings={"solid": {"body": str(body)}},
        scenarios=("push", "push-conserved"), meshes=("150",), truth_mesh="1200",
        estimators=("rls",), seeds=1, steps=2, obs_every=(1,), noise=(1e-5,),
    )  # fmt: skip
    runs, _ = compare(config, tmp_path / "out", registry=idbench.build_registry())
    assert (runs["status"] == "ok").all()
    by = runs.set_index("scenario")
    assert by.loc["push", "load_resultant_ratio"] < 0.9
    assert abs(by.loc["push-conserved", "load_resultant_ratio"] - 1) < 1e-9
    text = summary_text(runs)
    flagged = text[text.index("load: ") :].splitlines()
    assert flagged[0].startswith("load: 2 row(s)")  # the conserved moment differs
    push = next(line for line in flagged if line.startswith("  push 150:"))
    assert "resultant 0." in push and "area 0." in push
    conserved = next(line for line in flagged if "push-conserved" in line)
    assert "resultant" not in conserved


def test_conserve_is_checked_when_parsed():
    import tomllib

    raw = tomllib.loads(ORGAN_BODY)
    raw["manipulation"][0]["conserve"] = "force"
    with pytest.raises(ValueError, match=r"conserve = 'force': allowed are none, r"):
        parse_body(raw, "organ.toml")
    raw["manipulation"][0] = {
        "name": "raise", "kind": "grasp", "point": [0.03, 0.0, 0.03],
        "radius": 0.01, "displacement": [0, 0, 0.002], "conserve": "resultant",
    }  # fmt: skip
    with pytest.raises(ValueError, match="displacement-controlled grasp puts no"):
        parse_body(raw, "organ.toml")
