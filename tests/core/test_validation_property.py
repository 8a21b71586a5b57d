"""Property: any option string gives a clean dry run or one clean error line."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from idbench.cli.commands import main

BASE = ["compare", "--dry-run", "--truth-mesh", "12x3x3", "--meshes", "4x1x1",
        "--steps", "4", "--seeds", "1"]  # fmt: skip

numberish = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-5, 50).map(str),
    st.text(alphabet="0123456789.,-eE xabc", max_size=12),
)
options = st.sampled_from(
    ["--noise", "--obs-every", "--obs-points", "--steps", "--seeds", "--nu",
     "--E-true", "--prior", "--timeout", "--estimators", "--scenarios", "--meshes"]
)  # fmt: skip


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "c"))


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(st.lists(st.tuples(options, numberish), min_size=1, max_size=3))
def test_random_options_run_or_fail_cleanly(capsys, pairs):
    argv = list(BASE)
    for opt, value in pairs:
        argv += [opt, value]
    code = main(argv)
    out, err = capsys.readouterr()
    assert "Traceback" not in err + out
    if code == 0:
        assert " runs; " in out
    else:
        assert code == 2
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("idbench: error: "), err


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(
    key=st.text(alphabet="abcdefghijklmnopqrstuvwxyz_-", min_size=1, max_size=12),
    value=st.one_of(st.integers(-3, 3), st.floats(allow_nan=False), st.text(max_size=5),
                    st.lists(st.integers(0, 3), max_size=3)),
)  # fmt: skip
def test_random_toml_keys_run_or_fail_cleanly(tmp_path_factory, capsys, key, value):
    import json

    path = tmp_path_factory.mktemp("toml") / "c.toml"
    path.write_text(f"{key} = {json.dumps(value)}\n")
    code = main([*BASE, "--config", str(path)])
    out, err = capsys.readouterr()
    assert "Traceback" not in err + out
    assert code in (0, 2)
    if code == 2:
        assert len(err.strip().splitlines()) == 1
