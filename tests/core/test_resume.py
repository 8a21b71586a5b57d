"""Resume checks content, not names.

A rerun of ``compare --out DIR`` skips finished runs only if they were made
from the same files (mesh, body), by the same idbench and plugin versions,
with the same resolved settings; otherwise it is refused with one line that
names what differs and both values. A part whose rows belong to another run
is quarantined and its run done again. Tiny meshes, few steps.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import shutil
from pathlib import Path

import meshio
import pandas as pd
import pytest
from support.helpers import MODEL, STEPS, TRUTH, tiny

import idbench.registry.registry
import idbench.run.executors
from idbench.cli.commands import main
from idbench.run.compare import compare, runs_of
from idbench.store.results import ResultsError
from idbench_fem.bodies.box import parse as beam_mesh

ARGS = ["compare", "--truth-mesh", TRUTH, "--meshes", MODEL, "--steps", str(STEPS),
        "--seeds", "1", "--estimators", "rls", "-q"]  # fmt: skip


def write_mesh(path: Path, spec: str) -> str:
    """Write the structured beam ``spec`` to ``path``; the file's SHA-256."""
    beam = beam_mesh(spec)
    meshio.write(path, meshio.Mesh(beam.points, [("tetra", beam.tets)]))
    return hashlib.sha256(path.read_bytes()).hexdigest()


def refusal(capsys, argv: list[str]) -> str:
    """The one line ``idbench`` prints refusing ``argv`` (exit status 2)."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


# --- the files a run read --------------------------------------------------------


def test_a_mesh_file_changed_under_the_same_path_is_refused(tmp_path, capsys):
    mesh = tmp_path / "beam.vtu"
    before = write_mesh(mesh, "4x1x1")
    out = tmp_path / "out"
    argv = [*ARGS, "--meshes", str(mesh), "--out", str(out)]
    assert main(argv) == 0
    ids = set(pd.read_parquet(out / "runs.parquet")["run_id"])
    after = write_mesh(mesh, "5x1x1")  # same path, same box, other content
    err = refusal(capsys, argv)
    assert f"mesh {str(mesh)!r}" in err and "mesh_sha256" in err, err
    assert before[:12] in err and after[:12] in err, err
    assert "use another --out DIR or delete it" in err
    # the run is another run: its id follows the content
    assert {r.run_id for r in runs_of(tiny(meshes=(str(mesh),)))}.isdisjoint(ids)
    write_mesh(mesh, "4x1x1")  # the old content back: it resumes
    assert main(argv) == 0


def test_a_body_file_changed_under_the_same_path_is_refused(tmp_path, monkeypatch):
    """The solid model reads a body TOML (``--model-option body=FILE``)."""
    from support.bodies import write_beam_body

    body, _ = write_beam_body(tmp_path, spec="4x1x1")
    monkeypatch.setenv("IDBENCH_BODIES", str(body))  # registers its scenarios
    cfg = tiny(model="solid", model_settings={"solid": {"body": str(body)}},
               truth_mesh="truth", meshes=("truth",), scenarios=("end",),
               prior=(2500.0, 2500.0))  # fmt: skip
    out = tmp_path / "out"
    compare(cfg, out)
    text = body.read_text()
    body.write_text(text.replace("[0.0, -8.9, 0.0]", "[0.0, -9.9, 0.0]"))
    what = r"mesh 'truth' \(scenario 'end'\) of body_sha256 "
    digests = r"[0-9a-f]{12}\.\.\., now [0-9a-f]{12}"
    with pytest.raises(ResultsError, match=what + digests):
        compare(cfg, out)
    body.write_text(text)
    compare(cfg, out)


# --- versions ------------------------------------------------------------------------


def test_a_plugin_version_change_is_refused(tmp_path, monkeypatch, counted):
    real = idbench.registry.registry.plugin_version
    version = {"filters": "0.0.1"}

    def fake(pm, name):
        return version.get(name) or real(pm, name)

    monkeypatch.setattr(idbench.registry.registry, "plugin_version", fake)
    out = tmp_path / "out"
    compare(tiny(), out)
    recorded = json.loads((out / "manifest.json").read_text())["plugins"]
    assert recorded["filters"] == "0.0.1" and "fem" in recorded
    version["filters"] = "0.0.2"  # the estimators' plugin upgraded
    with pytest.raises(ResultsError, match=r"plugin 'filters' 0\.0\.1, now 0\.0\.2"):
        compare(tiny(), out)
    assert len(counted) == 1
    version["filters"] = "0.0.1"
    compare(tiny(), out)
    assert len(counted) == 1  # resumed: nothing ran again


def test_a_folder_of_another_idbench_version_is_refused(tmp_path):
    out = tmp_path / "out"
    compare(tiny(), out)
    path = out / "manifest.json"
    manifest = json.loads(path.read_text())
    manifest["versions"]["idbench"] = "0.0.9"
    path.write_text(json.dumps(manifest))
    now = importlib.metadata.version("idbench")
    with pytest.raises(ResultsError, match=rf"idbench 0\.0\.9, now {now}"):
        compare(tiny(), out)


def test_a_folder_of_an_idbench_that_recorded_no_contents_is_refused(tmp_path):
    out = tmp_path / "out"
    compare(tiny(), out)
    path = out / "manifest.json"
    manifest = json.loads(path.read_text())
    del manifest["inputs"], manifest["plugins"]  # as idbench 0.1.0 wrote it
    path.write_text(json.dumps(manifest))
    with pytest.raises(ResultsError, match="did not record plugin versions and what"):
        compare(tiny(), out)


# --- settings: resolved, not as given ------------------------------------------


@pytest.mark.parametrize(
    "first, second",
    [([], ["--nu", "0.45", "--E-true", "5000"]),
     (["--nu", "0.45", "--E-true", "5000"], []),
     (["--model-option", "grid=[20,4,4]"], ["--true", "E=5000.0"])],
)  # fmt: skip
def test_giving_a_default_explicitly_resumes(tmp_path, counted, first, second):
    out = ["--out", str(tmp_path / "out")]
    assert main([*ARGS, *first, *out]) == 0
    assert len(counted) == 1
    assert main([*ARGS, *second, *out]) == 0
    assert len(counted) == 1  # resumed, not run again


@pytest.mark.parametrize(
    "extra, words",
    [(["--steps", "6"], "steps was 5, now 6"),
     (["--noise", "2e-4"], "noise was [0.0001], now [0.0002]"),
     (["--estimators", "lms"], 'estimators was ["rls"], now ["lms"]'),
     (["--nu", "0.4"], "model_settings.svk-beam.nu was 0.45, now 0.4"),
     (["--E-true", "4000"], "true.E was 5000.0, now 4000.0"),
     (["--prior", "3000,1000"], "prior was [2500.0, 2500.0], now [3000.0, 1000.0]")],
)  # fmt: skip
def test_a_refusal_names_the_setting_and_both_values(tmp_path, capsys, extra, words):
    out = ["--out", str(tmp_path / "out")]
    assert main([*ARGS, *out]) == 0
    err = refusal(capsys, [*ARGS, *extra, *out])
    assert "other settings" in err and words in err, err


# --- part files ----------------------------------------------------------------


def test_a_part_moved_under_another_runs_name_is_quarantined(tmp_path, caplog, counted):
    cfg = tiny(estimators=("rls", "lms"))
    out = tmp_path / "out"
    runs, _ = compare(cfg, out)
    a, b = runs["run_id"]
    parts = out / "parts"
    for kind in ("runs", "traces"):  # b's parts now hold a's result
        shutil.copy(parts / f"{a}.{kind}.parquet", parts / f"{b}.{kind}.parquet")
    counted.clear()
    again, _ = compare(cfg, out)
    assert counted == [b]  # b done again, a kept
    assert list(again["run_id"]) == [a, b]
    pd.testing.assert_series_equal(again["E_final"], runs["E_final"])
    moved = pd.read_parquet(out / "quarantine" / f"{b}.runs.parquet")
    assert list(moved["run_id"]) == [a]
    assert f"run {b}: its stored result belongs to run {a}" in caplog.text


def test_a_traces_part_of_another_run_is_quarantined(tmp_path, caplog):
    cfg = tiny(estimators=("rls", "lms"))
    out = tmp_path / "out"
    runs, traces = compare(cfg, out)
    a, b = runs["run_id"]
    parts = out / "parts"
    shutil.copy(parts / f"{a}.traces.parquet", parts / f"{b}.traces.parquet")
    _, again = compare(cfg, out)
    assert (out / "quarantine" / f"{b}.traces.parquet").exists()
    assert "its traces part" in caplog.text
    pd.testing.assert_frame_equal(
        again.drop(columns=["wall_s"]), traces.drop(columns=["wall_s"])
    )
