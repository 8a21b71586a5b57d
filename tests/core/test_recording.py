"""Recordings: simulate --record, compare --data, and bad recordings in one line."""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
import pytest
from support.helpers import registry_with
from support.recordings import edited_copy

import idbench
from idbench.cli.commands import main
from idbench.observe.surface import heldout_points_mm
from idbench.plan.config import CompareConfig
from idbench.report.write import write_report
from idbench.run.compare import compare
from idbench.run.record import record
from idbench.store import recording

TRUTH, MESH, STEPS = "20x3x3", "6x2x2", 4
ESTIMATORS = ("rls", "ro-ukf")
CLOUD = {"cloud": {"points": 60, "outliers": 0.05, "noise": 1e-4}}


def base(**kw: Any) -> dict[str, Any]:
    return {"steps": STEPS, "seeds": 1, "obs_every": (1,), "noise": (1e-4,), **kw}


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    root = tmp_path_factory.mktemp("recordings")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IDBENCH_CACHE_DIR", str(root / "cache"))
        argv = ["simulate", "--mesh", TRUTH, "--scenario", "bend-y", "--steps",
                str(STEPS), "--noise", "1e-4",
                "--record", str(root / "markers")]  # fmt: skip
        assert main(argv) == 0
        record(
            CompareConfig(truth_mesh=TRUTH, **base(observe=("cloud",),
                          observe_settings=CLOUD)),
            root / "cloud",
        )  # fmt: skip
    return root


def test_a_recording_round_trips_through_compare_data(recordings, tmp_path):
    for observe, settings in (("markers", {}), ("cloud", CLOUD)):
        synthetic, _ = compare(CompareConfig(
            truth_mesh=TRUTH, meshes=(MESH,), estimators=ESTIMATORS,
            **base(observe=(observe,), observe_settings=settings),
        ))  # fmt: skip
        out = tmp_path / observe
        argv = ["compare", "--data", str(recordings / observe), "--meshes", MESH,
                "--estimators", ",".join(ESTIMATORS), "--seeds", "1",
                "--obs-every", "1", "--out", str(out)]  # fmt: skip
        assert main(argv) == 0
        runs = pd.read_parquet(out / "runs.parquet")
        assert list(runs.status) == ["ok"] * 2, runs.error.tolist()
        np.testing.assert_allclose(runs.E_final, synthetic.E_final, rtol=1e-9)
        np.testing.assert_allclose(runs.E_ref, synthetic.E_ref, rtol=1e-9)
        np.testing.assert_allclose(runs.tre_final_mm, synthetic.tre_final_mm, rtol=1e-9)
        assert list(runs.n_solves) == list(synthetic.n_solves)
        assert runs.shape_error_final.isna().all()  # no truth mesh to compare
        assert (runs.heldout_final_mm > 0).all()
        traces = pd.read_parquet(out / "traces.parquet")
        assert traces.heldout_mm.notna().all() and traces.tre_mm.notna().all()
    write_report(out)  # no shape error anywhere: the report still draws
    assert main(["report", str(out), "--versus", "ro-ukf"]) == 0  # NaN truth nodes
    text = (out / "report.md").read_text()
    assert "TRE, hidden targets (mm)" in text and "held-out markers (mm)" in text


def test_the_manifest_reads_back(recordings):
    rec = recording.read(recordings / "cloud")
    assert (rec.model, rec.scenario, rec.observe, rec.steps) == (
        rec.model, "bend-y", "cloud", STEPS,
    )  # fmt: skip
    assert [f.step for f in rec.frames] == list(range(1, STEPS + 1))
    assert rec.held_out["targets"].shape == (STEPS, 1, 3)
    np.testing.assert_array_equal(rec.load, np.arange(1, STEPS + 1) / STEPS)
    sizes = {len(f.data["points"]) for f in rec.frames}
    assert all(n <= 60 for n in sizes)


def test_a_cloud_recording_holds_out_a_cloud_scored_on_the_surface(
    recordings, tmp_path
):
    rec = recording.read(recordings / "cloud")
    held = rec.held_out["points"]
    assert held.shape[0] == STEPS and held.shape[2] == 3 and held.shape[1] <= 60
    # a second draw of the camera's pixels, not the frames' points
    assert not np.array_equal(held[0][: len(rec.frames[0].data["points"])],
                              rec.frames[0].data["points"])  # fmt: skip
    # written and read back bit for bit
    again = recording.write(
        tmp_path / "again",
        tomllib.loads((recordings / "cloud" / recording.MANIFEST).read_text()),
        rec.frames, rec.held_out,
    )  # fmt: skip
    np.testing.assert_array_equal(recording.read(again).held_out["points"], held)
    # noise-free points on the truth's surface: the truth model scores ~0
    reg = idbench.build_registry()
    spec = idbench.ModelSpec(TRUTH, reg.scenario("bend-y"), n_steps=STEPS)
    truth = reg.model("svk-beam")(spec)
    u = truth.reset()
    for k in range(1, STEPS + 1):
        u = truth.step(np.array([rec.true["E"]]), k, u)
        assert heldout_points_mm(truth, u, held[k - 1]) < 1e-9
    # compare --data scores every step on them (a coarser model: > 0)
    out = tmp_path / "out"
    argv = ["compare", "--data", str(recordings / "cloud"), "--meshes", MESH,
            "--estimators", "ro-ukf", "--seeds", "1", "--obs-every", "1",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    traces = pd.read_parquet(out / "traces.parquet")
    assert (traces.heldout_points_mm > 0).all() and len(traces) == STEPS
    runs = pd.read_parquet(out / "runs.parquet")
    assert runs.heldout_points_final_mm.iloc[0] == traces.heldout_points_mm.iloc[-1]


class Box:
    """A model whose surface is the unit cube at every state."""

    def surface(self, state: Any) -> tuple[np.ndarray, np.ndarray]:
        v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                      [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float)
        t = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5],
                      [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
                      [3, 0, 4], [3, 4, 7]])  # fmt: skip
        return v, t


def test_heldout_points_mm_is_the_mean_distance_to_the_surface():
    pts = np.array([[0.5, 0.5, 1.002], [0.3, 0.4, -0.001], [0.5, 0.5, 0.5],
                    [np.nan, np.nan, np.nan]])  # fmt: skip
    # 2 mm and 1 mm outside, 500 mm inside; the NaN row (no point) left out
    assert heldout_points_mm(Box(), np.zeros(1), pts) == pytest.approx(503 / 3)
    assert np.isnan(heldout_points_mm(Box(), np.zeros(1), pts[3:]))
    assert np.isnan(heldout_points_mm(object(), np.zeros(1), pts))


def swap_times(d: dict[str, np.ndarray]) -> None:
    d["time"][[1, 2]] = d["time"][[2, 1]]


def nan_point(d: dict[str, np.ndarray]) -> None:
    d["frame.00002/points"][0, 1] = np.nan


def far_cloud(d: dict[str, np.ndarray]) -> None:
    d["frame.00003/points"] += np.array([5.0, 0.0, 0.0])


def flat_held_points(d: dict[str, np.ndarray]) -> None:
    d["held_out/points"] = d["held_out/points"][:, :, :2]


def far_held_points(d: dict[str, np.ndarray]) -> None:
    d["held_out/points"][2] += np.array([5.0, 0.0, 0.0])


def millimetres(d: dict[str, np.ndarray]) -> None:
    for k in d:
        if k.endswith("markers"):
            d[k] *= 1000.0


def partial_nan_marker(d: dict[str, np.ndarray]) -> None:
    d["frame.00002/markers"][4] = np.nan  # marker 2's y only


def infinite_marker(d: dict[str, np.ndarray]) -> None:
    d["frame.00003/markers"][0] = np.inf


def occlude(d: dict[str, np.ndarray]) -> None:
    """Marker 1 hidden at frame 2, marker 2 at frame 4, both at frame 3."""
    d["frame.00002/markers"][0:3] = np.nan
    d["frame.00003/markers"][:] = np.nan
    d["frame.00004/markers"][3:6] = np.nan


BAD = [
    ("markers", swap_times, None, "frame 3: time 2 s is not after frame 2's 3 s"),
    ("markers", swap_times, None, "frames out of order"),
    ("cloud", nan_point, None, "frame 2: the cloud points has 1 of"),
    ("cloud", far_cloud, None, "frame 3: the cloud points lies"),
    ("cloud", far_cloud, None, "not registered"),
    ("cloud", flat_held_points, None, "held_out/points of shape (4, 60, 2): need"),
    ("cloud", far_held_points, None, "frame 3: the cloud held_out/points lies"),
    ("markers", None, lambda t: t.replace('units = "m"', 'units = "mm"'),
     "units = 'mm' cannot be right"),
    ("markers", millimetres, None, "frame 1: markers moves"),
    ("markers", millimetres, None, 'units = "m" cannot be right'),
    ("markers", None, lambda t: t.replace('"bend-y"', '"twist"'),
     "load 'twist' is not one the body has"),
    ("markers", None, lambda t: t.replace("markers = 2", "markers = 3"),
     "frame 1: markers of shape (6,); markers = 3 needs 9"),
    ("cloud", None, lambda t: t.replace('observe = "cloud"', 'observe = "force"'),
     "frame 1: observe 'force' cannot read it (KeyError"),
    ("markers", partial_nan_marker, None,
     "frame 2: marker 2 of markers is NaN in y only; an occluded marker is NaN in"),
    ("markers", infinite_marker, None, "frame 3: marker 1 of markers is infinite"),
]  # fmt: skip


@pytest.mark.parametrize(("which", "arrays", "toml", "words"), BAD)
def test_a_bad_recording_is_one_line(
    recordings, tmp_path, capsys, which, arrays, toml, words
):
    bad = edited_copy(recordings / which, tmp_path / "bad", arrays, toml)
    argv = ["compare", "--data", str(bad), "--meshes", MESH, "--estimators", "rls",
            "--seeds", "1", "--out", str(tmp_path / "out")]  # fmt: skip
    assert main(argv) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert words in err, err
    assert "Traceback" not in err


def test_a_missing_frame_is_named(recordings, tmp_path):
    def drop(d: dict[str, np.ndarray]) -> None:
        for k in [k for k in d if k.startswith("frame.00003/")]:
            del d[k]

    bad = edited_copy(recordings / "markers", tmp_path / "bad", drop)
    with pytest.raises(recording.RecordingError, match="frame 3 has no data"):
        recording.read(bad)


def test_a_recording_written_by_hand_as_the_readme_says(tmp_path, monkeypatch):
    """Clouds of a different size every frame, no idbench writer, no truth mesh."""
    from idbench.run.compare import runs_of
    from idbench.run.session import Session
    from idbench.truth.simulate import simulate_path

    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path / "cache"))
    spec = runs_of(CompareConfig(truth_mesh=TRUTH, meshes=(MESH,), **base()))[0]
    truth = Session().model(spec, TRUTH, role="truth")
    states = simulate_path(truth, np.array([5000.0]))
    rng = np.random.default_rng(0)
    arrays: dict[str, Any] = {
        "time": np.array([0.0, 0.4, 0.5, 1.0]),
        "load": np.arange(1, STEPS + 1) / STEPS,
    }
    for k, u in enumerate(states, start=1):
        vertices, triangles = truth.surface(u)
        seen = np.unique(triangles)
        pick = rng.choice(seen, size=30 + 10 * k, replace=False)
        arrays[f"frame.{k:05d}/points"] = vertices[pick]
        arrays[f"frame.{k:05d}/origin"] = np.array([0.5, -2.0, 2.0])
        arrays[f"frame.{k:05d}/sigma"] = np.array(1e-4)
    arrays["held_out/markers"] = np.array([truth.observe(u) for u in states])
    arrays["held_out/targets"] = np.array([truth.targets(u) for u in states])
    folder = tmp_path / "mine"
    folder.mkdir()
    np.savez(folder / "frames.npz", **arrays)
    (folder / "recording.toml").write_text(
        f'format = 1\nunits = "m"\nmodel = "{spec.setup.model}"\n'
        'scenario = "bend-y"\nobserve = "cloud"\nnoise = 0.0001\nmarkers = 2\n'
        f'steps = {STEPS}\nheld_out = ["markers", "targets"]\n'
    )
    runs, traces = compare(CompareConfig(
        meshes=(MESH,), estimators=("ro-ukf",), seeds=1, obs_every=(1,),
        prior=(4000.0, 2000.0), data=str(folder),
    ))  # fmt: skip
    assert list(runs.status) == ["ok"], runs.error.tolist()
    assert runs.E_true.isna().all()  # the manifest gives no [true]
    markers, _ = compare(CompareConfig(
        truth_mesh=TRUTH, meshes=(MESH,), estimators=("ro-ukf",),
        **base(), prior=(4000.0, 2000.0),
    ))  # fmt: skip
    # the coarse beam identifies about what it identifies from markers
    assert abs(runs.E_final.iloc[0] / markers.E_final.iloc[0] - 1) < 0.05
    assert traces.tre_mm.notna().all() and traces.heldout_mm.notna().all()


ALL = ("batch-ls", "enkf", "etkf", "lms", "rls", "ro-ukf", "ukf")


def test_occluded_markers_are_assimilated_visible_only(recordings, tmp_path):
    """NaN markers round-trip through compare --data: finite, and they count."""
    occluded = edited_copy(recordings / "markers", tmp_path / "occluded", occlude)
    frames = recording.read(occluded).frames
    assert np.isnan(frames[2].data["markers"]).all()
    runs = {}
    for name, folder in (("full", recordings / "markers"), ("occluded", occluded)):
        out = tmp_path / name
        argv = ["compare", "--data", str(folder), "--meshes", MESH, "--estimators",
                ",".join(ALL), "--seeds", "1", "--obs-every", "1",
                "--out", str(out)]  # fmt: skip
        assert main(argv) == 0
        runs[name] = pd.read_parquet(out / "runs.parquet").set_index("estimator")
        traces = pd.read_parquet(out / "traces.parquet")
    full, occ = runs["full"], runs["occluded"]
    assert (occ.status == "ok").all(), occ.error.tolist()
    assert np.isfinite(occ.E_final).all() and np.isfinite(occ.E_ref).all()
    assert (occ.heldout_final_mm > 0).all()
    # fewer values seen: a different answer (a masked NaN would be no answer)
    assert not np.allclose(occ.E_final, full.E_final, rtol=1e-9)
    # frame 3 (every marker hidden) is a step without observation
    by_step = traces.groupby("step")["observed"].agg(["all", "any"])
    assert list(by_step["all"]) == list(by_step["any"]) == [True, True, False, True]
    ro_ukf = traces[traces.run_id == occ.loc["ro-ukf", "run_id"]]
    nis = ro_ukf.set_index("step").nis
    assert np.isfinite(nis[[1, 2, 4]]).all() and np.isnan(nis[3])


@dataclass
class PriorOnly:
    """An estimator on the bare protocol (not idbench.Filter): the prior."""

    def start(self, model, prior):  # type: ignore[no-untyped-def]
        self.model, self.state = model, model.reset()
        self.mean, self.std = np.asarray(prior.mean), np.asarray(prior.std)

    def update(self, k, observation):  # type: ignore[no-untyped-def]
        self.state = self.model.step(self.mean, k, self.state)
        return idbench.Estimate(self.mean, self.std, self.model.cost(), self.state)


class PriorOnlyPlugin:
    @idbench.hookimpl
    def register_estimators(self, register: Any) -> None:
        register("prior-only", PriorOnly)


def test_an_estimator_off_filter_is_refused_occluded_markers(recordings, tmp_path):
    occluded = edited_copy(recordings / "markers", tmp_path / "occluded", occlude)
    registry = registry_with({"prior-only": PriorOnlyPlugin()})
    config = CompareConfig(meshes=(MESH,), estimators=("prior-only",), seeds=1,
                           obs_every=(1,), data=str(occluded))  # fmt: skip
    runs, _ = compare(config, registry=registry)
    (row,) = runs.to_dict("records")
    assert row["status"] == "skipped"
    assert len(row["error"].splitlines()) == 1
    assert "'prior-only' cannot take occluded (NaN) observation entries" in row["error"]
    assert "(steps 2, 4)" in row["error"]  # step 3, all hidden, is no observation
    # the same recording without NaN: it runs
    config = dataclasses.replace(config, data=str(recordings / "markers"))
    runs, _ = compare(config, registry=registry)
    assert list(runs.status) == ["ok"], runs.error.tolist()


def test_simulated_occlusion_round_trips_through_a_recording(tmp_path, monkeypatch):
    """``markers.occlusion``: seeded NaN markers; the recording gives the same runs."""
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path / "cache"))
    hide = {"markers": {"occlusion": 0.4}}
    argv = ["simulate", "--mesh", TRUTH, "--scenario", "bend-y", "--steps",
            str(STEPS), "--noise", "1e-4", "--obs-points", "4",
            "--observe-option", "markers.occlusion=0.4",
            "--record", str(tmp_path / "rec")]  # fmt: skip
    assert main(argv) == 0
    rec = recording.read(tmp_path / "rec")
    markers = np.array([f.data["markers"] for f in rec.frames]).reshape(STEPS, 4, 3)
    hidden = np.isnan(markers).all(axis=2)
    assert (np.isnan(markers).any(axis=2) == hidden).all()  # whole markers only
    assert 0 < hidden.sum() < hidden.size  # some hidden, some seen
    # the visible values are those without occlusion (drawn after the noise)
    argv[argv.index("markers.occlusion=0.4")] = "markers.occlusion=0"
    argv[-1] = str(tmp_path / "plain")
    assert main(argv) == 0
    plain = recording.read(tmp_path / "plain").frames
    seen = np.array([f.data["markers"] for f in plain]).reshape(STEPS, 4, 3)
    np.testing.assert_array_equal(markers[~hidden], seen[~hidden])
    synthetic, _ = compare(CompareConfig(
        truth_mesh=TRUTH, meshes=(MESH,), estimators=ALL,
        **base(observe=("markers",), observe_settings=hide, obs_points=(4,)),
    ))  # fmt: skip
    recorded, _ = compare(CompareConfig(
        meshes=(MESH,), estimators=ALL, seeds=1, obs_every=(1,),
        data=str(tmp_path / "rec"),
    ))  # fmt: skip
    assert list(recorded.status) == ["ok"] * len(ALL), recorded.error.tolist()
    assert np.isfinite(recorded.E_final).all()
    np.testing.assert_allclose(recorded.E_final, synthetic.E_final, rtol=1e-9)
    np.testing.assert_allclose(recorded.E_ref, synthetic.E_ref, rtol=1e-9)


def test_a_bad_occlusion_is_one_line(tmp_path, capsys):
    argv = ["simulate", "--mesh", TRUTH, "--scenario", "bend-y", "--steps", "2",
            "--observe-option", "markers.occlusion=1.5",
            "--record", str(tmp_path / "rec")]  # fmt: skip
    assert main(argv) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "occlusion = 1.5 is not allowed" in err and "0 <= occlusion < 1" in err
