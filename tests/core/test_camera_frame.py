"""A recording in the camera's frame: registered to each mesh before any run."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

import idbench
from idbench.cli.commands import main
from idbench.observe.kinds import Frame
from idbench.plan.config import CompareConfig
from idbench.run.record import record
from idbench.store import recording

TRUTH, MESH, STEPS = "20x3x3", "6x2x2", 4
CLOUD = {"cloud": {"points": 60, "outliers": 0.0, "noise": 1e-4}}
ANGLE = 8.0  # degrees, about (1, 1, 0)
SHIFT = np.array([0.004, -0.003, 0.002])  # m
R = Rotation.from_rotvec(np.radians(ANGLE) * np.array([1, 1, 0]) / np.sqrt(2))


def to_camera(points: np.ndarray) -> np.ndarray:
    """Body positions in the camera's frame: p = R p_c + t."""
    return (np.asarray(points) - SHIFT) @ R.as_matrix()


def rest_cloud(n: int = 400, seed: int = 3) -> np.ndarray:
    """Points on the beam's rest surface (truth mesh), with noise, camera frame."""
    reg = idbench.build_registry()
    model = reg.model("svk-beam")(
        idbench.ModelSpec(TRUTH, reg.scenario("bend-y"), STEPS, 2)
    )
    vertices, triangles = model.surface(model.reset())
    rng = np.random.default_rng(seed)
    tri = vertices[triangles[rng.integers(len(triangles), size=n)]]
    w = rng.dirichlet(np.ones(3), size=n)
    pts = np.einsum("ni,nij->nj", w, tri) + 1e-5 * rng.standard_normal((n, 3))
    return to_camera(pts)


def write_camera_copy(source: Path, dest: Path, rest: np.ndarray | None) -> Path:
    """``source`` (a body-frame cloud recording) seen by a camera at R, t."""
    rec = recording.read(source)
    manifest = tomllib.loads((source / recording.MANIFEST).read_text())
    for key in ("format", "units"):
        manifest.pop(key)
    manifest["frame"] = "camera"
    frames = [
        Frame(f.step, {**f.data, "points": to_camera(f.data["points"]),
                       "origin": to_camera(f.data["origin"][None, :])[0]})
        for f in rec.frames
    ]  # fmt: skip
    held = dict(rec.held_out)
    held["points"] = to_camera(held["points"].reshape(-1, 3)).reshape(
        held["points"].shape
    )
    for name in ("markers", "targets"):  # displacements: turned only
        if name in held:
            v = held[name]
            held[name] = (v.reshape(-1, 3) @ R.as_matrix()).reshape(v.shape)
    return recording.write(dest, manifest, frames, held, rec.time, rest=rest)


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    root = tmp_path_factory.mktemp("camera")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IDBENCH_CACHE_DIR", str(root / "cache"))
        body = record(
            CompareConfig(truth_mesh=TRUTH, steps=STEPS, seeds=1, obs_every=(1,),
                          noise=(1e-4,), observe=("cloud",), observe_settings=CLOUD),
            root / "body",
        )  # fmt: skip
        camera = write_camera_copy(body, root / "camera", rest_cloud())
        yield root, body, camera


def run(data: Path, out: Path) -> pd.DataFrame:
    argv = ["compare", "--data", str(data), "--meshes", MESH,
            "--estimators", "rls,ro-ukf", "--seeds", "1", "--obs-every", "1",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    return pd.read_parquet(out / "runs.parquet")


def test_a_camera_recording_is_registered_and_gives_the_body_frame_numbers(
    clouds, tmp_path
):
    _, body, camera = clouds
    seen = run(body, tmp_path / "body")
    moved = run(camera, tmp_path / "camera")
    assert list(moved.status) == ["ok", "ok"], moved.error.tolist()
    # the transform found is the camera's, to a fraction of the cloud's noise
    assert moved.registration_angle_deg.to_numpy() == pytest.approx(ANGLE, abs=0.02)
    assert moved.registration_shift_mm.to_numpy() == pytest.approx(
        1e3 * np.linalg.norm(SHIFT), abs=0.02
    )
    assert (moved.registration_rms_mm < 0.05).all()
    assert (moved.registration_inliers > 0.95).all()
    np.testing.assert_allclose(moved.E_final, seen.E_final, rtol=2e-3)
    np.testing.assert_allclose(
        moved.heldout_final_mm, seen.heldout_final_mm, rtol=0.05
    )  # held-out clouds moved too
    assert "registration_rms_mm" not in seen  # a body-frame recording has none


def test_camera_recordings_that_cannot_work_are_one_line(clouds, tmp_path, capsys):
    _, body, _ = clouds
    far = 5.0 + np.random.default_rng(0).standard_normal((50, 3))
    cases = {
        "no rest": (write_camera_copy(body, tmp_path / "a", None), "needs rest/points"),
        "far": (write_camera_copy(body, tmp_path / "b", far),
                f"does not register to mesh {MESH!r}"),
    }  # fmt: skip
    body_with_rest = write_camera_copy(body, tmp_path / "c", rest_cloud())
    text = (body_with_rest / recording.MANIFEST).read_text()
    (body_with_rest / recording.MANIFEST).write_text(
        text.replace('frame = "camera"', 'frame = "body"')
    )
    cases["rest in a body frame"] = (body_with_rest, 'only read with frame = "camera"')
    for name, (data, words) in cases.items():
        capsys.readouterr()
        argv = ["compare", "--data", str(data), "--meshes", MESH, "--estimators",
                "rls", "--out", str(tmp_path / f"out-{name}")]  # fmt: skip
        assert main(argv) == 2, name
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err, (name, err)
        assert len(err.strip().splitlines()) == 1, (name, err)
        assert not (tmp_path / f"out-{name}").exists(), name  # nothing stored


def channel_cloud(n: int = 300, seed: int = 3) -> np.ndarray:
    """The middle of the beam's top and side faces, a channel (camera frame).

    Nothing in it holds the pose along the beam: the rigid registration
    leaves the axial shift where its start put it.
    """
    reg = idbench.build_registry()
    model = reg.model("svk-beam")(
        idbench.ModelSpec(TRUTH, reg.scenario("bend-y"), STEPS, 2)
    )
    vertices = model.surface(model.reset())[0]
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    rng = np.random.default_rng(seed)
    x = lo[0] + (hi[0] - lo[0]) * rng.uniform(0.3, 0.7, n)
    u, face = rng.uniform(0, 1, n), rng.integers(3, size=n)
    y = np.where(face == 0, hi[1], lo[1] + (hi[1] - lo[1]) * u)
    z = np.where(face == 0, lo[2] + (hi[2] - lo[2]) * u,
                 np.where(face == 1, lo[2], hi[2]))  # fmt: skip
    points = np.stack([x, y, z], axis=1)
    return to_camera(points + 1e-5 * rng.standard_normal((n, 3)))


def test_the_model_refines_a_pose_the_rest_cloud_leaves_loose(clouds, tmp_path):
    _, body, _ = clouds
    camera = write_camera_copy(body, tmp_path / "patch", channel_cloud())
    rows = {}
    for mode, data in (("body", body), ("rigid", camera), ("with-model", camera)):
        argv = ["compare", "--data", str(data), "--meshes", TRUTH, "--estimators",
                "rls", "--seeds", "1", "--obs-every", "1",
                "--out", str(tmp_path / mode),
                *(["--registration", mode] if mode != "body" else [])]  # fmt: skip
        assert main(argv) == 0
        rows[mode] = pd.read_parquet(tmp_path / mode / "runs.parquet").iloc[0]
    seen, rigid, refined = rows["body"], rows["rigid"], rows["with-model"]
    # the frames, through the model, put the pose back to a fraction of the noise
    assert refined.registration_angle_deg == pytest.approx(ANGLE, abs=0.05)
    assert refined.registration_shift_mm == pytest.approx(
        1e3 * np.linalg.norm(SHIFT), abs=0.1
    )
    assert refined.registration_refined_mm > 3.0  # what the model moved
    assert "registration_refined_mm" not in rigid
    assert refined.status == "ok"
    # the channel alone leaves the pose millimetres off, and that goes into E
    assert abs(rigid.E_final / seen.E_final - 1) > 0.03, rigid.E_final
    assert refined.E_final == pytest.approx(seen.E_final, rel=0.003)


def test_refine_fits_the_pose_and_the_moduli_together(clouds, tmp_path):
    from idbench.calibrate.pose import refine
    from idbench.observe.registration import transform_error
    from idbench.store import registered

    _, body, _ = clouds
    rec = recording.read(write_camera_copy(body, tmp_path / "p", channel_cloud()))
    reg = idbench.build_registry()
    model = reg.model("svk-beam")(
        idbench.ModelSpec(TRUTH, reg.scenario("bend-y"), STEPS, 2)
    )
    vertices, triangles = model.surface(model.reset())
    moved, rigid = registered.to_body(rec, vertices, triangles)
    prior = model.parameters.prior(2000.0, 2000.0)  # far from the true 5,000 Pa
    found = refine(moved, rigid, model, prior, registered.noise_floor(rec))
    angle, shift = transform_error(found.fit, R.as_matrix(), SHIFT, rec.rest)
    assert angle < 0.05 and shift < 1e-4  # degrees, m (the clouds' noise)
    assert found.theta[0] == pytest.approx(5000.0, rel=0.005)
    assert found.paths >= 2 * found.iterations  # a path per modulus and step


def test_with_model_needs_a_camera_recording(clouds, tmp_path, capsys):
    _, body, _ = clouds
    for data in (["--data", str(body)], []):
        argv = ["compare", *data, "--registration", "with-model", "--estimators",
                "rls", "--out", str(tmp_path / "out")]  # fmt: skip
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "registration 'with-model'" in err and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1
        assert not (tmp_path / "out").exists()
