"""The compare summary as people and scripts read it: piped, grouped, formatted.

These run the CLI in a subprocess with stdout a pipe, as `idbench compare | cat`
or a CI log would.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from idbench.cli.commands import main

TINY = ["--truth-mesh", "12x3x3", "--meshes", "4x1x1,6x2x2", "--steps", "4",
        "--seeds", "2"]  # fmt: skip
SKIP_REASON = "over max_solves = 10"


def cli(*argv: str, cache: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "idbench.cli", *argv],
        env={**os.environ, "IDBENCH_CACHE_DIR": str(cache)},
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )


@pytest.fixture(scope="module")
def piped(tmp_path_factory):
    """A sweep over two noise levels, with the full UKF skipped by its budget."""
    tmp = tmp_path_factory.mktemp("piped")
    toml = tmp / "c.toml"
    toml.write_text("[estimators.ukf]\nmax_solves = 10\n")
    out = tmp / "out"
    done = cli("compare", *TINY, "--estimators", "rls,ukf", "--noise", "0,1e-3",
               "--config", str(toml), "--out", str(out),
               cache=tmp / "cache")  # fmt: skip
    assert done.returncode == 0, done.stderr
    return out, done


def test_piped_summary_is_never_cut(piped):
    _, done = piped
    assert "…" not in done.stdout and "..." not in done.stdout
    # the skip reason is printed whole, on the row it explains
    rows = [line for line in done.stdout.splitlines() if line.startswith("bend-y")]
    skipped = [line for line in rows if "skipped" in line]
    assert len(skipped) == 4
    assert all(SKIP_REASON in line and "max_solves" in line for line in skipped)
    assert "shape error (mm/pt)" in done.stdout  # headers with units, unabbreviated


def test_sweep_axes_make_rows(piped):
    out, done = piped
    runs = pd.read_parquet(out / "runs.parquet")
    assert len(runs) == 2 * 2 * 2 * 2  # meshes x estimators x noise x seeds
    rows = [line for line in done.stdout.splitlines() if line.startswith("bend-y")]
    # one row per mesh, estimator and noise level; seeds pooled (n = 2)
    assert len(rows) == 8
    noise_col = done.stdout.splitlines()[1].index("noise sigma")
    assert sorted({r[noise_col:].split()[0] for r in rows}) == ["0", "0.001"]
    assert all(line.split()[5] == "2" for line in rows)  # n (runs)


def test_progress_lines_when_not_a_terminal(piped):
    _, done = piped
    err = done.stderr.splitlines()
    assert any("truth 12x3x3 bend-y: step 4/4" in line for line in err)
    finished = [line for line in err if "finished:" in line]
    assert len(finished) == 16
    assert "run 16/16 finished" in finished[-1]


def test_rows_sort_by_nodes_numerically():
    from idbench.report.write import summarise

    runs = pd.DataFrame(
        {
            "run_id": list("abcd"),
            "scenario": "bend-y",
            "mesh": ["525", "90", "240", "1116"],
            "model_nodes": [525.0, 90.0, 240.0, 1116.0],
            "estimator": "rls",
            "seed": 0,
            "status": "ok",
            "E_true": 1.0,
            "E_final": 0.5,
            "E_ref": 0.5,
        }
    )
    assert summarise(runs)["model_nodes"].tolist() == [90, 240, 525, 1116]


@pytest.mark.parametrize("fmt", ["csv", "json", "markdown"])
def test_formats_for_scripts(piped, fmt):
    out, _ = piped  # a resume: every run is done, only the summary is printed
    done = cli("compare", *TINY, "--estimators", "rls,ukf", "--noise", "0,1e-3",
               "--config", str(out.parent / "c.toml"), "--out", str(out),
               "--format", fmt, cache=out.parent / "cache")  # fmt: skip
    assert done.returncode == 0, done.stderr
    if fmt == "csv":
        table = pd.read_csv(io.StringIO(done.stdout))
        assert len(table) == 8 and {"noise", "n", "E_ratio", "reason"} <= set(table)
    elif fmt == "json":
        records = json.loads(done.stdout)
        assert len(records) == 8
        assert {r["noise"] for r in records} == {0.0, 0.001}
    else:
        lines = done.stdout.splitlines()
        assert lines[0].startswith("| scenario |") and lines[1].startswith("|---")
        assert sum(line.startswith("| bend-y") for line in lines) == 8
        assert lines[0].rstrip().endswith("| reason (not ok) |")
    if fmt != "markdown":
        assert "wrote" not in done.stdout  # machine output stays clean


def test_terminal_table_abbreviates_headers_not_numbers(piped):
    from idbench.report.write import summarise, summary_text

    out, _ = piped
    runs = pd.read_parquet(out / "runs.parquet")
    text = summary_text(runs, "table", width=80)
    assert "…" not in text
    assert all(len(line) <= 80 for line in text.splitlines() if "[" not in line)
    s = summarise(runs)
    for v in s["E_final"].dropna():
        assert f"{v:.4g}" in text or f"{v:.0f}" in text
    assert "[1]" in text and SKIP_REASON in text.replace("\n    ", " ")


def test_help_shows_defaults_and_names(capsys):
    for argv, wanted in (
        (["compare", "--help"], ["(default: 20)", "(default: 0.0001)",
                                  "(default: 3; --quick: 1)", "bend-y",
                                  "table, markdown, csv or json"]),
        (["calibrate", "--help"], ["(default: 10)", "(default: 3)",
                                    "(default: 0,0.5,1,2,5,15,45,75,90)"]),
        (["simulate", "--help"], ["(default: 20)", "bend-y", "svk-beam"]),
    ):  # fmt: skip
        with pytest.raises(SystemExit):
            main(argv)
        text = " ".join(capsys.readouterr().out.split())
        for w in wanted:
            assert w in text, (argv, w)
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "``" not in capsys.readouterr().out


def test_info_shows_settings_not_private_fields(capsys):
    assert main(["info", "ro-ukf"]) == 0
    out = capsys.readouterr().out
    assert "sigma_floor" in out and "Lower bound (m) on the observation noise" in out
    assert "sigma_points" in out and "'simplex'" in out
    assert "_run" not in out
    assert main(["info", "ro-ukf", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert [s["name"] for s in info["settings"]] == [
        "transform", "sigma_floor", "correction", "sigma_points", "param_noise",
        "model_error"]  # fmt: skip
    assert main(["info", "no-such-thing"]) == 2


def test_info_knows_observation_kinds(capsys):
    assert main(["info", "cloud"]) == 0
    out = capsys.readouterr().out
    assert "cloud (observation, plugin idbench)" in out
    assert "points" in out and "--observe-option cloud.NAME=VALUE" in out
    assert main(["info", "force", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "observation"
    assert main(["info", "no-such-kind"]) == 2
    assert "markers" in capsys.readouterr().err
