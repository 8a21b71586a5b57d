"""A recording is untrusted input: checked as a whole before any run starts.

Each case is one line on stderr, exit 2, nothing stored: a frames.npz that is
no zip, truncated, of the wrong dtype, shape or frame count, an object array,
a decompression bomb; a manifest of the wrong types or with unknown keys;
settings the recording fixes given again; a recording changed under a
resumed folder; names that could not be read back.
"""

from __future__ import annotations

import tracemalloc
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.recordings import arrays_of, edited_copy

from idbench.cli.commands import main
from idbench.observe.kinds import Frame
from idbench.store import recording

TRUTH, MESH, STEPS = "20x3x3", "6x2x2", 4


@pytest.fixture(scope="module")
def rec(tmp_path_factory) -> Path:
    """A markers recording of the beam (4 steps, 2 markers), simulated once."""
    root = tmp_path_factory.mktemp("untrusted")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IDBENCH_CACHE_DIR", str(root / "cache"))
        argv = ["simulate", "--mesh", TRUTH, "--scenario", "bend-y", "--steps",
                str(STEPS), "--noise", "1e-4", "--model-option", "nu=0.4",
                "--record", str(root / "markers")]  # fmt: skip
        assert main(argv) == 0
    return root / "markers"


def refused(rec: Path, tmp_path: Path, capsys, *extra: str) -> str:
    out = tmp_path / "out"
    argv = ["compare", "--data", str(rec), "--meshes", MESH, "--estimators", "rls",
            "--seeds", "1", "--out", str(out), *extra]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err and "unexpected" not in err, err
    assert not out.exists() or not any(out.iterdir()), "nothing stored"
    return err


def put(name: str, value: Any):
    def edit(d: dict[str, np.ndarray]) -> None:
        d[name] = value

    return edit


def replace(old: str, new: str):
    def edit(text: str) -> str:
        assert old in text
        return text.replace(old, new)

    return edit


ARRAYS = [
    (put("frame.00002/markers", np.array(["a"] * 6)), "dtype <U1; allowed"),
    (put("frame.00002/markers", np.ones(6, complex)), "dtype complex128"),
    (put("frame.00001/markers", np.zeros((2, 3))), "markers of shape (2, 3)"),
    (put("frame.00009/markers", np.zeros(6)), "is frame 9; the manifest has steps"),
    (put("frame.00001/extra", np.zeros(3)), "unknown frame data 'frame.00001/extra'"),
    (put("calibration", np.zeros(3)), "unknown member 'calibration'"),
    (put("held_out/secrets", np.zeros((STEPS, 6))), "unknown member 'held_out/sec"),
    (put("frame.00001/sigma", np.array(0.0)), "sigma = 0.0: need one finite number"),
    (put("frame.00001/sigma", np.array(-1e-4)), "need one finite number > 0"),
    (put("frame.00001/force", np.array([1.0, np.nan])), "need a vector of finite"),
    (put("frame.00002/force", np.array([np.inf])), "frame 2: force = [inf]"),
    (put("frame.00001/origin", np.zeros(2)), "origin of shape (2,): need the camera"),
]  # fmt: skip


@pytest.mark.parametrize(("edit", "words"), ARRAYS)
def test_bad_arrays_are_one_line(rec, tmp_path, capsys, edit, words) -> None:
    bad = edited_copy(rec, tmp_path / "bad", edit)
    assert words in refused(bad, tmp_path, capsys)


MANIFESTS = [
    (replace("steps = 4", 'steps = "4"'), "steps = '4' (str) in recording.toml: need"),
    (replace("noise = 0.0001", 'noise = "1e-4"'), "noise = '1e-4' (str)"),
    (replace("markers = 2", "markers = 2.5"), "markers = 2.5 (float)"),
    (replace('scenario = "bend-y"', "scenario = 3"), "scenario = 3 (int)"),
    (lambda t: "extra = 1\n" + t, "unknown key 'extra' in recording.toml"),
    (replace("E = 5000.0", 'E = "5000"'), "need a table of finite numbers"),
    (replace("E = 5000.0", "E = 1e12"),
     "[true] E = 1e+12 is outside the model's bounds"),
]  # fmt: skip


@pytest.mark.parametrize(("toml", "words"), MANIFESTS)
def test_bad_manifests_are_one_line(rec, tmp_path, capsys, toml, words) -> None:
    bad = edited_copy(rec, tmp_path / "bad", toml=toml)
    assert words in refused(bad, tmp_path, capsys)


def test_an_object_array_is_refused_without_unpickling(rec, tmp_path, capsys):
    bad = edited_copy(rec, tmp_path / "bad")
    data = arrays_of(bad)
    data["frame.00001/markers"] = np.array([{"a": 1}, None], dtype=object)
    np.savez(bad / recording.ARRAYS, **data)  # pickles the object array
    assert "is an object array (a pickle)" in refused(bad, tmp_path, capsys)


def test_a_file_that_is_no_zip_and_a_truncated_zip(rec, tmp_path, capsys):
    bad = edited_copy(rec, tmp_path / "nozip")
    (bad / recording.ARRAYS).write_bytes(b"\x93NUMPY not a zip at all")
    assert "is not a zip archive of .npy arrays" in refused(bad, tmp_path, capsys)
    cut = edited_copy(rec, tmp_path / "cut")
    raw = (cut / recording.ARRAYS).read_bytes()
    (cut / recording.ARRAYS).write_bytes(raw[: len(raw) // 2])
    err = refused(cut, tmp_path / "2", capsys)
    assert "not a zip archive" in err or "truncated" in err


def test_a_decompression_bomb_is_refused_before_it_is_read(rec, tmp_path, capsys):
    bad = edited_copy(rec, tmp_path / "bomb")
    data = arrays_of(bad)
    with zipfile.ZipFile(bad / recording.ARRAYS, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, value in data.items():
            with zf.open(name + ".npy", "w") as fh:
                np.lib.format.write_array(fh, value)
        with zf.open("held_out/points.npy", "w", force_zip64=True) as fh:
            np.lib.format.write_array(fh, np.zeros((STEPS, 2_000_000, 3)))  # 192 MB
    assert (bad / recording.ARRAYS).stat().st_size < 2_000_000  # compresses well
    tracemalloc.start()
    err = refused(bad, tmp_path, capsys)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert "refused before reading" in err and "held_out/points" in err
    assert peak < 50_000_000, f"{peak / 1e6:.0f} MB read"


FIXED = [
    (("--steps", "3"), "fixes steps = 4; got 3"),
    (("--noise", "1e-3"), "fixes noise = 0.0001; got 0.001"),
    (("--observe", "cloud"), "fixes observe = markers; got cloud"),
    (("--obs-points", "4"), "fixes obs_points = 2; got 4"),
    (("--scenarios", "bend-z"), "fixes scenarios = bend-y; got bend-z"),
    (("--model-option", "nu=0.3"), "is of nu = 0.4; got nu = 0.3"),
]


@pytest.mark.parametrize(("extra", "words"), FIXED)
def test_what_a_recording_fixes_cannot_be_given_again(
    rec, tmp_path, capsys, extra, words
) -> None:
    assert words in refused(rec, tmp_path, capsys, *extra)


def test_the_same_values_again_are_accepted(rec, tmp_path) -> None:
    argv = ["compare", "--data", str(rec), "--meshes", MESH, "--estimators", "rls",
            "--seeds", "1", "--steps", "4", "--model-option", "nu=0.4",
            "--out", str(tmp_path / "out")]  # fmt: skip
    assert main(argv) == 0


def test_a_resume_after_the_recording_changed_is_refused(rec, tmp_path, capsys):
    mine = edited_copy(rec, tmp_path / "mine")
    argv = ["compare", "--data", str(mine), "--meshes", MESH, "--estimators", "rls",
            "--seeds", "1", "--out", str(tmp_path / "out")]  # fmt: skip
    assert main(argv) == 0
    data = arrays_of(mine)
    data["frame.00003/markers"] += 1e-5
    np.savez(mine / recording.ARRAYS, **data)
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "data_sha256 was" in err, err


def test_relative_paths_resolve_against_the_recording_not_the_cwd(
    tmp_path, monkeypatch
) -> None:
    frames = [Frame(k, {"markers": np.zeros(6)}) for k in (1, 2)]
    manifest = {"model": "svk-beam", "scenario": "bend-y", "observe": "markers",
                "noise": 1e-4, "markers": 2, "steps": 2}  # fmt: skip
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "body.toml").write_text("# the body\n")
    monkeypatch.chdir(tmp_path / "elsewhere")
    root = tmp_path / "rec"
    recording.write(root, {**manifest, "model_settings": {"body": "./body.toml"}},
                    frames)  # fmt: skip
    (root / "data").mkdir()
    (root / "data" / "body.toml").write_text("# the recording's body\n")
    text = (root / recording.MANIFEST).read_text()
    assert 'body = "../elsewhere/body.toml"' in text  # written relative to it
    (root / recording.MANIFEST).write_text(text.replace("../elsewhere/", "data/"))
    read = recording.read(root)
    assert read.model_settings["body"] == str((root / "data" / "body.toml").resolve())
    (root / recording.MANIFEST).write_text(text.replace("../elsewhere/", "nowhere/"))
    missing = recording.read(root).model_settings["body"]
    assert missing == str((root / "nowhere" / "body.toml").resolve())


NAMES = st.text(st.characters(blacklist_categories=("Cs",)), min_size=1, max_size=12)
LABELS = NAMES.filter(lambda s: "/" not in s and "\\" not in s)  # not paths


@settings(max_examples=60, deadline=None)
@given(scenario=NAMES, option=LABELS)
def test_what_write_accepts_read_gives_back(tmp_path_factory, scenario, option):
    root = tmp_path_factory.mktemp("names")
    frames = [Frame(1, {"markers": np.zeros(3)})]
    manifest = {"model": "m", "scenario": scenario, "observe": "markers",
                "noise": 0.0, "markers": 1, "steps": 1,
                "model_settings": {"label": option}}  # fmt: skip
    try:
        recording.write(root, manifest, frames)
    except recording.RecordingError as exc:  # refused at the door, in one line
        assert not scenario.isprintable() and "\n" not in str(exc)
        return
    back = recording.read(root)
    assert back.scenario == scenario and back.model_settings["label"] == option
