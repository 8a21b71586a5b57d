"""Caches never poison themselves.

A generated mesh enters the mesh cache only whole and valid, a damaged one is
generated again; a full disk (``ENOSPC``, simulated) while writing a mesh, a
truth entry or a result part is one line naming the file, and leaves no part
of it behind.
"""

from __future__ import annotations

import errno
import logging
from pathlib import Path

import numpy as np
import pytest

import idbench
from idbench.cli.commands import main
from idbench.truth import simulate
from idbench.truth.cache import cache_dir

gmsh = pytest.importorskip("gmsh")

from idbench_fem.bodies import catalog as bodies  # noqa: E402
from idbench_fem.bodies import geometry  # noqa: E402
from idbench_fem.bodies.mesh import read_mesh  # noqa: E402
from idbench_fem.models.solid import make_model  # noqa: E402

NODES = "60"
TINY = ["--truth-mesh", "12x3x3", "--meshes", "4x1x1", "--steps", "3", "--seeds",
        "1", "--estimators", "rls"]  # fmt: skip


def _full_disk(*_args, **_kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    """An empty cache; meshes made with one gmsh pass (no size search)."""
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(geometry, "_length_for", lambda g, n, h0: (h0, n, 0))
    return tmp_path / "cache"


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*")) if folder.exists() else []


def test_a_truncated_cached_mesh_is_regenerated_and_the_run_succeeds(cache, caplog):
    liver = bodies.get_body("liver")
    path = bodies.mesh_file(liver, NODES)
    whole = read_mesh(path)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])  # a full disk
    with caplog.at_level(logging.WARNING):
        again = bodies.mesh_file(liver, NODES)
    assert again == path and "generating it again" in caplog.text
    assert str(path) in caplog.text
    assert len(read_mesh(path).points) == len(whole.points)
    scenario = idbench.Scenario("sag-90", {"body": "liver", "manipulation": "sag-90"})
    model = make_model(idbench.ModelSpec(NODES, scenario, 2, 2, {}))
    u = model.step(np.array([4000.0]), 1, model.reset())
    assert np.isfinite(u).all() and np.abs(u).max() > 0
    assert not [n for n in _leftovers(cache / "meshes") if n.startswith(".tmp-")]


def test_a_full_disk_while_meshing_is_one_line_naming_the_file(cache, monkeypatch):
    written = []

    def half_then_full(name):
        Path(name).write_text("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nod")
        written.append(name)
        _full_disk()

    monkeypatch.setattr(gmsh, "write", half_then_full)
    with pytest.raises(OSError) as err:
        bodies.mesh_file(bodies.get_body("liver"), NODES)
    text = str(err.value)
    target = cache / "meshes" / "liver" / "liver-n60.msh"
    assert str(target) in text and "disk is full" in text and "\n" not in text
    assert written  # the write did start
    assert _leftovers(cache / "meshes") == ["liver"]  # no part of it


def test_a_mesh_gmsh_truncated_silently_never_enters_the_cache(cache, monkeypatch):
    real = gmsh.write

    def truncating(name):
        real(name)
        data = Path(name).read_bytes()
        Path(name).write_bytes(data[: len(data) * 2 // 3])  # and no error

    monkeypatch.setattr(gmsh, "write", truncating)
    with pytest.raises(ValueError) as err:
        bodies.mesh_file(bodies.get_body("liver"), NODES)
    assert "liver-n60.msh" in str(err.value) and "\n" not in str(err.value)
    assert _leftovers(cache / "meshes") == ["liver"]


@pytest.fixture
def beam(tmp_path, monkeypatch):
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path / "cache"))
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=False))
    spec = idbench.ModelSpec(mesh="6x2x2", scenario=reg.scenario("bend-y"), n_steps=3)
    return reg.model("svk-beam")(spec)


def test_a_full_disk_for_the_truth_cache_names_the_file(beam, monkeypatch, caplog):
    def half_then_full(fh, **arrays):
        fh.write(b"PK\x03\x04 half an npz")
        _full_disk()

    monkeypatch.setattr(np, "savez", half_then_full)
    with caplog.at_level(logging.WARNING):
        got = simulate.simulate_truth(beam, np.array([5000.0]))
    assert got.states.shape == (3, beam.reset().size)  # the sweep goes on
    (record,) = [r for r in caplog.records if "truth cache" in r.getMessage()]
    text = record.getMessage()
    key = simulate.truth_key(beam, np.array([5000.0]))
    assert str(cache_dir() / f"truth-{key}.npz") in text
    assert "disk is full" in text and "\n" not in text
    assert _leftovers(cache_dir()) == []


def test_a_full_disk_for_a_result_part_is_one_line_naming_it(tmp_path, monkeypatch,
                                                              capsys):  # fmt: skip
    import pandas as pd

    out = tmp_path / "out"
    monkeypatch.setattr(pd.DataFrame, "to_parquet", _full_disk)
    assert main(["compare", *TINY, "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "disk is full" in err and str(out / "parts") in err
    assert not list(out.rglob(".tmp-*"))
