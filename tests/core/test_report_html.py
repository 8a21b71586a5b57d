"""report.html in a real headless browser (Chromium through Playwright).

Skipped, with the reason, only where no browser can be driven
(:mod:`support.browser`).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from support.browser import launched
from support.helpers import compare_into


@pytest.fixture(scope="module")
def browser():
    yield from launched()


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    return compare_into(
        tmp_path_factory.mktemp("html"), "--truth-mesh", "12x3x3", "--meshes",
        "4x1x1,6x2x2", "--steps", "4", "--seeds", "1", "--estimators", "rls,lms",
        "--noise", "0,1e-3", "--plot",
    )  # fmt: skip


@pytest.fixture
def page(browser, report):
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    errors: list[str] = []
    requests: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else 0)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("request", lambda r: requests.append(r.url))
    page.goto((report / "report.html").as_uri())
    page.wait_for_load_state("load")
    yield page, errors, requests
    page.close()


def _column(page, header: str) -> list[str]:
    index = page.eval_on_selector_all(
        "#summary thead th",
        "(ths, h) => ths.findIndex(t => t.textContent === h)",
        header,
    )
    assert index >= 0, header
    return page.eval_on_selector_all(
        "#summary tbody tr",
        "(rows, i) => rows.map(r => r.cells[i].getAttribute('data-value'))",
        index,
    )


def test_renders_offline_without_errors(page):
    pg, errors, requests = page
    assert errors == []
    assert all(url.startswith("file:") for url in requests), requests
    assert pg.title() == "idbench report"
    # two noise levels x two meshes x two estimators: eight summary rows
    assert pg.locator("#summary tbody tr").count() == 8


def test_every_figure_is_visible(page, report):
    pg, _, _ = page
    stems = sorted(p.stem for p in report.glob("*.svg"))
    assert len(stems) == 5
    for stem in stems:
        svg = pg.locator(f"#fig-{stem} svg")
        assert svg.count() == 1, stem
        svg.scroll_into_view_if_needed()
        assert svg.is_visible(), stem
        box = svg.bounding_box()
        assert box is not None and box["width"] > 200 and box["height"] > 150, stem


def test_clicking_a_header_sorts_the_table(page):
    pg, errors, _ = page
    before = [float(v) for v in _column(pg, "E final")]
    assert before != sorted(before)  # the default order is by mesh, not by E
    pg.click("#summary thead th:text-is('E final')")
    assert [float(v) for v in _column(pg, "E final")] == sorted(before)
    assert pg.get_attribute("#summary thead th:text-is('E final')", "aria-sort") == (
        "ascending"
    )
    pg.click("#summary thead th:text-is('E final')")
    assert [float(v) for v in _column(pg, "E final")] == sorted(before, reverse=True)
    pg.click("#summary thead th:text-is('estimator')")  # text columns sort too
    names = _column(pg, "estimator")
    assert names == sorted(names)
    assert errors == []


def test_metric_selector_shows_one_metric(page):
    pg, errors, _ = page
    pg.select_option("#metric", "E_ratio")
    assert pg.is_visible("#summary thead th:text-is('E / E_true')")
    assert not pg.is_visible("#summary thead th:text-is('E final')")
    assert pg.is_visible("#summary thead th:text-is('estimator')")  # keys stay
    pg.select_option("#metric", "all")
    assert pg.is_visible("#summary thead th:text-is('E final')")
    assert errors == []


def test_data_links_point_next_to_the_page(page, report):
    pg, _, _ = page
    hrefs = pg.eval_on_selector_all("a[download]", "as => as.map(a => a.href)")
    local = {
        Path(h.removeprefix("file://")).name for h in hrefs if h.startswith("file:")
    }
    assert {"runs.parquet", "traces.parquet", "manifest.json"} <= local
    assert any(h.startswith("data:text/csv;base64,") for h in hrefs)
    html = (report / "report.html").read_text()
    for fetch in ('src="http', 'href="http', "url(http", "@import", "<link"):
        assert fetch not in html  # nothing to fetch: usable offline


def test_manifest_is_shown(page):
    pg, _, _ = page
    text = pg.inner_text("body")
    assert "version of numpy" in text and "cpu_count" in text
    assert '"truth_mesh": "12x3x3"' in text
