"""report.html with its 3D view for a 1,000-node liver comparison: size and open time.

Targets: under 5 MB for 7 estimators x 3 seeds x 20 steps, drawn in under 2 s
in Chromium. Running seven estimators on the liver takes long, so this runs
one (rls, one seed) on the 1,000-node liver (truth 4,000 nodes, 20 steps), then
makes the folder of the full comparison from it: 21 runs (7 estimator names x
3 seeds), each a copy of the run's row and surfaces under its own id, its
displacements perturbed (so that no two runs' arrays are alike, as in a real
comparison). The view's payload has the full comparison's shape: its size is
the real one; the numbers in it are not results. Then it writes the report
and opens it in headless Chromium (Debian's, through Playwright) ``--opens``
times, timing from navigation to the view's first drawn frame.

    python benchmarks/view_report.py            # the 1,000-node liver
    python benchmarks/view_report.py --quick    # 200 nodes, truth 500, 4 steps

Prints the page's size, its view's share, three.js's, and the open times.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from idbench.cli.commands import main
from idbench.report.view3d import asset
from idbench.report.write import write_report
from idbench.store import surfaces

ESTIMATORS = ("ro-ukf", "ukf", "enkf", "etkf", "rls", "lms", "batch-ls")
SEEDS = 3
TARGET_MB, TARGET_S = 5.0, 2.0


def one_run(out: Path, mesh: str, truth: str, steps: int) -> None:
    argv = [
        "compare", "--config", "examples/liver/compare.toml", "--meshes", mesh,
        "--truth-mesh", truth, "--model-option", f"reference={truth}",
        "--steps", str(steps), "--seeds", "1", "--estimators", "rls",
        "--out", str(out), "-q",
    ]  # fmt: skip
    assert main(argv) == 0


def widen(out: Path, rng: np.random.Generator) -> None:
    """Make ``out`` hold 7 estimators x 3 seeds: copies of its one run."""
    runs = pd.read_parquet(out / "runs.parquet")
    traces = pd.read_parquet(out / "traces.parquet")
    base = runs.iloc[0]
    source = surfaces.folder(out) / f"run-{base['run_id']}.npz"
    arrays = surfaces.load(source)
    rows, steps = [], []
    for e, name in enumerate(ESTIMATORS):
        for seed in range(SEEDS):
            run_id = f"{base['run_id'][:10]}{e}{seed:05d}"
            row = base.copy()
            row["run_id"], row["estimator"], row["seed"] = run_id, name, seed
            rows.append(row)
            steps.append(traces.assign(run_id=run_id))
            moved = dict(arrays)
            scale = float(np.abs(arrays["displacement"]).max())
            noise = rng.normal(0, 0.02 * scale, arrays["displacement"].shape)
            moved["displacement"] = (arrays["displacement"] + noise).astype(np.float32)
            surfaces._save(surfaces.folder(out) / f"run-{run_id}.npz", run_id, moved)
    source.unlink()
    pd.DataFrame(rows).to_parquet(out / "runs.parquet")
    pd.concat(steps, ignore_index=True).to_parquet(out / "traces.parquet")


def open_times(page_path: Path, opens: int) -> list[float]:
    from playwright.sync_api import sync_playwright

    args = ["--headless", "--no-sandbox", "--disable-gpu",
            "--disable-background-networking"]  # fmt: skip
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    times = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=args)
        for _ in range(opens):
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            t0 = time.perf_counter()
            page.goto(page_path.as_uri())
            page.wait_for_selector("#view3d[data-drawn]", timeout=60_000)
            times.append(time.perf_counter() - t0)
            page.close()
        browser.close()
    return times


def run(quick: bool, opens: int, keep: Path | None) -> None:
    mesh, truth, steps = ("200", "500", 4) if quick else ("1000", "4000", 20)
    with tempfile.TemporaryDirectory(prefix="idbench-view-") as tmp:
        out = keep or Path(tmp) / "out"
        t0 = time.perf_counter()
        one_run(out, mesh, truth, steps)
        took = time.perf_counter() - t0
        print(f"one rls run on the {mesh}-node liver: {took:.0f} s")
        widen(out, np.random.default_rng(0))
        write_report(out)
        page = out / "report.html"
        text = page.read_text(encoding="utf-8")
        start = text.index('<h2 id="view">')
        end = text.index("</script>", text.index('id="view3d-data"'))
        mb = page.stat().st_size / 1e6
        three = len(asset("vendor/three.min.js").encode()) / 1e6
        stored = sum(p.stat().st_size for p in surfaces.folder(out).glob("run-*"))
        print(f"report.html: {mb:.2f} MB (target < {TARGET_MB} MB); the view's data "
              f"{(end - start) / 1e6:.2f} MB, three.js {three:.2f} MB; "
              f"{len(ESTIMATORS) * SEEDS} runs x {steps} steps")  # fmt: skip
        per_run = stored / 1e3 / (len(ESTIMATORS) * SEEDS)
        print(f"stored surfaces: {per_run:.0f} kB a run")
        times = open_times(page, opens)
        median = statistics.median(times)
        print(f"open to first frame: median {median:.2f} s, max {max(times):.2f} s "
              f"over {opens} (target < {TARGET_S} s)")  # fmt: skip


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--opens", type=int, default=5)
    parser.add_argument("--keep", type=Path, help="write the folder here, keep it")
    a = parser.parse_args()
    run(a.quick, a.opens, a.keep)
