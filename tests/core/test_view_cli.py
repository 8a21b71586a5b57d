"""``idbench view DIR [--run ID]``: opens report.html's 3D view, or prints its path."""

from __future__ import annotations

import webbrowser

import pandas as pd
import pytest
from support.helpers import MODEL, STEPS, TRUTH, compare_into

from idbench.cli.commands import main


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    return compare_into(
        tmp_path_factory.mktemp("view"), "--truth-mesh", TRUTH, "--meshes", MODEL,
        "--steps", str(STEPS), "--seeds", "2", "--estimators", "rls",
    )  # fmt: skip


def test_it_opens_the_view_in_the_browser(out, monkeypatch, capsys):
    opened = []
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(webbrowser, "open", lambda url: opened.append(url) or True)
    assert not (out / "report.html").exists()
    assert main(["view", str(out)]) == 0
    assert (out / "report.html").exists()  # written first: it was missing
    assert opened == [(out / "report.html").resolve().as_uri() + "#view"]
    assert "opened" in capsys.readouterr().out


def test_a_run_is_shown_first_by_its_id_or_a_unique_prefix(out, monkeypatch, capsys):
    opened = []
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(webbrowser, "open", lambda url: opened.append(url) or True)
    run_id = str(pd.read_parquet(out / "runs.parquet")["run_id"].iloc[1])
    assert main(["view", str(out), "--run", run_id[:6]]) == 0
    assert opened[-1].endswith(f"#run={run_id}")
    assert main(["view", str(out), "--run", "nosuchrun"]) == 2
    assert "no run" in capsys.readouterr().err


def test_without_a_display_it_prints_the_path(out, monkeypatch, capsys):
    monkeypatch.setattr("sys.platform", "linux")
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(webbrowser, "open", lambda url: pytest.fail("opened"))
    assert main(["view", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == str(out / "report.html")
    assert "no browser" in printed[1]


def test_a_folder_without_results_is_refused(tmp_path, capsys):
    assert main(["view", str(tmp_path)]) == 2
    assert "compare output" in capsys.readouterr().err
