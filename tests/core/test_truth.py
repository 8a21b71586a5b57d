"""The truth cache and ``idbench simulate``."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

import idbench
from idbench.cli.commands import main
from idbench.truth import cache, simulate


@pytest.fixture()
def beam(tmp_path, monkeypatch):
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path / "cache"))
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=False))
    spec = idbench.ModelSpec(mesh="6x2x2", scenario=reg.scenario("bend-y"), n_steps=3)
    return reg.model("svk-beam")(spec)


def test_truth_is_cached_and_reused(beam):
    theta = np.array([5000.0])
    first = simulate.simulate_truth(beam, theta)
    solves = beam.cost().forward_solves
    again = simulate.simulate_truth(beam, theta)
    assert beam.cost().forward_solves == solves  # loaded, not simulated
    np.testing.assert_array_equal(first.states, again.states)
    np.testing.assert_array_equal(first.grid, again.grid)
    assert first.observations.shape == (3, 6)
    # another modulus is another entry
    other = simulate.simulate_truth(beam, np.array([4000.0]))
    assert beam.cost().forward_solves == solves + 3
    assert np.abs(other.states[-1]).max() > np.abs(first.states[-1]).max()
    assert len(list(cache.cache_dir().glob("truth-*.npz"))) == 2


def test_truncated_cache_entry_is_recomputed(beam):
    theta = np.array([5000.0])
    first = simulate.simulate_truth(beam, theta)
    (entry,) = cache.cache_dir().glob("truth-*.npz")
    entry.write_bytes(entry.read_bytes()[:100])
    again = simulate.simulate_truth(beam, theta)
    np.testing.assert_array_equal(first.states, again.states)
    with np.load(entry, allow_pickle=False) as data:  # rewritten whole
        assert data["states"].shape == first.states.shape


class _Payload:
    """Unpickling this would create a file: proof that pickle ran."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_a_pickled_cache_entry_is_never_unpickled(beam, tmp_path):
    theta = np.array([5000.0])
    first = simulate.simulate_truth(beam, theta)
    (entry,) = cache.cache_dir().glob("truth-*.npz")
    with np.load(entry, allow_pickle=False) as data:
        key = data["key"]
    marker = tmp_path / "pwned"
    evil = np.array([_Payload(str(marker))], dtype=object)
    with open(entry, "wb") as fh:
        np.savez(fh, key=key, states=evil)  # object array: stored as a pickle
    again = simulate.simulate_truth(beam, theta)
    assert not marker.exists()
    np.testing.assert_array_equal(first.states, again.states)


def test_no_pickle_or_eval_in_the_code():
    import pathlib
    import re

    root = pathlib.Path(__file__).resolve().parents[2]
    sources = [*(root / "idbench").rglob("*.py"), *(root / "plugins").rglob("*.py")]
    assert len(sources) > 20
    banned = re.compile(
        r"^\s*(import|from)\s+(pickle|cloudpickle|dill|shelve|marshal)\b"
        r"|\b(eval|exec)\(|allow_pickle\s*=\s*True|read_pickle|to_pickle",
        re.M,
    )
    texts = {str(p.relative_to(root)): p.read_text() for p in sources}
    hits = [f"{n}: {m[0]}" for n, t in texts.items() for m in banned.finditer(t)]
    assert hits == []


def test_key_ignores_probes_but_not_physics(beam):
    desc = beam.describe()
    key = simulate.truth_key(beam, np.array([5000.0]))
    assert key != simulate.truth_key(beam, np.array([5001.0]))
    beam.describe = lambda: {**desc, "markers": 99}
    assert simulate.truth_key(beam, np.array([5000.0])) == key
    beam.describe = lambda: {**desc, "nu": 0.3}
    assert simulate.truth_key(beam, np.array([5000.0])) != key


def test_simulate_cli_writes_xdmf_time_series(tmp_path, capsys):
    out = tmp_path / "beam.xdmf"
    code = main(["simulate", "--mesh", "6x2x2", "--scenario", "bend-y",
                 "--steps", "3", "--out", str(out)])  # fmt: skip
    assert code == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("step")]
    assert len(lines) == 3
    tip_y = [float(ln.split()[-3]) for ln in lines]
    assert tip_y[0] < 0 and tip_y[2] < tip_y[1] < tip_y[0]  # bending in -y grows
    with meshio.xdmf.TimeSeriesReader(out) as reader:
        points, _cells = reader.read_points_cells()
        assert reader.num_steps == 3
        _t, point_data, _ = reader.read_data(2)
    u = point_data["displacement"]
    assert u.shape == points.shape
    assert u[:, 1].min() == pytest.approx(tip_y[2], rel=0.2)


def test_simulate_cli_rejects_bad_input(tmp_path, capsys):
    out = str(tmp_path / "x.xdmf")
    assert main(["simulate", "--mesh", "6x2x2", "--scenario", "twist",
                 "--out", out]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert "twist" in err and "bend-y" in err and "Traceback" not in err
    assert main(["simulate", "--mesh", "nonsense", "--scenario", "bend-y",
                 "--out", out]) == 2  # fmt: skip
    assert "nonsense" in capsys.readouterr().err


def test_simulate_cli_writes_the_models_cell_data(tmp_path, capsys, monkeypatch):
    """A model's optional ``cell_data()`` (region tags) goes with every step."""
    from idbench_fem.models import solid

    def cell_data(self):
        return {"region": np.arange(len(self.mesh_data.tets), dtype=float)}

    monkeypatch.setattr(solid.SolidModel, "cell_data", cell_data)
    out = tmp_path / "beam.xdmf"
    assert main(["simulate", "--mesh", "4x1x1", "--scenario", "bend-y",
                 "--steps", "2", "--out", str(out)]) == 0  # fmt: skip
    with meshio.xdmf.TimeSeriesReader(out) as reader:
        _points, cells = reader.read_points_cells()
        _t, _pd, cell_data = reader.read_data(1)
    n_tets = len(cells[0].data)
    np.testing.assert_array_equal(cell_data["region"][0], np.arange(n_tets))
