"""What a run shows is stored beside its results: surfaces per stored step,
checked like the rest of a results folder on resume and when read."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from support.helpers import STEPS, tiny

import idbench
from idbench.report.scene import read_scenes
from idbench.report.write import write_report
from idbench.run.compare import compare
from idbench.store import surfaces
from idbench.store.results import ResultsError


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("surfaces") / "out"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IDBENCH_CACHE_DIR", str(out.parent / "cache"))
        compare(tiny(estimators=("rls", "lms")), out)
    return out


def test_stored_steps_every_step_then_every_kth_and_the_last():
    assert surfaces.stored_steps(5) == [1, 2, 3, 4, 5]
    assert surfaces.stored_steps(surfaces.MAX_STEPS) == list(range(1, 51))
    long = surfaces.stored_steps(121)  # k = 3
    assert long[:3] == [3, 6, 9] and long[-2:] == [120, 121]
    assert len(long) <= surfaces.MAX_STEPS + 1


def test_each_run_stores_its_surface_at_every_step(folder):
    runs = pd.read_parquet(folder / "runs.parquet")
    for run_id in runs["run_id"]:
        arrays = surfaces.load(folder / "surfaces" / f"run-{run_id}.npz")
        assert list(arrays["steps"]) == list(range(1, STEPS + 1))
        mesh = surfaces.load(folder / "surfaces" / f"mesh-{arrays['mesh_key']}.npz")
        assert arrays["displacement"].dtype == np.float32
        assert arrays["displacement"].shape == (STEPS, len(mesh["vertices"]), 3)
        assert mesh["triangles"].max() == len(mesh["vertices"]) - 1  # compact
        truth = folder / "surfaces" / f"truth-{arrays['truth_key']}.npz"
        assert surfaces.load(truth)["displacement"].shape[0] == STEPS
    assert not {c for c in runs.columns if c.startswith("_")}  # not a column


def test_each_run_stores_its_markers_and_its_targets(folder):
    from idbench.score.metrics import ellipsoid_covers

    runs = pd.read_parquet(folder / "runs.parquet").set_index("run_id")
    for run_id, row in runs.iterrows():
        arrays = surfaces.load(folder / "surfaces" / f"run-{run_id}.npz")
        seen, predicted = arrays["markers_observed"], arrays["markers_predicted"]
        assert seen.dtype == np.float32 and seen.shape == (STEPS, 2, 3)  # 2 markers
        assert predicted.shape == seen.shape and np.isfinite(predicted).all()
        observed = np.isfinite(seen).all(axis=(1, 2))  # obs_every = 2
        assert list(observed) == [k % 2 == 0 for k in range(1, STEPS + 1)]
        assert np.abs(seen[observed] - predicted[observed]).max() < 0.01  # m
        true, moved = arrays["targets_true"], arrays["targets_predicted"]
        assert true.shape == moved.shape == (STEPS, 1, 3)  # the beam's target
        error = true[-1].astype(float) - moved[-1]
        tre = 1000 * np.linalg.norm(error, axis=1).mean()
        assert tre == pytest.approx(row["tre_final_mm"], rel=1e-4, abs=1e-6)
        cov = arrays["targets_cov"]  # the scores' own: the same coverage
        assert cov.shape == (1, 3, 3) and cov.dtype == np.float64
        covered = ellipsoid_covers(error[0], cov[0])  # NaN: no std (LMS)
        np.testing.assert_equal(covered, row["tre_covered_final"])
        assert np.isfinite(cov).all() == np.isfinite(row["tre_covered_final"])


def test_stored_points_that_do_not_fit_their_steps_are_refused(folder, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(folder, out)
    path = next((out / "surfaces").glob("run-*.npz"))
    arrays = surfaces.load(path)
    arrays["targets_true"] = arrays["targets_true"][1:]  # digest made anew
    surfaces._save(path, path.stem.partition("-")[2], arrays)
    scenes = read_scenes(out, pd.read_parquet(out / "runs.parquet"))
    assert "targets_true" in scenes.problem and scenes.runs == {}


def test_a_markers_block_is_read_from_its_frames_and_no_markers_store_none():
    from idbench.core.interfaces import Observation
    from idbench.observe import kinds

    registry = idbench.build_registry()
    spec = idbench.ModelSpec(mesh="4x1x1", scenario=registry.scenario("bend-y"),
                             n_steps=2, markers=2)  # fmt: skip
    model = registry.model("svk-beam")(spec)
    theta = np.array([5000.0])
    states = [model.step(theta, 1, model.reset())]
    states.append(model.step(theta, 2, states[0]))
    values = [model.observe(u) + 1e-3 for u in states]
    frames = [kinds.Frame(k, {"markers/markers": values[k - 1],
                              "force/force": np.zeros(3)}) for k in (1, 2)]  # fmt: skip
    keys = {"run_id": "r", "mesh_key": "m", "truth_key": "t"}
    found = {}
    for observe in ("markers+force", "force"):
        recorder = surfaces.Recorder(model, 2, keys, kinds.build(observe, {}), frames)
        recorder.step(1, states[0], Observation(np.zeros(9), 1e-3, 1))
        recorder.step(2, states[1], None)  # step 2 not observed
        found[observe] = recorder.arrays()
    points = model.marker_points
    seen = found["markers+force"]["markers_observed"]
    np.testing.assert_allclose(seen[0], points + values[0].reshape(-1, 3), atol=1e-6)
    assert np.isnan(seen[1]).all()
    assert not {n for n in found["force"] if n.startswith("markers")}
    assert not {n for n in found["force"] if n.startswith("targets")}  # no truth


def test_the_scenes_set_each_run_against_its_truth(folder):
    runs = pd.read_parquet(folder / "runs.parquet")
    scenes = read_scenes(folder, runs)
    assert scenes.problem == "" and set(scenes.runs) == set(runs["run_id"])
    for scene in scenes.runs.values():
        assert scene.error_mm.shape == scene.shown.displacement.shape[:2]
        assert np.all(np.isfinite(scene.error_mm)) and scene.error_mm.max() > 0


def test_a_mesh_surface_of_other_content_is_refused_on_resume(folder, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(folder, out)
    path = next((out / "surfaces").glob("mesh-*.npz"))
    arrays = surfaces.load(path)
    arrays["described"] = np.array("0" * 24)  # made from another mesh file
    surfaces._save(path, path.stem.partition("-")[2], arrays)
    with pytest.raises(ResultsError, match="of another content"):
        compare(tiny(estimators=("rls", "lms")), out)
    runs = pd.read_parquet(out / "runs.parquet")
    assert "another content" in read_scenes(out, runs).problem


def test_an_altered_run_surface_is_named_not_shown(folder, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(folder, out)
    path = next((out / "surfaces").glob("run-*.npz"))
    with np.load(path) as data:
        arrays = {k: np.array(data[k]) for k in data.files}
    arrays["displacement"] = arrays["displacement"] * 2  # digest kept: altered
    np.savez(path, **arrays)
    scenes = read_scenes(out, pd.read_parquet(out / "runs.parquet"))
    assert "altered" in scenes.problem and path.name in scenes.problem
    assert scenes.runs == {}
    write_report(out)  # the report says so, and draws no still of it
    assert "No 3D view: this folder fails its checks" in (out / "report.md").read_text()
    assert not list(out.glob("view_*.png"))


def test_the_report_has_stills_of_the_best_and_the_worst_run(folder, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(folder, out)
    write_report(out)
    text = (out / "report.md").read_text()
    assert "![view_best](view_best.png)" in text
    assert "![view_worst](view_worst.png)" in text
    assert (out / "view_best.png").stat().st_size > 5000


def test_a_resume_keeps_the_stored_surfaces(folder, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(folder, out)
    before = {p.name: p.read_bytes() for p in (out / "surfaces").iterdir()}
    compare(tiny(estimators=("rls", "lms")), out)
    after = {p.name: p.read_bytes() for p in (out / "surfaces").iterdir()}
    assert after == before
