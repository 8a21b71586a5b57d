"""Observation models: the depth camera, its residual, force, combinations.

Small meshes (a 9x2x2 beam, a truth of 14x3x3) and few steps; the truth cache
is per-session (conftest).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from support.helpers import registry_with
from support.toymodels import SensitiveLinearToy

import idbench
from idbench.cli.commands import main
from idbench.core.interfaces import Observation
from idbench.observe import kinds, surface
from idbench.observe.camera import render
from idbench.observe.cloud import Cloud
from idbench.observe.surface import point_to_surface
from idbench.plan.config import CompareConfig, ConfigError
from idbench.run.compare import compare, runs_of
from idbench.run.session import Session

CUBE = np.array(
    [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
     [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float,
)  # fmt: skip
CUBE_TRIANGLES = np.array(
    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
     [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]],
)  # fmt: skip


def beam(mesh: str = "9x2x2", steps: int = 4) -> Any:
    reg = idbench.build_registry()
    spec = idbench.ModelSpec(mesh=mesh, scenario=reg.scenario("bend-y"), n_steps=steps)
    return reg.model("svk-beam")(spec)


def path(model: Any, E: float) -> list[np.ndarray]:
    u, out = model.reset(), []
    for k in range(1, model.n_steps + 1):
        u = model.step(np.array([E]), k, u)
        out.append(u)
    return out


# --- the camera ---------------------------------------------------------------


def test_the_z_buffer_sees_only_the_front_of_a_box():
    # a cube, and a small box hidden right behind it: looking down from z = 5
    hidden = CUBE * 0.5 + [0.25, 0.25, -1.0]
    vertices = np.concatenate([CUBE, hidden])
    triangles = np.concatenate([CUBE_TRIANGLES, CUBE_TRIANGLES + 8])
    hits, depth, rays = render(
        vertices, triangles, np.array([0.5, 0.5, 5.0]), np.array([0.5, 0.5, 0.0]),
        (64, 48), 30.0,
    )  # fmt: skip
    assert len(hits) > 100
    np.testing.assert_allclose(hits[:, 2], 1.0, atol=1e-12)  # the top face only
    assert np.all(hits[:, 2] > 0.5)  # nothing behind it, nor the hidden box
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    np.testing.assert_allclose(depth, np.linalg.norm(hits - [0.5, 0.5, 5.0], axis=1))


def test_the_z_buffer_is_not_a_normal_test():
    # the hidden box alone, its triangles flipped (normals inward): still seen
    hits, _, _ = render(
        CUBE, CUBE_TRIANGLES[:, ::-1].copy(), np.array([0.5, 0.5, 5.0]),
        np.array([0.5, 0.5, 0.0]), (32, 24), 30.0,
    )  # fmt: skip
    np.testing.assert_allclose(hits[:, 2], 1.0, atol=1e-12)


def clean_cube(origin: Any = (0.5, 0.5, 5.0)) -> dict[str, np.ndarray]:
    o = np.array(origin, dtype=float)
    hits, depth, rays = render(
        CUBE, CUBE_TRIANGLES, o, np.zeros(3) + 0.5, (40, 30), 20.0
    )
    return {"hits": hits, "depth": depth, "rays": rays, "origin": o}


def test_noise_is_along_the_ray():
    clean = clean_cube()
    cloud = Cloud(points=2000, noise=0.01)
    (frame,) = cloud.measure([clean], np.random.default_rng(3), 0.0)
    p = frame["points"]
    d = p - clean["origin"]
    t = np.linalg.norm(d, axis=1)
    # each point lies on one of the pixel rays, at the hit's depth plus noise
    cos = (d / t[:, None]) @ clean["rays"].T
    j = np.argmax(cos, axis=1)
    np.testing.assert_allclose(cos[np.arange(len(p)), j], 1.0, atol=1e-12)
    err = t - clean["depth"][j]
    assert 0.009 < err.std() < 0.011 and abs(err.mean()) < 0.001


def test_outlier_and_hole_fractions_and_fixed_length():
    clean = clean_cube()
    P = clean["depth"].size
    cloud = Cloud(points=300, noise=0.0, holes=0.6, outliers=0.1)
    frames = cloud.measure([clean, clean], np.random.default_rng(0), 0.0)
    for frame in frames:
        p = frame["points"]
        assert p.shape == (300, 3)
        t = np.linalg.norm(p - clean["origin"], axis=1)
        on = np.isclose(p[:, 2], 1.0, atol=1e-9)
        assert int((~on).sum()) == 30  # exactly 10% outliers, in front
        assert np.all(p[~on, 2] > 1.0) and np.all(t[~on] > 0)
        pixels = {tuple(np.round(x, 9)) for x in p[on]}
        assert len(pixels) <= round(0.4 * P)  # 60% of the pixels dropped
    # fewer covered pixels than points: still the fixed length (resampled)
    few = Cloud(points=5000).measure([clean], np.random.default_rng(0), 1e-3)
    assert few[0]["points"].shape == (5000, 3)


def test_fixed_length_every_frame_of_a_bending_beam():
    model = beam()
    states = path(model, 5000.0)
    cloud = Cloud(points=123)
    clean = [
        cloud.sense(model, np.array([5000.0]), k, s) for k, s in enumerate(states, 1)
    ]
    visible = [c["depth"].size for c in clean]
    frames = cloud.measure(clean, np.random.default_rng(1), 1e-4)
    assert {f["points"].shape for f in frames} == {(123, 3)}
    assert len(set(visible)) > 1  # the visible part changes; the length does not


# --- the residual -----------------------------------------------------------------


def test_closest_point_distance_matches_brute_force():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.5, 1.5, size=(400, 3))
    d = point_to_surface(pts, CUBE, CUBE_TRIANGLES, candidates=12)
    inside = np.all((pts > 0) & (pts < 1), axis=1)
    outside_d = np.linalg.norm(pts - np.clip(pts, 0, 1), axis=1)
    inside_d = np.min(np.concatenate([pts, 1 - pts], axis=1), axis=1)
    expected = np.where(inside, -inside_d, outside_d)
    np.testing.assert_allclose(d, expected, atol=1e-12)
    g = point_to_surface(pts, CUBE, CUBE_TRIANGLES, gate=0.1, candidates=12)
    np.testing.assert_allclose(g, np.clip(expected, -0.1, 0.1), atol=1e-12)


def test_cloud_residual_is_zero_on_the_truth_and_grows_with_a_wrong_E():
    model = beam()
    true, soft = path(model, 5000.0), path(model, 3500.0)
    cloud = Cloud(points=400, noise=0.0, candidates=6)
    k = model.n_steps
    clean = cloud.sense(model, np.array([5000.0]), k, true[-1])
    data = cloud.measure([clean], np.random.default_rng(0), 0.0)[0]
    frame = kinds.Frame(k, data)
    r_true = cloud.predict(model, frame, np.array([5000.0]), k, true[-1])
    r_soft = cloud.predict(model, frame, np.array([3500.0]), k, soft[-1])
    assert np.abs(r_true).max() < 1e-12
    assert np.abs(r_soft).mean() > 1e-4
    assert np.all(cloud.values(frame) == 0) and len(r_true) == 400
    # point-to-plane (the default): small on the truth, beside a wrong E
    plane = Cloud(points=400, noise=0.0)
    r_true = plane.predict(model, frame, np.array([5000.0]), k, true[-1])
    r_soft = plane.predict(model, frame, np.array([3500.0]), k, soft[-1])
    assert np.median(np.abs(r_true)) < 1e-12
    assert np.abs(r_true).mean() < 0.2 * np.abs(r_soft).mean()


def test_point_to_plane_is_exact_on_a_face_and_signed():
    pts = np.array([[0.3, 0.4, 1.2], [0.6, 0.5, 0.9], [0.5, 0.5, -0.25]])
    d = point_to_surface(pts, CUBE, CUBE_TRIANGLES)
    np.testing.assert_allclose(d, [0.2, -0.1, 0.25], atol=1e-12)


def beam_frame(points: int = 300) -> tuple[Any, np.ndarray, dict[float, list[Any]]]:
    """A bending beam's cloud at its last step and the paths at several E."""
    model = beam()
    paths = {E: path(model, E) for E in (5000.0, 4990.0, 5010.0, 3000.0, 9000.0)}
    cloud = Cloud(points=points, noise=1e-3)
    k = model.n_steps
    clean = cloud.sense(model, np.array([5000.0]), k, paths[5000.0][-1])
    data = cloud.measure([clean], np.random.default_rng(3), 1e-3)[0]
    return model, data["points"], paths


@pytest.mark.parametrize(
    "order",
    [(5000.0, 4990.0, 5010.0, 3000.0, 9000.0), (9000.0, 3000.0, 5010.0, 5000.0)],
)
def test_a_reused_association_gives_a_fresh_querys_residual_in_any_order(order):
    model, pts, paths = beam_frame()
    points = pts.copy()  # a new array: its association starts at order[0]
    for E in order:
        V, T = model.surface(paths[E][-1])
        reused = point_to_surface(points, V, T, gate=0.01)
        fresh = point_to_surface(points, V, T, gate=0.01, reuse=False)
        np.testing.assert_array_equal(reused, fresh)
    # the far states (E x 0.6, x 1.8) re-query: still the fresh query's triangles
    assert surface.association(points, T).queries >= 2


def test_nearby_states_of_a_frame_build_no_kd_tree(monkeypatch):
    model, pts, _ = beam_frame()
    built = []
    real = surface.cKDTree
    monkeypatch.setattr(
        surface, "cKDTree", lambda *a, **kw: built.append(1) or real(*a, **kw)
    )
    for E in (5000.0, 4999.99, 5000.01, 5000.0):  # as finite differences do
        V, T = model.surface(path(model, E)[-1])
        point_to_surface(pts, V, T)
    assert len(built) == 1  # the first state's query; the others are certified
    # a changed point set (same array, edited in place) is associated anew
    pts[0] += 0.01
    point_to_surface(pts, V, T)
    assert len(built) == 2


def test_point_to_plane_of_the_reused_association_is_near_the_closest_point():
    model, pts, paths = beam_frame()
    for E in (5000.0, 3000.0):
        V, T = model.surface(paths[E][-1])
        plane = point_to_surface(pts, V, T)
        exact = point_to_surface(pts, V, T, candidates=8)
        scale = np.sqrt(np.mean(exact**2))
        # point-to-plane is exact where the nearest-centroid triangle holds the
        # closest point (3 in 4 points here), off by curvature x offset^2 elsewhere
        same = np.abs(plane - exact) < 1e-9
        assert same.mean() > 0.6, same.mean()
        if E != 5000.0:  # a wrong E: the residual is the misfit, not the noise
            assert np.sqrt(np.mean((plane - exact) ** 2)) < 0.2 * scale


# --- the filters with a per-value noise ------------------------------------------


@pytest.mark.parametrize("name", ["ro-ukf", "ukf", "enkf", "etkf", "rls"])
def test_an_array_noise_std_equal_to_the_scalar_gives_the_same_estimate(name):
    reg = idbench.build_registry()
    estimates = []
    for std in (0.05, np.full(3, 0.05)):
        toy = SensitiveLinearToy(n_steps=4, m=3, n=4)
        est = reg.estimator(name)()
        est.start(toy, idbench.Prior((1.0,), (0.5,)))
        u = toy.reset()
        for k in range(1, 5):
            u = toy.step(np.array([1.7]), k, u)
            e = est.update(k, Observation(toy.observe(u) + 0.01 * k, std, k))
        estimates.append(e.mean)
    np.testing.assert_allclose(estimates[0], estimates[1], rtol=1e-9)


# --- through compare ----------------------------------------------------------------


def tiny(**kw: Any) -> CompareConfig:
    base: dict[str, Any] = {
        "truth_mesh": "14x3x3", "meshes": ("9x2x2",), "scenarios": ("bend-y",),
        "estimators": ("ro-ukf",), "steps": 6, "seeds": 1, "obs_every": (1,),
    }  # fmt: skip
    return CompareConfig(**{**base, **kw})


def test_markers_keep_todays_stream_and_run_ids():
    config = tiny()
    (plain,) = runs_of(config)
    (named,) = runs_of(tiny(observe=("markers",)))
    assert plain.run_id == named.run_id and not plain.observed_otherwise()
    session = Session()
    truth = session.truth(plain)
    seq = np.random.SeedSequence(
        [plain.seed, int(idbench.store.files.stable_hash(plain.noise_key()), 16)]
    )
    noise = np.random.default_rng(seq).standard_normal(truth.observations.shape)
    for k, obs in enumerate(session.observations(plain), start=1):
        np.testing.assert_array_equal(
            obs.values, truth.observations[k - 1] + noise[k - 1] * plain.noise
        )
    model = session.model(plain, plain.mesh)
    assert session.estimator_model(plain, model) is model


def test_ro_ukf_with_a_cloud_identifies_E_close_to_markers(tmp_path):
    config = tiny(
        observe=("markers", "cloud"),
        observe_settings={"cloud": {"points": 200, "outliers": 0.05}},
    )
    runs, _ = compare(config, tmp_path)
    assert set(runs.status) == {"ok"}
    E = runs.set_index("observe").E_final
    assert abs(E["cloud"] / E["markers"] - 1) < 0.2
    assert E["cloud"] != E["markers"]


def test_cloud_plus_force_concatenates_with_per_value_noise():
    config = tiny(
        observe=("cloud+force",),
        observe_settings={"cloud": {"points": 50}, "force": {"noise": 0.01}},
    )
    (spec,) = runs_of(config)
    stream = Session().observations(spec)
    obs = stream[0]
    assert obs.values.shape == (53,)
    assert np.all(obs.values[:50] == 0)
    assert np.all(obs.noise_std[50:] == 0.01) and np.all(obs.noise_std[:50] == 1e-4)


@pytest.mark.parametrize(
    ("kw", "words"),
    [
        ({"observe": ("camera",)}, ["camera", "allowed", "cloud"]),
        ({"observe": ("cloud+",)}, ["empty block"]),
        ({"observe": ("cloud",), "observe_settings": {"cloud": {"pointz": 3}}},
         ["pointz", "points"]),
        ({"observe": ("cloud",), "observe_settings": {"cloud": {"holes": 1.5}}},
         ["holes", "[0, 1)"]),
        ({"observe": ("markers",), "observe_settings": {"clod": {"points": 3}}},
         ["[observe.clod]", "not used"]),

    ],
)  # fmt: skip
def test_bad_observation_settings_are_one_line(kw, words):
    with pytest.raises(ConfigError) as info:
        runs_of(tiny(**kw))
    text = str(info.value)
    assert "\n" not in text and all(w in text for w in words), text


def test_a_camera_that_sees_nothing_is_one_line_before_any_run(tmp_path):
    config = tiny(
        observe=("cloud",),
        observe_settings={
            "cloud": {"position": [0.0, 0.0, 10.0], "look_at": [0.0, 0.0, 20.0]}
        },
    )
    with pytest.raises(ConfigError) as info:
        compare(config, tmp_path)
    text = str(info.value)
    assert "\n" not in text
    assert "observe 'cloud'" in text and "sees no part" in text
    assert not (tmp_path / "runs.parquet").exists()


def test_cli_compare_with_a_cloud(tmp_path, capsys):
    code = main([
        "compare", "--truth-mesh", "14x3x3", "--meshes", "9x2x2", "--steps", "4",
        "--seeds", "1", "--estimators", "ro-ukf", "--observe", "markers,cloud",
        "--observe-option", "cloud.points=100", "--out", str(tmp_path),
    ])  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    assert "cloud" in out


# --- force: a displacement-controlled toy ----------------------------------------


class DrivenSpring:
    """A chain whose end is driven (u independent of E), the tool force measured.

    u_k = (k/K) d for every E (displacement control: markers cannot tell E);
    the reaction at the driven end is E c . u.
    """

    def __init__(self, n_steps: int) -> None:
        self.n_steps = n_steps
        self.parameters = idbench.ParameterSpec(("E",), (1.0,), (1e4,), (300.0,))
        self.d = np.array([0.1, 0.2, 0.3])
        self.c = np.array([[1.0, -1.0, 0.5], [0.0, 2.0, 1.0]])
        self.solves = 0

    def reset(self) -> np.ndarray:
        return np.zeros(3)

    def step(self, theta, k, state, *, substeps=1):  # type: ignore[no-untyped-def]
        self.solves += 1
        return (k / self.n_steps) * self.d

    def observe(self, state: np.ndarray) -> np.ndarray:
        return state.copy()

    def reaction(self, theta, k, state):  # type: ignore[no-untyped-def]
        return float(theta[0]) * (self.c @ state)

    def grid(self, state: np.ndarray) -> np.ndarray:
        return state.reshape(1, 3)

    def cost(self) -> idbench.Cost:
        return idbench.Cost(self.solves, self.solves, self.solves)

    def describe(self) -> dict[str, Any]:
        return {"model": "driven-spring"}


class DrivenPlugin:
    @idbench.hookimpl
    def register_models(self, register: Callable[..., None]) -> None:
        register("driven", lambda spec: DrivenSpring(spec.n_steps))


@pytest.fixture
def driven() -> idbench.Registry:
    return registry_with({"driven": DrivenPlugin()})


def test_force_identifies_E_of_a_displacement_controlled_body(driven, tmp_path):
    config = CompareConfig(
        model="driven", truth_mesh="t", meshes=("m",), scenarios=("bend-y",),
        estimators=("ro-ukf", "ukf", "enkf", "rls"), steps=6, seeds=1,
        obs_every=(1,), prior=(150.0, 100.0), observe=("markers", "force"),
        observe_settings={"force": {"noise": 0.01}},
    )  # fmt: skip
    runs, _ = compare(config, tmp_path, registry=driven)
    assert set(runs.status) == {"ok"}
    for estimator, rows in runs.groupby("estimator"):
        E = rows.set_index("observe").E_final
        assert abs(E["force"] / 300.0 - 1) < 0.02, estimator  # identified
        assert abs(E["markers"] / 300.0 - 1) > 0.3, estimator  # u says nothing of E


def test_a_model_without_surface_is_refused_for_a_cloud(driven):
    config = CompareConfig(
        model="driven", truth_mesh="t", meshes=("m",), scenarios=("bend-y",),
        estimators=("ro-ukf",), steps=3, seeds=1, prior=(150.0, 100.0),
        observe=("cloud",),
    )  # fmt: skip
    with pytest.raises(ConfigError, match=r"needs the model's surface\(\)"):
        runs_of(config, driven)


def test_toml_observe_axis_and_tables(tmp_path):
    from idbench.plan.config import build_config, load_toml

    path = tmp_path / "c.toml"
    path.write_text(
        '[compare]\nobserve = ["markers", "cloud-few"]\n'
        '[observe.cloud-few]\nkind = "cloud"\npoints = 20\n'
    )
    config = build_config(toml=load_toml(path), **tiny().__dict__ | {"observe": None})
    assert config.observe == ("markers", "cloud-few")
    runs = runs_of(config)
    (few,) = [r for r in runs if r.observe == "cloud-few"]
    assert dict(dict(few.observe_settings)["cloud-few"])["points"] == 20
    assert Session().observations(few)[0].values.shape == (20,)


def test_a_low_rank_innovation_covariance_gives_the_dense_nis():
    from idbench.estimate.lowrank import LowRankCovariance
    from idbench.score.metrics import nis

    rng = np.random.default_rng(0)
    low = LowRankCovariance(rng.uniform(0.5, 2.0, 40), rng.normal(size=(40, 3)))
    v = rng.normal(size=40)
    assert nis(v, low) == pytest.approx(nis(v, low.dense()), rel=1e-10)


def test_two_workers_give_the_serial_cloud_numbers(tmp_path):
    config = tiny(
        observe=("cloud", "cloud+force"), seeds=2,
        observe_settings={"cloud": {"points": 40, "outliers": 0.1}},
    )  # fmt: skip
    serial, _ = compare(config, tmp_path / "serial")
    pool, _ = compare(config, tmp_path / "pool", jobs=2)
    cols = ["run_id", "E_final", "E_ref", "shape_error_final"]
    a = serial[cols].sort_values("run_id").reset_index(drop=True)
    b = pool[cols].sort_values("run_id").reset_index(drop=True)
    np.testing.assert_array_equal(a.run_id, b.run_id)
    np.testing.assert_allclose(a[cols[1:]], b[cols[1:]], rtol=1e-9)


def test_fe_surface_is_closed_and_outward_and_reaction_balances_the_load():
    model = beam()
    states = path(model, 5000.0)
    V, T = model.surface(states[-1])
    p0, p1, p2 = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    volume = np.einsum("ij,ij->i", p0, np.cross(p1, p2)).sum() / 6
    assert volume > 0  # outward normals enclose a positive volume
    edges = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # closed: every edge in two triangles
    load = model.external_force(model.n_steps).reshape(-1, 3).sum(axis=0)
    reaction = model.reaction(np.array([5000.0]), model.n_steps, states[-1])
    np.testing.assert_allclose(reaction, -load, atol=1e-9 * np.abs(load).max())


def test_check_optional_members_catches_a_bad_surface():
    from idbench.registry.testing import check_optional_members

    toy = SensitiveLinearToy(n_steps=3)
    toy.surface = lambda state: (np.zeros((4, 3)), np.array([[0, 1, 7]]))  # type: ignore[attr-defined]
    with pytest.raises(AssertionError, match="do not exist"):
        check_optional_members(toy, toy.reset())


def test_an_observed_model_has_no_sensitivity_and_the_models_other_members():
    from idbench.core import capabilities as cap
    from idbench.observe.observed_model import ObservedModel

    model = SensitiveLinearToy(p=1, n_steps=3)
    model.n_nodes = 7
    frames = [kinds.Frame(k, {"markers": np.zeros(3)}) for k in (1, 2, 3)]
    seen = ObservedModel(model, kinds.Markers(), frames)
    assert cap.sensitivity_of(model) is not None and cap.sensitivity_of(seen) is None
    assert not hasattr(seen, "sensitivity") and cap.n_nodes_of(seen) == 7
    assert cap.step_many_of(seen) is not None  # its own: the model's r steps
    u = seen.step(np.array([2.0]), 1, seen.reset())
    np.testing.assert_array_equal(seen.observe(u), model.observe(u[:-1]))
    assert seen.describe() == model.describe() and seen.cost() == model.cost()
