"""How a sweep plans, orders and shares its work (commit 2eda7a2).

``estimate_solves`` of the built-in estimators and :func:`idbench.plan.check.plan`'s
cost guess, :func:`idbench.run.compare.dispatch_order`, the products a
:class:`~idbench.run.session.Session` shares (:meth:`~Session.shared`,
:meth:`~Session.adopt`) and how the worker pool passes them on, workers started
ahead (:func:`idbench.run.executors.started`), and :meth:`ResultStore.scan` and
:meth:`~ResultStore.consolidate`.

Everything runs on tiny meshes (truth 10x2x2, models 4x1x1 and 6x2x2) with
three load steps.
"""

from __future__ import annotations

import dataclasses
import itertools
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pandas as pd
import pytest

import idbench
import idbench.run.session
from idbench.plan.check import Plan, plan
from idbench.plan.config import CompareConfig, ConfigError
from idbench.plan.runspec import RunSpec
from idbench.registry.registry import Entry, Registry, build_registry
from idbench.run import executors
from idbench.run.compare import compare, dispatch_order, interleave, runs_of
from idbench.run.executors import execute_all
from idbench.run.session import Session
from idbench.store.results import ResultStore

TRUTH = "10x2x2"
MESHES = ("4x1x1", "6x2x2")
STEPS = 3
BUILT_IN = ("ro-ukf", "ukf", "enkf", "etkf", "rls", "lms", "batch-ls")
COMPARED = ["E_final", "E_ref", "shape_error_final", "shape_error_direct",
            "transfer_error", "transfer_error_direct"]  # fmt: skip


def small(**overrides: Any) -> CompareConfig:
    """Two meshes x two seeds on the 10x2x2 truth, three load steps."""
    base: dict[str, Any] = {
        "truth_mesh": TRUTH,
        "meshes": MESHES,
        "steps": STEPS,
        "seeds": 2,
        "estimators": ("rls", "ro-ukf", "batch-ls"),
    }
    return CompareConfig(**{**base, **overrides})


@pytest.fixture(scope="module")
def cache_env(tmp_path_factory) -> Iterator[None]:
    """The per-session truth cache of conftest.py, also for module fixtures."""
    with pytest.MonkeyPatch.context() as m:
        m.setenv("IDBENCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "c"))
        yield


@pytest.fixture(scope="module")
def registry() -> Registry:
    return build_registry()


@pytest.fixture(scope="module")
def all_plan(cache_env, registry) -> tuple[Plan, Session]:
    """The plan of every built-in estimator on both meshes (nothing run)."""
    session = Session(registry)
    return plan(small(estimators=BUILT_IN), session), session


@pytest.fixture(scope="module")
def runs(cache_env, registry) -> list[RunSpec]:
    """rls, ro-ukf and batch-ls (the reference) x 2 meshes x 2 seeds: 12 runs."""
    return runs_of(small(), registry)


def own_reference(spec: RunSpec) -> bool:
    return spec.estimator == spec.setup.reference and not spec.settings


# --- estimate_solves and the plan --------------------------------------------


@pytest.mark.parametrize("name", BUILT_IN)
@pytest.mark.parametrize(("n_state", "p", "steps"), [(48, 1, 3), (162, 3, 20)])
def test_every_built_in_estimator_estimates_a_positive_int(
    registry, name, n_state, p, steps
):
    est = registry.estimator(name)()
    guess = est.estimate_solves(n_state, p, steps)
    assert type(guess) is int
    assert guess > 0
    # linear in the number of steps for every estimator with its defaults
    assert est.estimate_solves(n_state, p, 2 * steps) == 2 * guess


def test_ukf_estimate_is_zero_exactly_when_over_max_solves(registry):
    ukf = registry.estimator("ukf")
    default = ukf()
    assert default.max_solves == 1500
    # 2 (n_state + p) + 1 = 1499 <= 1500: (2n + 1) a step
    assert default.estimate_solves(747, 2, 7) == 1499 * 7
    # 2 (n_state + p) + 1 = 1501 > 1500: skipped, costs nothing
    assert default.estimate_solves(748, 2, 7) == 0
    assert default.estimate_solves(10_000, 1, 7) == 0
    # the budget itself is allowed, as begin() allows it
    assert ukf(max_solves=601).estimate_solves(298, 2, 7) == 601 * 7
    assert ukf(max_solves=600).estimate_solves(298, 2, 7) == 0


def test_ro_ukf_estimate_counts_its_sigma_points(registry):
    ro_ukf = registry.estimator("ro-ukf")
    for p in (1, 2, 5):
        assert ro_ukf().estimate_solves(100, p, 4) == (p + 1) * 4  # simplex
        assert ro_ukf(sigma_points="simplex").estimate_solves(100, p, 4) == (p + 1) * 4
        assert ro_ukf(sigma_points="star").estimate_solves(100, p, 4) == (2 * p + 1) * 4
    # the state size does not matter: the state is not sampled
    assert ro_ukf().estimate_solves(10, 2, 4) == ro_ukf().estimate_solves(10**6, 2, 4)


@pytest.mark.parametrize("name", ["enkf", "etkf"])
def test_ensemble_estimate_is_one_step_per_member(registry, name):
    cls = registry.estimator(name)
    for p in (1, 3):
        assert cls().estimate_solves(100, p, 5) == (2 * p + 2) * 5  # default members
        assert cls(members=7).estimate_solves(100, p, 5) == 7 * 5


def test_other_estimates_follow_their_settings(registry):
    for name in ("rls", "lms"):
        assert registry.estimator(name)().estimate_solves(100, 2, 5) == 5  # own path
    batch = registry.estimator("batch-ls")
    assert batch().estimate_solves(100, 1, 6) == 5 * 6  # one fit, ~5 paths
    assert batch(max_nfev=2).estimate_solves(100, 1, 6) == 2 * 6  # capped
    assert batch(refit="each").estimate_solves(100, 1, 6) == 5 * (6 * 7 // 2)


def test_plan_sums_the_estimates_and_weighs_them_by_state_size(all_plan, registry):
    the_plan, session = all_plan
    assert len(the_plan.runs) == len(BUILT_IN) * len(MESHES) * 2
    assert set(the_plan.work) == {r.run_id for r in the_plan.runs}
    total = 0
    for spec in the_plan.runs:
        model = session.model(spec, spec.mesh)
        n_state, p = model.reset().size, model.parameters.p
        est = registry.estimator(spec.estimator)(**dict(spec.settings))
        guess = est.estimate_solves(n_state, p, STEPS)
        assert guess > 0, spec.estimator  # the ukf fits in its budget here
        assert the_plan.work[spec.run_id] == float(guess * n_state)
        total += guess
    assert the_plan.solves == total
    # a finer mesh is more work for the same estimator and seed
    by = {(r.estimator, r.mesh, r.seed): the_plan.work[r.run_id] for r in the_plan.runs}
    for name in BUILT_IN:
        assert by[(name, "6x2x2", 0)] > by[(name, "4x1x1", 0)]


def test_a_ukf_over_budget_is_planned_as_free_and_skipped(
    cache_env, registry, tmp_path
):
    """estimate_solves says 0 for exactly the runs that begin() skips."""
    config = small(
        meshes=("4x1x1",), seeds=1, estimators=("ukf",),
        estimator_settings={"ukf": {"max_solves": 50}},
    )  # fmt: skip
    the_plan = plan(config, Session(registry))
    assert the_plan.solves == 0
    assert list(the_plan.work.values()) == [0.0]
    rows, _ = compare(config, tmp_path, registry=registry)
    assert list(rows["status"]) == ["skipped"]
    assert "max_solves = 50" in rows["error"].iloc[0]


@dataclasses.dataclass
class Keeper:
    """An estimator that keeps the prior; subclasses break its cost guess."""

    def start(self, model: Any, prior: idbench.Prior) -> None:
        self.prior = prior

    def update(self, k: int, observation: Any) -> idbench.Estimate:
        mean = np.asarray(self.prior.mean, dtype=float)
        return idbench.Estimate(mean, np.full(mean.shape, np.nan), idbench.Cost())


class RaisingGuess(Keeper):
    def estimate_solves(self, n_state: int, p: int, steps: int) -> int:
        raise RuntimeError("cannot say")


class ExitingGuess(Keeper):
    def estimate_solves(self, n_state: int, p: int, steps: int) -> int:
        raise SystemExit(3)


class NonsenseGuess(Keeper):
    def estimate_solves(self, n_state: int, p: int, steps: int) -> Any:
        return "many"


@pytest.mark.parametrize("cls", [Keeper, RaisingGuess, ExitingGuess, NonsenseGuess])
def test_a_plugin_that_cannot_guess_is_planned_with_two_solves_a_step(
    cache_env, cls, caplog
):
    reg = build_registry()
    reg.estimators["plug"] = Entry("plug", cls, "test")
    config = small(meshes=("4x1x1",), seeds=1, estimators=("plug", "rls"))
    session = Session(reg)
    the_plan = plan(config, session)
    plug = next(r for r in the_plan.runs if r.estimator == "plug")
    n_state = session.model(plug, plug.mesh).reset().size
    assert the_plan.work[plug.run_id] == 2 * STEPS * n_state
    assert the_plan.solves == 2 * STEPS + STEPS  # and rls's own path
    if cls is not Keeper:
        assert "'plug' cannot estimate its cost" in caplog.text


# --- dispatch order ----------------------------------------------------------


def check_groups(order: list[RunSpec], work: dict[str, float]) -> None:
    """Own reference runs first, then the rest; each by non-increasing work."""
    flags = [own_reference(r) for r in order]
    n_ref = sum(flags)
    assert flags == [True] * n_ref + [False] * (len(order) - n_ref)
    for group in (order[:n_ref], order[n_ref:]):
        costs = [work.get(r.run_id, 0.0) for r in group]
        assert costs == sorted(costs, reverse=True)


def test_dispatch_order_with_the_plans_work(cache_env, registry, runs):
    work = plan(small(), Session(registry)).work
    order = dispatch_order(runs, work)
    assert sorted(r.run_id for r in order) == sorted(r.run_id for r in runs)
    assert len({r.run_id for r in order}) == len(runs)
    check_groups(order, work)
    assert [r.estimator for r in order[:4]] == ["batch-ls"] * 4
    assert [r.mesh for r in order[:4]] == ["6x2x2", "6x2x2", "4x1x1", "4x1x1"]
    assert {r.mesh for r in order[4:8]} == {"6x2x2"}


def test_the_reference_runs_go_first_however_cheap(runs):
    work = {r.run_id: (1.0 if own_reference(r) else 1e9) for r in runs}
    order = dispatch_order(runs, work)
    assert [own_reference(r) for r in order] == [True] * 4 + [False] * 8
    check_groups(order, work)


def test_a_reference_estimator_run_with_settings_is_not_its_datas_reference(runs):
    tuned = [
        dataclasses.replace(r, settings=(("max_nfev", 7),))
        if r.estimator == "batch-ls" else r
        for r in runs
    ]  # fmt: skip
    work = {r.run_id: (1e9 if r.estimator == "ro-ukf" else 1.0) for r in tuned}
    order = dispatch_order(tuned, work)
    assert not any(own_reference(r) for r in order)
    assert [r.estimator for r in order[:4]] == ["ro-ukf"] * 4
    check_groups(order, work)


def test_equal_work_keeps_the_interleave_order(runs):
    inter = interleave(runs)
    # no work known: every run costs 0, so only the reference split reorders
    order = dispatch_order(runs, {})
    assert order == [r for r in inter if own_reference(r)] + [
        r for r in inter if not own_reference(r)
    ]
    # work by mesh only: ties within a mesh keep interleave order, so runs on
    # different data (here: seeds) alternate
    work = {r.run_id: float(r.mesh == "6x2x2") for r in runs}
    order = dispatch_order(runs, work)
    check_groups(order, work)
    position = {r.run_id: i for i, r in enumerate(inter)}
    others = [r for r in order if not own_reference(r)]
    for mesh in MESHES:
        tied = [r for r in others if r.mesh == mesh]
        assert [position[r.run_id] for r in tied] == sorted(
            position[r.run_id] for r in tied
        )
        keys = [r.reference_key() for r in tied]
        assert len(set(keys[:2])) == 2  # different data first
        assert all(a != b for a, b in itertools.pairwise(keys))


def test_runs_missing_from_work_go_last_in_their_group(runs):
    work = {r.run_id: 5.0 for r in runs if r.mesh == "4x1x1"}
    order = dispatch_order(runs, work)
    check_groups(order, work)
    assert [r.mesh for r in order[:4]] == ["4x1x1", "4x1x1", "6x2x2", "6x2x2"]
    assert [r.mesh for r in order[4:]] == ["4x1x1"] * 4 + ["6x2x2"] * 4


# --- shared products of a session --------------------------------------------


@pytest.fixture(scope="module")
def computed(cache_env, registry, runs) -> tuple[Session, RunSpec]:
    """A session that fitted the reference and ran the direct runs of one run."""
    spec = next(r for r in runs if r.estimator == "rls" and r.mesh == "4x1x1")
    session = Session(registry)
    session.reference(spec)
    session.direct(spec)
    session.direct(spec, "stretch-x")  # the transfer scenario's
    return session, spec


def refuse(*args: Any, **kwargs: Any) -> Any:
    raise AssertionError("computed again instead of adopted")


def test_shared_names_each_product_by_kind_and_key(computed):
    session, spec = computed
    shared = session.shared()
    kinds = sorted(kind for kind, _ in shared)
    assert kinds == ["direct", "direct", "reference", "truth"]  # the fit's data
    assert ("reference", spec.reference_key()) in shared
    products = session.products(spec)
    assert set(shared) <= products  # the transfer truth was not needed here
    assert {k for k in shared if k[0] != "truth"} == {
        k for k in products if k[0] != "truth"
    }
    truth = shared[("truth", spec.truth_product_key(spec.scenario))]
    assert truth.states.size == 0  # runs do not read the states: not shipped
    np.testing.assert_array_equal(truth.grid, session.truth(spec).grid)
    metrics = spec.direct_key(spec.scenario)
    np.testing.assert_array_equal(shared[("direct", metrics)], session.direct(spec))
    assert shared[("direct", metrics)].ndim == 3  # (K, G, d)
    assert shared[("direct", metrics)].shape[0] == STEPS


def test_an_adopting_session_computes_nothing(computed, registry, monkeypatch):
    first, spec = computed
    second = Session(registry)
    assert second.known_reference(spec) is None
    second.adopt(first.shared())
    monkeypatch.setattr(Session, "model", refuse)
    monkeypatch.setattr(idbench.run.session, "simulate_path", refuse)
    np.testing.assert_array_equal(second.reference(spec), first.reference(spec))
    np.testing.assert_array_equal(second.direct(spec), first.direct(spec))
    np.testing.assert_array_equal(
        second.direct(spec, "stretch-x"), first.direct(spec, "stretch-x")
    )
    assert np.isfinite(second.reference(spec)).all()
    assert set(second.shared()) == set(first.shared())


def test_adopt_keeps_what_a_session_already_has(computed, registry):
    first, spec = computed
    second = Session(registry)
    mine = np.array([1234.5])
    second.remember_reference(spec, mine)
    metrics = ("direct", spec.direct_key(spec.scenario))
    second.adopt({metrics: [[[0, 0, 0]]]})
    second.adopt(first.shared())
    assert second.known_reference(spec)[0] == 1234.5
    assert second.reference(spec)[0] == 1234.5
    kept = second.shared()[metrics]
    assert kept.dtype == float and kept.shape == (1, 1, 3) and not kept.any()
    # what it lacked it took
    transfer = ("direct", spec.direct_key("stretch-x"))
    np.testing.assert_array_equal(second.shared()[transfer], first.shared()[transfer])


# --- the worker side and the parent side of passing products -----------------


def test_a_worker_adopts_what_it_is_sent_and_returns_only_what_it_added(
    cache_env, registry, runs, monkeypatch
):
    """The worker loop, run in this process: two runs on one data set."""
    rls = next(r for r in runs if r.estimator == "rls" and r.mesh == "4x1x1")
    batch = next(
        r for r in runs if own_reference(r) and r.reference_key() == rls.reference_key()
    )
    session = Session(registry)
    monkeypatch.setattr(executors.worker, "worker_session", lambda: session)
    monkeypatch.setattr(executors.worker, "_die_with_parent", lambda parent: None)
    ours, theirs = mp.Pipe()
    sentinel = np.array([1234.5])
    ours.send((rls, {("reference", rls.reference_key()): sentinel}))
    ours.send((batch, {}))
    ours.send(None)
    got: list[Any] = []

    def read() -> None:
        while sum(m[0] == "done" for m in got) < 2:
            got.append(ours.recv())

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    handler = signal.getsignal(signal.SIGINT)
    try:
        executors.worker._worker_main(theirs, os.getpid())  # returns on None
    finally:
        signal.signal(signal.SIGINT, handler)
        reader.join(30)
        ours.close()
        theirs.close()
    assert not reader.is_alive()
    assert [m[1] for m in got if m[0] == "phase"] == ["estimator", "scoring"] * 2
    (_, (row1, _), added1), (_, (row2, _), added2) = [m for m in got if m[0] == "done"]
    assert row1["status"] == "ok" and row1["E_ref"] == 1234.5  # adopted, not fitted
    # the reference came in; the truths are computed here (no parent sent them)
    assert {kind for kind, _ in added1} == {"direct", "truth"}
    assert {key for kind, key in added1 if kind == "direct"} == {
        rls.direct_key(rls.scenario),
        rls.direct_key("stretch-x"),
    }
    # the reference estimator's own run keeps the adopted value and adds nothing
    assert row2["status"] == "ok" and row2["E_ref"] == 1234.5
    assert row2["E_final"] != 1234.5
    assert added2 == {}


def test_a_worker_is_sent_only_what_it_lacks(runs):
    sent: list[Any] = []
    w = executors.Worker.__new__(executors.Worker)
    w.conn = SimpleNamespace(send=sent.append)
    w.spec, w.deadline, w.has = None, None, set()
    known: dict[Any, Any] = {("reference", "a"): np.ones(1)}
    w.give(runs[0], known)
    assert sent[-1][0] is runs[0] and set(sent[-1][1]) == {("reference", "a")}
    known[("direct", "b")] = np.zeros((1, 1, 3))
    w.give(runs[1], known)
    assert set(sent[-1][1]) == {("direct", "b")}
    w.give(runs[2], known)
    assert sent[-1][1] == {}
    assert w.has == {("reference", "a"), ("direct", "b")}

    # what it reports back it holds: the pool does not send it again
    pool = executors.Pool.__new__(executors.Pool)
    pool.timeout, pool.attempts = None, {}
    result = ({"run_id": runs[2].run_id}, [])
    done = ("done", result, {("reference", "c"): np.ones(1)})
    w.conn = SimpleNamespace(poll=lambda: True, recv=lambda: done, send=sent.append)
    assert pool.attend(w, []) == (runs[2], result, done[2])
    assert w.spec is None and ("reference", "c") in w.has
    known[("reference", "c")] = np.ones(1)
    w.give(runs[3], known)
    assert sent[-1][1] == {}


# --- the worker pool ---------------------------------------------------------


@pytest.fixture(scope="module")
def serial_and_parallel(cache_env, tmp_path_factory) -> tuple[pd.DataFrame, ...]:
    config = small(truth_mesh="8x2x2", estimators=("rls", "batch-ls"))
    serial, _ = compare(config, tmp_path_factory.mktemp("serial"), jobs=1)
    parallel, _ = compare(config, tmp_path_factory.mktemp("parallel"), jobs=2)
    return serial, parallel


def test_two_workers_give_the_serial_table(serial_and_parallel):
    serial, parallel = serial_and_parallel
    assert len(serial) == 8
    assert list(parallel["run_id"]) == list(serial["run_id"])
    assert (serial["status"] == "ok").all() and (parallel["status"] == "ok").all()
    for col in COMPARED:
        assert np.isfinite(serial[col]).all(), col
        np.testing.assert_allclose(parallel[col], serial[col], rtol=1e-12, err_msg=col)
    np.testing.assert_array_equal(parallel["n_solves"], serial["n_solves"])


def test_every_run_on_one_data_set_has_its_reference_runs_e_ref(serial_and_parallel):
    """The reference value is the reference estimator's own fit in both tables."""
    for table in serial_and_parallel:
        by_data = table.groupby(["mesh", "seed"])
        assert by_data.ngroups == 4
        for _, group in by_data:
            own = group.loc[group["estimator"] == "batch-ls", "E_final"].item()
            assert (group["E_ref"] == own).all()


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_the_pool_starts_from_the_parents_shared_products(
    cache_env, registry, runs, monkeypatch, method
):
    """A worker uses a reference the parent session knows instead of fitting.

    Forked, it holds the parent's session from the start (nothing is sent);
    spawned, it receives the reference with its first run.
    """
    monkeypatch.setenv(executors.START_METHOD_ENV, method)
    chosen = [r for r in runs if r.estimator == "rls" and r.mesh == "4x1x1"]
    assert len(chosen) == 2
    parent = Session(registry)
    for i, spec in enumerate(chosen):
        parent.remember_reference(spec, np.array([1000.0 + i]))
    rows = {row["run_id"]: row for row, _ in execute_all(chosen, parent, jobs=2)}
    for i, spec in enumerate(chosen):
        assert rows[spec.run_id]["status"] == "ok"
        assert rows[spec.run_id]["E_ref"] == 1000.0 + i


# --- workers started ahead ---------------------------------------------------


@pytest.fixture
def spawned(monkeypatch) -> None:
    """Spawned workers, the ones :func:`executors.started` starts ahead."""
    monkeypatch.setenv(executors.START_METHOD_ENV, "spawn")


def test_forked_workers_are_not_started_ahead(monkeypatch):
    monkeypatch.setenv(executors.START_METHOD_ENV, "fork")
    with executors.started(2):
        assert executors.started_ahead() == []  # forked later, from the planned parent


def test_the_next_pool_takes_the_started_workers(spawned, cache_env, registry, runs):
    chosen = [r for r in runs if r.estimator == "rls" and r.mesh == "4x1x1"]
    assert executors.started_ahead() == []
    with executors.started(2):
        spare = list(executors.started_ahead())
        assert len(spare) == 2 and all(w.proc.is_alive() for w in spare)
        rows = [row for row, _ in execute_all(chosen, Session(registry), jobs=2)]
        assert [row["status"] for row in rows] == ["ok", "ok"]
        assert executors.started_ahead() == []  # taken, not left for the block end
        assert not any(w.proc.is_alive() for w in spare)  # and closed with the pool
    assert executors.started_ahead() == []


def test_a_pool_takes_only_the_workers_it_needs_and_stops_the_rest(
    spawned, cache_env, registry, runs
):
    one = [next(r for r in runs if r.estimator == "rls" and r.mesh == "4x1x1")]
    with executors.started(2):
        first, second = executors.started_ahead()
        rows = [row for row, _ in execute_all(one, Session(registry), jobs=2)]
        assert [row["status"] for row in rows] == ["ok"]
        # the one it did not need was stopped when the pool was built
        assert executors.started_ahead() == []
        assert not first.proc.is_alive() and not second.proc.is_alive()
    assert executors.started_ahead() == []


def test_a_dead_started_worker_is_replaced(spawned, cache_env, registry, runs):
    one = [next(r for r in runs if r.estimator == "rls" and r.mesh == "4x1x1")]
    with executors.started(1):
        (dead,) = executors.started_ahead()
        dead.proc.kill()
        dead.proc.join(5)
        rows = [row for row, _ in execute_all(one, Session(registry), jobs=1,
                                              timeout=60.0)]  # fmt: skip
        assert [row["status"] for row in rows] == ["ok"]
        assert executors.started_ahead() == []


def test_workers_no_pool_took_are_stopped_at_the_end_of_the_block(spawned):
    with executors.started(2):
        spare = list(executors.started_ahead())
        assert len(spare) == 2 and all(w.proc.is_alive() for w in spare)
    assert executors.started_ahead() == []
    assert not any(w.proc.is_alive() for w in spare)
    with executors.started(0):
        assert executors.started_ahead() == []


def test_a_sweep_that_fails_planning_leaves_no_process(cache_env, tmp_path):
    before = set(mp.active_children())  # none, unless another test leaked some
    config = small(estimators=("rls", "no-such-filter"))
    with pytest.raises(ConfigError, match="no-such-filter"):
        compare(config, tmp_path / "out", jobs=2)
    assert executors.started_ahead() == []
    for child in set(mp.active_children()) - before:
        child.join(1)
    assert set(mp.active_children()) <= before
    assert not (tmp_path / "out").exists()


# --- the result store --------------------------------------------------------


def stored(tmp_path: Path) -> ResultStore:
    """A store holding runs a (ok), b (failed), c (ok, no traces) and d (ok)."""
    store = ResultStore(tmp_path / "results", {"steps": 3}, {})
    rows = {"a": "ok", "b": "failed", "c": "ok", "d": "ok"}
    for run_id, status in rows.items():
        traces = [] if run_id == "c" else [
            {"run_id": run_id, "step": k, "E": float(k)} for k in (1, 2)
        ]  # fmt: skip
        store.write({"run_id": run_id, "status": status, "E_final": 1.0}, traces)
    return store


def test_scan_says_which_finished_runs_failed(tmp_path):
    store = stored(tmp_path)
    assert store.scan() == {"a": False, "b": True, "c": False, "d": False}
    assert store.finished() == {"a", "b", "c", "d"}
    assert store.failed() == {"b"}


@pytest.mark.parametrize("kind", ["runs", "traces"])
@pytest.mark.parametrize("damage", ["garbage", "truncated"])
def test_a_damaged_part_is_quarantined_and_its_run_unfinished(tmp_path, kind, damage):
    store = stored(tmp_path)
    part = store.parts / f"d.{kind}.parquet"
    if damage == "garbage":
        part.write_bytes(b"\x00not parquet at all\xff" * 10)
    else:
        part.write_bytes(part.read_bytes()[: part.stat().st_size // 2])
    assert store.scan() == {"a": False, "b": True, "c": False}
    assert sorted(p.name for p in store.quarantine.iterdir()) == [
        "d.runs.parquet", "d.traces.parquet"
    ]  # fmt: skip
    assert not list(store.parts.glob("d.*"))
    assert store.scan() == {"a": False, "b": True, "c": False}  # stays out


def test_a_run_part_without_its_traces_is_not_finished(tmp_path):
    store = stored(tmp_path)
    (store.parts / "a.traces.parquet").unlink()
    assert store.scan() == {"b": True, "c": False, "d": False}
    assert (store.parts / "a.runs.parquet").exists()  # not quarantined: not damaged


def test_consolidate_keeps_the_order_given_and_skips_unfinished(tmp_path):
    store = stored(tmp_path)
    (store.parts / "d.runs.parquet").write_bytes(b"garbage")
    runs, traces = store.consolidate(["c", "x", "b", "d", "a"])
    assert list(runs["run_id"]) == ["c", "b", "a"]
    assert list(runs["status"]) == ["ok", "failed", "ok"]
    assert list(traces["run_id"]) == ["b", "b", "a", "a"]
    assert list(traces["step"]) == [1, 2, 1, 2]
    pd.testing.assert_frame_equal(pd.read_parquet(store.root / "runs.parquet"), runs)
    pd.testing.assert_frame_equal(
        pd.read_parquet(store.root / "traces.parquet"), traces
    )
    assert (store.quarantine / "d.runs.parquet").exists()
    # another order, another table
    runs, _ = store.consolidate(["a", "b"])
    assert list(runs["run_id"]) == ["a", "b"]
    runs, traces = store.consolidate(["x"])
    assert runs.empty and traces.empty


def test_a_session_keeps_truths_and_direct_runs_apart_by_true_value():
    # a Dask worker's session outlives a sweep: a second sweep with another
    # true E must not get the first sweep's truth or direct runs
    kw: dict[str, Any] = dict(
        truth_mesh="10x2x2", meshes=("4x1x1",), steps=3, seeds=1, estimators=("rls",)
    )
    a = runs_of(CompareConfig(**kw))[0]
    b = runs_of(CompareConfig(**kw, true={"E": 8000.0}))[0]
    assert a.direct_key(a.scenario) != b.direct_key(b.scenario)
    shared = Session()
    shared.direct(a), shared.truth(a)
    fresh = Session()
    np.testing.assert_array_equal(shared.direct(b), fresh.direct(b))
    np.testing.assert_array_equal(
        shared.truth(b).observations, fresh.truth(b).observations
    )
    assert not np.array_equal(shared.direct(b), shared.direct(a))


def test_a_free_worker_skips_runs_whose_inputs_another_is_computing(runs, registry):
    # the first queued run shares its data's reference fit (or direct run) with
    # the run a busy worker is on: the free worker takes the next one instead
    session = Session(registry)
    # the truths, as in a sweep, were prepared by the parent: known
    prepared = {k: None for r in runs for k in session.products(r) if k[0] == "truth"}
    busy_spec = next(r for r in runs if own_reference(r))

    def fresh(r: Any) -> set[Any]:
        return session.products(r) - prepared.keys()

    same = [r for r in runs if r is not busy_spec and fresh(r) & fresh(busy_spec)]
    other = [r for r in runs if not fresh(r) & fresh(busy_spec)]
    assert same and other
    busy = [SimpleNamespace(spec=busy_spec)]
    queue = [same[0], other[0]]
    products = session.products
    assert executors.next_run_index(queue, busy, prepared, products) == 1  # type: ignore[arg-type]
    # once what it computes is known, the order stands
    known = {**prepared, **{key: None for key in products(busy_spec)}}
    assert executors.next_run_index(queue, busy, known, products) == 0  # type: ignore[arg-type]
    # nothing free of conflicts within the look-ahead: the first
    assert executors.next_run_index([same[0]], busy, prepared, products) == 0  # type: ignore[arg-type]


def test_started_workers_are_per_thread(spawned, cache_env, registry, runs):
    # a pool in another thread does not take this thread's spares
    one = [next(r for r in runs if r.estimator == "rls" and r.mesh == "4x1x1")]
    with executors.started(1):
        (mine,) = executors.started_ahead()
        rows: list[Any] = []

        def other() -> None:
            rows.extend(row for row, _ in execute_all(one, Session(registry), jobs=2))

        thread = threading.Thread(target=other)
        thread.start()
        thread.join(120)
        assert [row["status"] for row in rows] == ["ok"]
        assert executors.started_ahead() == [mine] and mine.proc.is_alive()
    assert not mine.proc.is_alive()


def test_a_worker_starting_ignores_ctrl_c_until_the_parent_says(spawned, tmp_path):
    # started with SIGINT ignored (inherited): a Ctrl-C while the workers
    # import is the parent's, with no traceback from the children
    script = tmp_path / "ctrl_c.py"
    script.write_text(
        "import os, signal, time\n"
        "from idbench.run import executors\n"
        "with executors.started(2):\n"
        "    time.sleep(0.3)\n"
        "    os.killpg(0, signal.SIGINT)\n"
        "    time.sleep(2)\n"
    )
    done = subprocess.run(
        [sys.executable, str(script)],
        capture_output=True,
        text=True,
        timeout=60,
        start_new_session=True,
    )
    assert done.returncode != 0  # the parent got its KeyboardInterrupt
    assert done.stderr.count("KeyboardInterrupt") == 1, done.stderr


def test_a_part_without_a_status_is_run_again(tmp_path):
    store = ResultStore(tmp_path / "out", {"x": 1}, {})
    store.write({"run_id": "a", "status": "ok"}, [{"run_id": "a", "step": 1}])
    store.write({"run_id": "b", "E_final": 1.0}, [{"run_id": "b", "step": 1}])
    assert store.scan() == {"a": False, "b": True}
    assert store.failed() == {"b"}
