"""report.html's 3D view in a real headless browser (Chromium through Playwright).

The canvas draws something, the step slider and the choice of run change its
pixels, so do the markers' and the targets' layers, nothing is fetched, a
hostile estimator name and message stay text, and a folder whose stored
surfaces fail their checks says so instead of drawing them. Skipped only
where no browser can be driven (:mod:`support.browser`).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass

import numpy as np
import pytest
from support.browser import launched
from support.helpers import registry_with

import idbench
from idbench import CompareConfig
from idbench.report.write import write_report
from idbench.run.compare import compare
from idbench_filters.rls import Rls

HOSTILE = "<img src=x onerror=alert(1)>"


@dataclass
class Hostile(Rls):
    pass


@dataclass
class Fails(Rls):
    def update(self, k, observation):
        if k == 3:
            raise ValueError(f"{HOSTILE} at step {k}")
        return super().update(k, observation)


class Plugin:
    @idbench.hookimpl
    def register_estimators(self, register):
        register(HOSTILE, Hostile)
        register("fails", Fails)


@pytest.fixture(scope="module")
def browser():
    yield from launched()


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("view") / "out"
    config = CompareConfig(
        truth_mesh="12x3x3", meshes=("4x1x1", "6x2x2"), steps=4, seeds=2,
        estimators=("rls", HOSTILE, "fails"), observe=("markers+cloud",),
        observe_settings={"cloud": {"points": 150, "outliers": 0.1}},
    )  # fmt: skip
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IDBENCH_CACHE_DIR", str(out.parent / "cache"))
        compare(config, out, registry=registry_with({"hostile": Plugin()}))
    write_report(out)
    return out


def opened(browser, path, fragment=""):
    page = browser.new_page(viewport={"width": 1100, "height": 900})
    seen = {"errors": [], "requests": [], "dialogs": []}
    errors = seen["errors"]
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else 0)
    page.on("pageerror", lambda e: seen["errors"].append(str(e)))
    page.on("request", lambda r: seen["requests"].append(r.url))
    page.on("dialog", lambda d: (seen["dialogs"].append(d.message), d.dismiss()))
    page.goto(path.as_uri() + fragment)
    page.wait_for_load_state("load")
    page.locator("#view").scroll_into_view_if_needed()
    return page, seen


PIXELS = """() => {
  const c = document.querySelector('#view3d canvas');
  const copy = document.createElement('canvas');
  copy.width = c.width; copy.height = c.height;
  const g = copy.getContext('2d');
  g.drawImage(c, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let drawn = 0, hash = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (d[i] < 250 || d[i + 1] < 250 || d[i + 2] < 250) { drawn++; }
    hash = (hash * 31 + d[i] + 7 * d[i + 1] + 13 * d[i + 2]) % 1000000007;
  }
  return [drawn / (d.length / 4), hash];
}"""


def test_the_view_draws_and_the_slider_and_the_run_change_it(browser, report):
    page, seen = opened(browser, report / "report.html")
    drawn, first = page.evaluate(PIXELS)
    assert drawn > 0.02  # not blank: the surface covers part of the canvas
    slider = page.locator("#view3d-step")
    assert slider.get_attribute("max") == "3"  # four stored steps
    slider.fill("0")  # the first step: the body barely loaded
    _, at_first = page.evaluate(PIXELS)
    assert at_first != first
    assert page.locator("#view3d .view-step").text_content() == "step 1 of 4"
    page.select_option("#view3d select[data-axis=mesh]", "6x2x2")
    _, other = page.evaluate(PIXELS)
    assert other != at_first
    assert "6x2x2" in page.locator("#view3d .view-info").text_content()
    page.locator("#view3d-cloud").uncheck()  # the cloud's points are drawn
    _, without_cloud = page.evaluate(PIXELS)
    assert without_cloud != other
    assert seen["errors"] == []
    assert all(url.startswith("file:") for url in seen["requests"]), seen["requests"]


def test_the_markers_and_the_targets_layers_draw(browser, report):
    """Observed markers and the beam's default target: each layer shows pixels."""
    page, seen = opened(browser, report / "report.html")
    page.select_option("#view3d select[data-axis=estimator]", "rls")
    assert page.locator("#view3d-step").input_value() == "3"  # the last step
    _, both = page.evaluate(PIXELS)
    for layer in ("markers", "targets"):
        box = page.locator(f"#view3d-{layer}")
        assert box.is_enabled() and box.is_checked()
        box.uncheck()
        _, without = page.evaluate(PIXELS)
        assert without != both, layer
        box.check()
        assert page.evaluate(PIXELS)[1] == both, layer
    legend = page.locator("#view3d .view-legend").text_content()
    assert "markers, observed" in legend and "targets, true" in legend
    assert seen["errors"] == []


def test_a_region_is_the_targets_95_percent_ellipsoid():
    from idbench.report.scene import REGION, ellipsoid_axes
    from idbench.score.metrics import ellipsoid_covers

    assert REGION == pytest.approx(2.7955, abs=1e-4)
    rng = np.random.default_rng(0)
    root = rng.normal(size=(3, 3))
    cov = root @ root.T
    axes = ellipsoid_axes(cov[None])[0]
    np.testing.assert_allclose(axes @ axes.T, REGION**2 * cov, rtol=1e-9)
    for j in range(3):  # each semi-axis ends on the region's boundary
        assert ellipsoid_covers(0.999 * axes[:, j], cov) == 1.0
        assert ellipsoid_covers(1.001 * axes[:, j], cov) == 0.0
    assert np.isnan(ellipsoid_axes(np.full((1, 3, 3), np.nan))).all()


def test_a_summary_row_and_a_run_id_choose_the_run(browser, report):
    import pandas as pd

    runs = pd.read_parquet(report / "runs.parquet")
    chosen = runs[(runs["estimator"] == "rls") & (runs["mesh"] == "6x2x2")]
    run_id = str(chosen[chosen["seed"] == 1]["run_id"].iloc[0])
    page, seen = opened(browser, report / "report.html", f"#run={run_id}")
    selected = {
        axis: page.locator(f"#view3d select[data-axis={axis}]").input_value()
        for axis in ("mesh", "estimator", "seed")
    }
    assert selected == {"mesh": "6x2x2", "estimator": "rls", "seed": "1"}
    row = page.locator("#summary tbody tr", has_text="4x1x1").filter(has_text="fails")
    row.first.click()
    assert page.locator("#view3d select[data-axis=estimator]").input_value() == "fails"
    assert page.locator("#view3d select[data-axis=mesh]").input_value() == "4x1x1"
    assert seen["errors"] == []


def test_a_hostile_name_and_message_are_text(browser, report):
    page, seen = opened(browser, report / "report.html")
    options = page.locator("#view3d select[data-axis=estimator] option")
    assert HOSTILE in options.all_text_contents()
    page.select_option("#view3d select[data-axis=estimator]", HOSTILE)
    assert HOSTILE in page.locator("#view3d .view-info").text_content()
    page.select_option("#view3d select[data-axis=estimator]", "fails")
    message = page.locator("#view3d .view-message").text_content()
    assert f"{HOSTILE} at step 3" in message
    assert page.locator("#view3d .view-step").text_content() == "step 2 of 4"
    assert page.locator("#view3d img").count() == 0
    assert seen["dialogs"] == [] and seen["errors"] == []


def test_a_folder_failing_its_checks_says_why(browser, report, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(report, out)
    path = next((out / "surfaces").glob("run-*.npz"))
    with np.load(path) as data:
        arrays = {k: np.array(data[k]) for k in data.files}
    arrays["displacement"] = arrays["displacement"] + 1.0
    np.savez(path, **arrays)
    write_report(out)
    page, seen = opened(browser, out / "report.html")
    note = page.locator("#view3d .view-note").text_content()
    assert "fails its checks" in note and path.name in note
    assert not page.locator("#view3d canvas").is_visible()
    assert seen["errors"] == []
