"""Helper processes of the beam's batched steps (model option ``processes``)."""

from __future__ import annotations

import gc
import logging
import multiprocessing as mp
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from support.beams import beam_model

from idbench import ModelFailure, Observation, Prior
from idbench_fem.bodies import box
from idbench_fem.fem import pairs, predictions
from idbench_fem.fem.step_workers import Helper, HelperLost
from idbench_fem.models.beam_scenarios import SCENARIOS
from idbench_fem.models.beam_settings import BeamSettings
from idbench_fem.models.solid import SolidModel
from idbench_filters import RoUkf

SPREAD = 0.3
"""Log-normal spread of the regional moduli: far enough apart that the
anchor's predictions settle no pair, so the helpers get work."""


def _beam(processes: int = 1) -> SolidModel:
    return beam_model(
        box.parse("8x2x2"), SCENARIOS[0], n_steps=4, parameters="E_regions",
        options={"regions": 4, "processes": processes},
    )  # fmt: skip


def _thetas(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return 5000.0 * np.exp(SPREAD * rng.normal(size=(5, 4)))


def _path(model: SolidModel, thetas: np.ndarray, steps: int = 3) -> list[np.ndarray]:
    """step_many over the first ``steps`` load steps from the reference state."""
    states = np.tile(model.reset(), (len(thetas), 1))
    out = []
    for k in range(1, steps + 1):
        states = model.step_many(thetas, k, states)
        out.append(states)
    return out


def _assert_converged(model: SolidModel, thetas, k, states) -> None:
    """Every row meets the Newton test of step() at load k."""
    f = np.linalg.norm(model.external_force(k))
    for theta, u in zip(thetas, states, strict=True):
        r = np.linalg.norm(model.residual(theta, k, u))
        assert r <= max(model.rtol * f, model.atol) * (1 + 1e-12)


@pytest.fixture(scope="module")
def two():
    """A model with one helper and its path (the helper starts once)."""
    model = _beam(processes=2)
    thetas = _thetas()
    states = _path(model, thetas)
    yield model, thetas, states
    model.close()


def test_helper_does_work_and_every_pair_converges(two):
    model, thetas, states = two
    (helper,) = model._helpers
    # the first step hands pairs over after the anchor, the later ones early
    assert helper.alive and helper.calls == 3
    assert model._batch_anchor.unsettled  # so steps 2 and 3 sent pairs early
    for k, s in enumerate(states, start=1):
        _assert_converged(model, thetas, k, s)


def test_results_equal_one_process_to_the_tolerance(two):
    model, thetas, states = two
    one = _beam(processes=1)
    for a, b in zip(_path(one, thetas), states, strict=True):
        scale = np.abs(a).max()
        assert np.abs(a - b).max() <= 1e-6 * scale
    # the same work is counted: one forward solve a pair
    assert model.cost().forward_solves == one.cost().forward_solves == 15


def test_ro_ukf_estimates_equal_one_process_to_the_tolerance():
    estimates = []
    for processes in (1, 2):
        model = _beam(processes)
        theta = np.array([5000.0, 4000.0, 6000.0, 5000.0])
        u, obs = model.reset(), {}
        for k in range(1, 5):
            u = model.step(theta, k, u)
            obs[k] = Observation(values=model.observe(u), noise_std=1e-4, step=k)
        est = RoUkf()
        est.start(model, Prior((2500.0,) * 4, (2500.0,) * 4))
        for k in range(1, 5):
            e = est.update(k, obs[k])
        estimates.append(e.mean)
        if processes == 2:
            assert model._helpers[0].calls >= 3
        model.close()
    np.testing.assert_allclose(estimates[1], estimates[0], rtol=1e-6)


_PAUSES = np.random.default_rng(20261130)
"""Pauses of the delayed helpers (each helper process draws its own sequence)."""


def _delayed_solve(model, k, rows):
    """pairs.helper_solve after a random pause of 0-40 ms."""
    time.sleep(0.04 * _PAUSES.random())
    return pairs.helper_solve(model, k, rows)


def test_results_do_not_depend_on_timing():
    """Two helpers answering after random pauses: bitwise the same states."""
    thetas = _thetas(3)
    runs = []
    for delayed in (False, True, True):
        model = _beam(processes=3)
        if delayed:
            model._helpers[:] = [Helper(model._recipe, _delayed_solve) for _ in "ab"]
        runs.append(_path(model, thetas, steps=4))
        assert [h.calls for h in model._helpers] == [4, 4]
        model.close()
    for other in runs[1:]:
        for a, b in zip(runs[0], other, strict=True):
            np.testing.assert_array_equal(a, b)


def test_ctrl_c_while_waiting_loses_the_helper_not_the_results(monkeypatch):
    """A KeyboardInterrupt while a helper's answer is awaited must not leave that
    answer to be read as the next call's (the states would be another step's)."""
    model = _beam(processes=2)
    thetas = _thetas(4)
    states = model.step_many(thetas, 1, np.tile(model.reset(), (5, 1)))
    (helper,) = model._helpers
    real = helper._conn.recv

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(helper._conn, "recv", interrupted)
    with pytest.raises(KeyboardInterrupt):
        model.step_many(thetas, 2, states)
    monkeypatch.setattr(helper._conn, "recv", real)
    assert not helper.alive
    new = model.step_many(thetas * 1.1, 2, states)  # other thetas: other answers
    _assert_converged(model, thetas * 1.1, 2, new)
    model.close()


def test_one_models_helpers_run_at_a_time():
    a, b = _beam(processes=2), _beam(processes=2)
    thetas, start = _thetas(5), np.tile(a.reset(), (5, 1))
    a.step_many(thetas, 1, start)
    (first,) = a._helpers
    b.step_many(thetas, 1, start)
    assert first.closed and first._process.poll() is not None
    assert b._helpers[0].alive
    _assert_converged(a, thetas, 1, a.step_many(thetas, 1, start))
    assert a._helpers[0] is not first and a._helpers[0].alive  # started again
    assert b._helpers[0].closed
    a.close()
    b.close()


def test_processes_leaves_run_ids_and_output_folders_alone(tmp_path):
    from idbench.plan.config import CompareConfig
    from idbench.run.compare import compare, runs_of

    def config(**options):
        return CompareConfig(
            estimators=("rls",), meshes=("6x2x2",), truth_mesh="9x2x2", seeds=1,
            steps=3, model_settings={"svk-beam": options},
        )  # fmt: skip

    ids = {r.run_id for r in runs_of(config())}
    assert {r.run_id for r in runs_of(config(processes=2))} == ids
    assert {r.run_id for r in runs_of(config(nu=0.3))} != ids
    (two,) = runs_of(config(processes=2))
    assert dict(two.setup.execution) == {"processes": 2}
    runs, _ = compare(config(), tmp_path)
    ran = []
    again, _ = compare(  # resumes the same comparison: nothing left to run
        config(processes=2), tmp_path, progress=lambda *a: ran.append(a)
    )
    assert ran == [] and list(again.run_id) == list(runs.run_id)
    # an empty settings table means what no table means
    plain = CompareConfig(
        estimators=("rls",), meshes=("6x2x2",), truth_mesh="9x2x2", seeds=1, steps=3
    )
    compare(plain, tmp_path, progress=lambda *a: ran.append(a))
    assert ran == []


def test_processes_reach_the_model_and_pick_it_in_a_session():
    from idbench.plan.config import CompareConfig
    from idbench.run.compare import runs_of
    from idbench.run.session import Session

    def spec(**options):
        config = CompareConfig(
            estimators=("rls",), meshes=("6x2x2",), truth_mesh="9x2x2", seeds=1,
            steps=3, model_settings={"svk-beam": options},
        )  # fmt: skip
        return runs_of(config)[0]

    session = Session()
    two = session.model(spec(processes=2), "6x2x2")
    one = session.model(spec(), "6x2x2")
    assert two.processes == 2 and one.processes == 1
    assert session.model(spec(processes=2), "6x2x2") is two


def test_helpers_of_models_in_two_threads_do_not_stop_each_other(caplog):
    import threading

    thetas = _thetas(6)
    errors, models = [], []

    def run():
        try:
            model = _beam(processes=2)
            models.append(model)
            _path(model, thetas, steps=3)
        except Exception as exc:  # reported below
            errors.append(exc)

    with caplog.at_level(logging.WARNING, logger="idbench_fem.fem.step_workers"):
        threads = [threading.Thread(target=run) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert errors == [] and "lost" not in caplog.text
    for model in models:
        assert model._helpers[0].alive and model._helpers[0].calls == 3
        model.close()


@pytest.mark.parametrize(("p", "beta"), [(1, 0.0), (4, 2.0)])
def test_predictions_take_the_form_of_the_parameters(monkeypatch, p, beta):
    seen = []
    real = predictions.prediction_steps

    def spy(theta_a, thetas, b):
        seen.append(b)
        return real(theta_a, thetas, b)

    monkeypatch.setattr(predictions, "prediction_steps", spy)
    if p == 1:
        model = beam_model(box.parse("8x2x2"), SCENARIOS[0], n_steps=4)
        thetas = np.array([[4000.0], [5000.0], [6000.0]])
    else:
        model, thetas = _beam(), _thetas()
    model.step_many(thetas, 1, np.tile(model.reset(), (len(thetas), 1)))
    assert seen == [beta]


def test_a_helper_counts_pairs_settled_at_their_prediction():
    model = _beam()
    thetas = _thetas(7)[:2]
    start = np.tile(model.reset(), (2, 1))
    done = model.step_many(thetas, 1, start)
    rows = pairs.PendingPairs(thetas, done, start)  # predictions already converged
    states, work = pairs.helper_solve(_beam(), 1, rows)
    np.testing.assert_array_equal(states, done)
    assert work[3] == 2 and work[1] == 0
    before = model.batch_stats.converged_at_prediction
    pairs.add_work(model, work)
    assert model.batch_stats.converged_at_prediction == before + 2


@pytest.fixture
def sigpipe_default():
    """SIGPIPE at its default (kill), as gmsh leaves it once imported."""
    old = signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    yield
    signal.signal(signal.SIGPIPE, old)


def test_a_lost_helper_is_replaced_by_this_process(caplog, sigpipe_default):
    model = _beam(processes=2)
    thetas = _thetas(1)
    states = np.tile(model.reset(), (5, 1))
    states = model.step_many(thetas, 1, states)
    (helper,) = model._helpers
    assert helper.calls == 1
    helper._process.kill()
    helper._process.wait()
    with caplog.at_level(logging.WARNING, logger="idbench_fem.fem.step_workers"):
        new = model.step_many(thetas, 2, states)
    assert "helper process was lost" in caplog.text
    assert not helper.alive and model._step_helpers() == []
    _assert_converged(model, thetas, 2, new)
    _assert_converged(model, thetas, 3, model.step_many(thetas, 3, new))
    model.close()


def _model_recipe() -> SolidModel:
    return _beam()


def test_helper_reports_model_failures_and_errors():
    helper = Helper(_model_recipe, pairs.helper_solve)
    try:
        model = _beam()
        n = model.n_state
        rows = pairs.PendingPairs(
            np.full((1, 4), -1.0), np.zeros((1, n)), np.zeros((1, n))
        )
        helper.submit(2, rows)
        with pytest.raises(ModelFailure, match="not positive") as info:
            helper.collect()
        assert info.value.step == 2
        good = pairs.PendingPairs(
            np.full((1, 4), 5000.0), np.zeros((1, n)), np.zeros((1, n))
        )
        helper.submit(1, good)
        states, work = helper.collect()
        _assert_converged(model, good.thetas, 1, states)
        assert work[1] >= 1  # it factored
        bad = pairs.PendingPairs(
            np.full((1, 4), 5000.0), np.zeros((1, 3)), np.zeros((1, 3))
        )
        helper.submit(1, bad)  # wrong shapes: an error, not a model failure
        with pytest.raises(HelperLost):
            helper.collect()
        assert not helper.alive
    finally:
        helper.close()


def test_close_and_garbage_collection_end_the_process():
    model = _beam(processes=2)
    model.step_many(_thetas(2), 1, np.tile(model.reset(), (5, 1)))
    process = model._helpers[0]._process
    model.close()
    assert process.poll() is not None
    model = _beam(processes=2)
    model.step_many(_thetas(2), 1, np.tile(model.reset(), (5, 1)))
    process = model._helpers[0]._process
    del model
    gc.collect()
    assert process.wait(timeout=10) is not None


def test_a_script_without_a_main_guard_can_use_helpers(tmp_path):
    script = tmp_path / "user_script.py"
    script.write_text(
        textwrap.dedent(
            """
            import numpy as np
            from idbench_fem.bodies import box
            from idbench_fem.models.beam import build
            from idbench_fem.models.beam_scenarios import SCENARIOS
            from idbench_fem.models.beam_settings import BeamSettings

            s = BeamSettings(parameters="E_regions", regions=4, processes=2)
            m = build(box.parse("6x2x2"), SCENARIOS[0], n_steps=2, settings=s)
            th = 5000.0 * np.exp(0.3 * np.random.default_rng(0).normal(size=(5, 4)))
            u = m.step_many(th, 1, np.tile(m.reset(), (5, 1)))
            print("calls", m._helpers[0].calls)
            """
        )
    )
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "calls 1" in done.stdout


def _gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (exited, or a zombie nobody reaps)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in "ZX"
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_helper_inside_a_long_solve_ends_with_its_killed_parent(tmp_path):
    (tmp_path / "sleepy.py").write_text(
        "import time\n"
        "def build():\n    return None\n"
        "def solve(model, seconds):\n    time.sleep(seconds)\n"
    )
    parent = tmp_path / "parent.py"
    parent.write_text(
        textwrap.dedent(
            """
            import os, signal
            import sleepy
            from idbench_fem.fem.step_workers import Helper

            helper = Helper(sleepy.build, sleepy.solve)
            helper.submit(600.0)  # the helper is ready, now in a 10-minute solve
            print(helper._process.pid, flush=True)
            os.kill(os.getpid(), signal.SIGKILL)
            """
        )
    )
    done = subprocess.run(
        [sys.executable, str(parent)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == -signal.SIGKILL, done.stderr
    pid = int(done.stdout.split()[0])
    deadline = time.monotonic() + 60.0  # it ends within a second; 60 s: slow CI
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _gone(pid), "the helper outlived its parent"


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_processes_must_be_a_whole_number(bad):
    with pytest.raises(ValueError, match=f"processes {bad!r}: need a whole number"):
        _beam(processes=bad)
    with pytest.raises(ValueError, match=f"processes {bad!r}: need a whole number"):
        BeamSettings(processes=bad)


def test_processes_is_not_part_of_the_identity():
    assert BeamSettings(processes=2).identity() == BeamSettings().identity()
    assert BeamSettings(processes=2).options()["processes"] == 2
    assert _beam(processes=2).describe() == _beam().describe()


def _path_in_fork(model: SolidModel, thetas: np.ndarray, conn) -> None:
    """In a forked copy of ``model``'s process: its path, and its helper's pid."""
    states = _path(model, thetas)
    (helper,) = model._helpers
    conn.send((helper._process.pid, helper.owned, states[-1]))
    model.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forks on Linux")
def test_a_forked_copy_starts_its_own_helper_and_leaves_the_parents_alone():
    # a sweep's forked worker holds a copy of the parent's models
    model = _beam(processes=2)
    thetas = _thetas()
    first = _path(model, thetas)
    (helper,) = model._helpers
    calls = helper.calls
    ctx = mp.get_context("fork")
    mine, theirs = ctx.Pipe()
    child = ctx.Process(target=_path_in_fork, args=(model, thetas, theirs), daemon=True)
    child.start()
    theirs.close()
    try:
        assert mine.poll(120), "the forked copy did not answer"
        pid, owned, last = mine.recv()
        child.join(30)
    finally:
        if child.is_alive():
            child.kill()
    assert child.exitcode == 0
    assert owned and pid != helper._process.pid  # a helper of its own
    _assert_converged(model, thetas, 3, last)
    # the parent's helper still serves the parent, in step with it
    again = _path(model, thetas)
    assert model._helpers == [helper] and helper.alive and helper.calls > calls
    np.testing.assert_allclose(again[-1], first[-1], rtol=1e-9, atol=1e-15)
    model.close()
