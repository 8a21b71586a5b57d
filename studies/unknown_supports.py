"""Reproduces the unknown-supports table: a liver on springs, and where it starts.

The truth is the liver of ``examples/liver/springs.toml``: held by springs of
known stiffness on its ligament (normal and tangential) and on its posterior
surface (normal), grasped and lifted (``grasp-lift``), simulated on the
4,000-node mesh. Its 8 markers (0.1 mm noise) are recorded once per seed
(:func:`idbench.run.record.record`) and the same recording is read by models
on the 1,000-node mesh that hold the liver differently (:data:`DESIGNS`):
with the truth's springs (``known``: the value of E a right support finds),
with the springs' normal stiffnesses identified with E (``identified``),
with springs of half the truth's stiffness (``soft``), and clamped at the
ligament as idbench's liver is (``clamp``: the price of a wrong support).
Each design's body is written beside the results; the recording's manifest
names it and the true values it knows. Every estimator runs on every
recording (:data:`ESTIMATORS`).

Where it starts (:func:`registration`): the truth's unloaded surface seen by
the default depth camera (1,000 points, 1 mm noise along the ray, 5%
outliers, 10% holes) is moved into a camera frame by a rigid offset
(:data:`OFFSETS`, in a random direction per seed) and registered back
(:func:`idbench.observe.registration.register`) to the model's rest surface
and to the truth's own; the table has the errors of the transform found.
Then (:func:`clouds`) the ``known`` design identifies E from recorded clouds
in the model's frame, in the camera's frame (offset, unregistered) and
registered by the transform of that frame's unloaded cloud.

Run ``python studies/unknown_supports.py [--quick] [--out DIR]``. A full run
writes ``docs/results/data/unknown_supports*.csv`` (the results page's
tables: :func:`markdown`, :func:`markdown_registration`).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path
from typing import Any

import _cli
import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

import idbench
from idbench.observe.cloud import Cloud
from idbench.observe.registration import register, transform_error
from idbench.plan.config import CompareConfig
from idbench.run.compare import compare
from idbench.run.record import record
from idbench.store import recording
from idbench_fem.bodies.description import load_body
from idbench_fem.models.solid import make_model

ROOT = Path(__file__).resolve().parent.parent
TRUTH_BODY = ROOT / "examples" / "liver" / "springs.toml"
SCENARIO = "grasp-lift"
MESH = "1000"
TRUTH = "4000"
STEPS = 20
MARKERS = 8
NOISE = 1e-4  # m
PRIOR = (2000.0, 2000.0)  # Pa, E's; the stiffnesses' priors are the body's
SEEDS = 3
ESTIMATORS: tuple[str, ...] = ("ro-ukf", "ukf", "enkf", "etkf", "rls", "lms",
                               "batch-ls")  # fmt: skip
DESIGNS = ("known", "identified", "soft", "clamp")
"""How the models hold the liver (see the module docstring)."""
SOFT = 0.5
"""The ``soft`` design's springs, as a share of the truth's."""
CLOUD = {"points": 1000, "noise": 1e-3, "outliers": 0.05, "holes": 0.1}
OFFSETS = ((5.0, 5.0), (10.0, 10.0))
"""Rigid offsets of the camera frame: (mm, degrees)."""
CLOUD_OFFSET = (5.0, 5.0)
"""The offset of the clouds the filters read (mm, degrees)."""
CLOUD_ESTIMATORS = ("ro-ukf", "etkf")

QUICK: dict[str, Any] = {
    "mesh": "300",
    "truth": "600",
    "steps": 4,
    "seeds": 1,
    "estimators": ("ro-ukf",),
    "designs": ("known", "identified", "clamp"),
    "offsets": ((10.0, 10.0),),
    "cloud_estimators": ("ro-ukf",),
}


# -- the designs' bodies ---------------------------------------------------------


def design_body(folder: Path, design: str) -> Path:
    """Write the body TOML of ``design`` into ``folder`` (the truth's, changed).

    Mesh paths point at the shipped liver's (generated in the mesh cache);
    the ``[[support]]`` tables are replaced as the design says.
    """
    text = TRUTH_BODY.read_text()
    text = text.replace('"meshes/', f'"{TRUTH_BODY.parent / "meshes"}/')
    head = text[: text.index("[[support]]")]
    tail = text[text.index("[[manipulation]]") :]
    tail = tail.split("\n[design]")[0] + "\n"  # (reduced models' offline paths)
    supports = load_body(TRUTH_BODY).supports
    if design == "clamp":
        middle = '[fixed]\nname = "ligament"\n\n'
    else:
        scale = SOFT if design == "soft" else 1.0
        middle = ""
        for s in supports:
            middle += (
                f'[[support]]\nname = "{s.name}"\nregion = "{s.region.name}"\n'
                f"k_n = {scale * s.k_n!r}\nk_t = {scale * s.k_t!r}\n"
            )
            if design == "identified":
                (_, mean, std), *_ = s.prior
                prior = f"prior = {{ k_n = [{mean!r}, {std!r}] }}"
                middle += f'identify = ["k_n"]\n{prior}\n'
            middle += "\n"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"liver-{design}.toml"
    path.write_text(head + middle + tail)
    return path


def design_truth(design: str) -> dict[str, float]:
    """The true values of a design's parameters (its model's names)."""
    body = load_body(TRUTH_BODY)
    true = {"E": body.material.E}
    if design == "identified":
        true.update({f"k_n_{s.name}": s.k_n for s in body.supports})
    return true


# -- recordings -----------------------------------------------------------------


def record_truth(
    folder: Path, seed: int, q: dict[str, Any], observe: str = "markers"
) -> Path:
    """The truth's observations of ``seed``: markers, or the base cloud."""
    truth = q.get("truth", TRUTH)
    body = design_body(folder / "bodies", "known")
    config = CompareConfig(
        model="solid",
        model_settings={"solid": {"body": str(body), "reference": truth}},
        truth_mesh=truth,
        meshes=(truth,),
        scenarios=(SCENARIO,),
        steps=q.get("steps", STEPS),
        obs_points=(MARKERS,),
        noise=(NOISE,),
        observe=(observe,),
        observe_settings={"cloud": dict(CLOUD)} if observe == "cloud" else {},
        estimators=("ro-ukf",),
    )
    return record(config, folder / f"{observe}-seed{seed}", seed=seed)


def retarget(
    source: Path, dest: Path, body: Path, true: dict[str, float], move: Any = None
) -> Path:
    """A copy of a recording for the model of ``body``, its clouds moved by ``move``.

    ``move(points)`` (N, 3) -> (N, 3) maps each frame's points and camera
    origin (None: as recorded).
    """
    rec = recording.read(source)
    manifest = tomllib.loads((source / recording.MANIFEST).read_text())
    manifest.pop("format", None)
    manifest.pop("units", None)
    manifest["model_settings"] = {**manifest["model_settings"], "body": str(body)}
    manifest["true"] = dict(true)
    frames = list(rec.frames)
    if move is not None:
        frames = [
            dataclasses.replace(f, data=_moved(f.data, move)) for f in frames
        ]
    return recording.write(dest, manifest, frames, rec.held_out, rec.time)


def _moved(data: Any, move: Any) -> dict[str, Any]:
    """A cloud frame's arrays with its points and camera centre moved."""
    out = dict(data)
    out["points"] = move(np.asarray(data["points"]))
    out["origin"] = move(np.asarray(data["origin"])[None, :])[0]
    return out


def run(data: Path, q: dict[str, Any], estimators: tuple[str, ...], out: Path) -> Any:
    """Every estimator on a recording (the model mesh of the study)."""
    config = CompareConfig(
        data=str(data),
        meshes=(q.get("mesh", MESH),),
        estimators=estimators,
        seeds=1,
        obs_every=(1,),
        prior=PRIOR,
    )
    runs, _ = compare(config, out)
    return runs


def _row(r: Any, **keys: Any) -> dict[str, Any]:
    r = r.to_dict()  # a diverged run lacks some columns
    wall = float(r.get("wall_s_step", math.nan))
    row = {
        **keys,
        "estimator": r["estimator"],
        "status": r["status"],
        "E": r.get("E_final", math.nan),
        "E_ratio": r.get("E_final", math.nan) / r["E_true"],
        "E_cover95_ref": r.get("E_cover95_ref", math.nan),
        "tre_mm": r.get("tre_final_mm", math.nan),
        "tre_covered": r.get("tre_covered_final", math.nan),
        "rate_hz": 1.0 / wall if wall > 0 else math.nan,
        "n_solves": r.get("n_solves", math.nan),
    }
    for s in load_body(TRUTH_BODY).supports:
        name = f"k_n_{s.name}"
        row[f"{name}_ratio"] = r.get(f"{name}_final", math.nan) / s.k_n
        row[f"{name}_cover95_ref"] = r.get(f"{name}_cover95_ref", math.nan)
    return row


# -- the three parts -------------------------------------------------------------


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """One row per (design, estimator, seed) on the markers (see the module)."""
    q = QUICK if quick else {}
    folder = Path(out or "results/unknown_supports")
    rows = []
    for seed in range(q.get("seeds", SEEDS)):
        source = record_truth(folder / "data", seed, q)
        for design in q.get("designs", DESIGNS):
            body = design_body(folder / "bodies", design)
            data = retarget(
                source, folder / "data" / f"{design}-seed{seed}", body,
                design_truth(design),
            )  # fmt: skip
            runs = run(data, q, q.get("estimators", ESTIMATORS),
                       folder / "runs" / f"{design}-seed{seed}")  # fmt: skip
            rows += [_row(r, design=design, seed=seed) for _, r in runs.iterrows()]
    table = pd.DataFrame(rows)
    known = table[table["design"] == "known"].set_index(["estimator", "seed"])["E"]
    keys = list(zip(table["estimator"], table["seed"], strict=True))
    table["E_vs_known"] = table["E"].to_numpy() / known.reindex(keys).to_numpy()
    return table


def _offset(rng: np.random.Generator, mm: float, deg: float) -> tuple[Any, Any]:
    """A rigid offset (R, t) of ``mm`` and ``deg`` in random directions."""
    axis, shift = rng.standard_normal((2, 3))
    R = Rotation.from_rotvec(math.radians(deg) * axis / np.linalg.norm(axis))
    return R.as_matrix(), 1e-3 * mm * shift / np.linalg.norm(shift)


def _models(q: dict[str, Any], folder: Path) -> tuple[Any, Any]:
    """The ``known`` design's truth (truth mesh) and model (model mesh)."""
    body = str(design_body(folder / "bodies", "known"))
    sc = idbench.Scenario(SCENARIO, {"body": body, "manipulation": SCENARIO})
    settings = {"body": body, "reference": q.get("truth", TRUTH)}
    build = [
        make_model(idbench.ModelSpec(mesh, sc, 1, MARKERS, settings))
        for mesh in (q.get("truth", TRUTH), q.get("mesh", MESH))
    ]
    return build[0], build[1]


def rest_cloud(truth: Any, seed: int) -> Any:
    """The camera's cloud of the unloaded truth (model frame), drawn for ``seed``."""
    cloud = Cloud(**CLOUD)  # type: ignore[arg-type]
    clean = cloud.sense(truth, np.asarray(truth.parameters.default), 0, truth.reset())
    rng = np.random.default_rng([seed, 41])
    return cloud.measure([clean], rng, CLOUD["noise"])[0]["points"]


def organ_points(truth: Any) -> Any:
    """The truth's surface nodes at rest (N, 3): the organ a transform moves."""
    vertices, triangles = truth.surface(truth.reset())
    return vertices[np.unique(triangles)]


def registration(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """One row per (offset, seed, surface): the registration's errors."""
    import time

    q = QUICK if quick else {}
    folder = Path(out or "results/unknown_supports")
    truth, model = _models(q, folder)
    rows = []
    for seed in range(q.get("seeds", SEEDS)):
        pts = rest_cloud(truth, seed)
        for mm, deg in q.get("offsets", OFFSETS):
            R, t = _offset(np.random.default_rng([seed, 43, int(mm)]), mm, deg)
            camera = (pts - t) @ R  # the model's frame is R p + t
            organ = (organ_points(truth) - t) @ R  # where the error is measured
            for name, m in (("model", model), ("truth", truth)):
                start = time.perf_counter()
                fit = register(camera, *m.surface(m.reset()), floor=CLOUD["noise"])
                seconds = time.perf_counter() - start
                angle, worst = transform_error(fit, R, t, organ)
                rows.append({
                    "offset_mm": mm, "offset_deg": deg, "seed": seed,
                    "surface": f"{name} ({m.n_nodes:,} nodes)",
                    "angle_error_deg": angle, "worst_error_mm": 1e3 * worst,
                    "rms_mm": 1e3 * fit.rms, "inliers": fit.inliers,
                    "iterations": fit.iterations, "seconds": seconds,
                })  # fmt: skip
    return pd.DataFrame(rows)


def clouds(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """E from clouds: the model's frame, offset, registered (``known`` design)."""
    q = QUICK if quick else {}
    folder = Path(out or "results/unknown_supports")
    truth, model = _models(q, folder)
    body = design_body(folder / "bodies", "known")
    rows = []
    for seed in range(q.get("seeds", SEEDS)):
        source = record_truth(folder / "data", seed, q, observe="cloud")
        mm, deg = CLOUD_OFFSET
        R, t = _offset(np.random.default_rng([seed, 47]), mm, deg)
        rest = (rest_cloud(truth, seed) - t) @ R
        fit = register(rest, *model.surface(model.reset()), floor=CLOUD["noise"])
        angle, worst = transform_error(fit, R, t, (organ_points(truth) - t) @ R)
        moves = {
            "cloud": None,
            "cloud, offset": lambda p, R=R, t=t: (p - t) @ R,
            "cloud, registered": lambda p, R=R, t=t, f=fit: f.apply((p - t) @ R),
        }
        for name, move in moves.items():
            tag = f"{name}-{seed}".replace(", ", "-")
            data = retarget(
                source, folder / "data" / tag, body, design_truth("known"), move
            )
            ests = q.get("cloud_estimators", CLOUD_ESTIMATORS)
            runs = run(data, q, ests, folder / "runs" / tag)
            reg = {"registration_deg": angle, "registration_mm": 1e3 * worst}
            for _, r in runs.iterrows():
                rows.append(_row(r, observe=name, seed=seed, **reg))
    return pd.DataFrame(rows)


KIDNEY = {"body": "kidney", "scenario": "grasp-pole", "prior": (3000.0, 3000.0)}
"""The kidney of the point-cloud study: two moduli, a view that barely sees
its grasp, and a cloud bias that the coarse rest surface explains."""


def kidney(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """The kidney's parenchyma E from markers, clouds, and registered clouds.

    Per seed: the truth's markers and base cloud recorded; the cloud read as
    recorded (the model's frame) and moved by the transform that registers
    the truth's unloaded cloud to the model's rest surface (no offset: what
    the registration removes is the coarse surface's own mismatch).
    """
    q = QUICK if quick else {}
    folder = Path(out or "results/unknown_supports") / "kidney"
    truth_mesh, mesh = q.get("truth", TRUTH), q.get("mesh", MESH)
    settings = {"body": KIDNEY["body"], "reference": truth_mesh}
    sc = idbench.Scenario(KIDNEY["scenario"], {**settings, "manipulation":
                                                KIDNEY["scenario"]})  # fmt: skip
    truth, model = (
        make_model(idbench.ModelSpec(m, sc, 1, MARKERS, settings))
        for m in (truth_mesh, mesh)
    )
    rows = []
    for seed in range(q.get("seeds", SEEDS)):
        fit = register(rest_cloud(truth, seed), *model.surface(model.reset()),
                       floor=CLOUD["noise"])  # fmt: skip
        for observe, move in (("markers", None), ("cloud", None),
                              ("cloud, registered", fit.apply)):  # fmt: skip
            kind = "markers" if observe == "markers" else "cloud"
            config = CompareConfig(
                model="solid", model_settings={"solid": settings},
                truth_mesh=truth_mesh, meshes=(truth_mesh,),
                scenarios=(KIDNEY["scenario"],), steps=q.get("steps", STEPS),
                obs_points=(MARKERS,), noise=(NOISE,), observe=(kind,),
                observe_settings={"cloud": dict(CLOUD)} if kind == "cloud" else {},
                estimators=("ro-ukf",),
            )  # fmt: skip
            source = record(config, folder / f"{kind}-seed{seed}", seed=seed)
            manifest = tomllib.loads((source / recording.MANIFEST).read_text())
            tag = f"{observe}-{seed}".replace(", ", "-")
            data = retarget(source, folder / tag, KIDNEY["body"], manifest["true"],
                            move)  # fmt: skip
            runs, _ = compare(
                CompareConfig(data=str(data), meshes=(mesh,), estimators=("ro-ukf",),
                              seeds=1, obs_every=(1,), prior=KIDNEY["prior"]),
                folder / "runs" / tag,
            )  # fmt: skip
            r = runs.iloc[0].to_dict()
            rows.append({
                "observe": observe, "seed": seed, "status": r["status"],
                "E_ratio": r.get("E_parenchyma_final", math.nan)
                / manifest["true"]["E_parenchyma"],
                "tre_mm": r.get("tre_final_mm", math.nan),
                "registration_deg": fit.angle_deg,
                "registration_mm": 1e3 * float(np.linalg.norm(fit.translation)),
            })  # fmt: skip
    table = pd.DataFrame(rows)
    base = table[table["observe"] == "markers"].set_index("seed")["E_ratio"]
    markers = base.reindex(table["seed"]).to_numpy()
    table["dE_vs_markers"] = table["E_ratio"].to_numpy() / markers - 1
    return table


def markdown_kidney(table: pd.DataFrame) -> str:
    """The page's kidney table: each observation's seeds, mean (worst)."""
    head = ["observation", "E_parenchyma / E_true", "dE vs markers, mean (worst)",
            "TRE (mm)", "registration found (deg, mm)"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, d in table.groupby("observe", sort=False):
        dE = 100 * d["dE_vs_markers"]
        worst = dE.to_numpy()[np.argmax(np.abs(dE.to_numpy()))]
        reg = "-"
        if name.endswith("registered"):
            deg, mm = d["registration_deg"].mean(), d["registration_mm"].mean()
            reg = f"{deg:.2f}, {mm:.2f}"
        cells = [
            str(name), f"{d['E_ratio'].mean():.3f}",
            "-" if name == "markers" else f"{dE.mean():+.1f}% ({worst:+.1f}%)",
            f"{d['tre_mm'].mean():.3g}", reg,
        ]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# -- tables and figure ------------------------------------------------------------


def summary(table: pd.DataFrame, by: str = "design") -> pd.DataFrame:
    """Means over seeds per (``by``, estimator); the worst seed of E vs known."""
    ok = table[table["status"] == "ok"]
    cols = [c for c in ok.columns if c.endswith(("_ratio", "_cover95_ref"))]
    cols += ["tre_mm", "tre_covered", "rate_hz"]
    cols += [c for c in ("E_vs_known", "registration_deg", "registration_mm")
             if c in ok]  # fmt: skip
    runs = table.groupby([by, "estimator"], sort=False).size()  # every group
    g = ok.groupby([by, "estimator"], sort=False)
    out = g[cols].mean().reindex(runs.index)
    out["seeds"] = g.size().reindex(runs.index).fillna(0).astype(int)
    out["runs"] = runs
    skipped = table[table["status"] == "skipped"].groupby([by, "estimator"]).size()
    out["skipped"] = skipped.reindex(runs.index).fillna(0).astype(int)
    if "E_vs_known" in ok:
        dev = (ok["E_vs_known"] - 1).abs()
        worst = ok.assign(d=dev).groupby([by, "estimator"], sort=False)["d"].max()
        out["E_vs_known_worst"] = worst.reindex(runs.index)
    return out.reset_index()


def _runs(r: Any) -> str:
    """``ok/runs``, or ``skipped`` where the estimator refused every run."""
    if r.get("skipped", 0) == r["runs"]:
        return "skipped"
    return f"{r['seeds']}/{r['runs']}"


def _f(x: Any, fmt: str) -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, fmt)


def markdown(summary_table: pd.DataFrame) -> str:
    """The page's table of the designs: E, springs, TRE, coverage, rate."""
    head = ["model's support", "estimator", "ok runs", "E / E_true",
            "E / E (known springs)", "k_n ligament / true", "k_n posterior / true",
            "TRE (mm)", "E covered (95%)", "k covered (95%)", "rate (Hz)"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in summary_table.iterrows():
        both = [r.get(f"k_n_{n}_cover95_ref", np.nan) for n in ("ligament",
                                                                 "posterior")]
        k_cov = np.mean(both)  # NaN unless identified
        cells = [
            str(r["design"]), str(r["estimator"]), _runs(r),
            _f(r["E_ratio"], ".3f"), _f(r.get("E_vs_known", np.nan), ".3f"),
            _f(r.get("k_n_ligament_ratio", np.nan), ".3f"),
            _f(r.get("k_n_posterior_ratio", np.nan), ".3f"),
            _f(r["tre_mm"], ".3g"), _f(r["E_cover95_ref"], ".2f"), _f(k_cov, ".2f"),
            _f(r["rate_hz"], ".3g"),
        ]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def markdown_registration(table: pd.DataFrame) -> str:
    """The page's table of the registrations: mean and worst over seeds."""
    head = ["offset", "registered to", "angle error (deg), mean (worst)",
            "error over the organ (mm), mean (worst)", "rms (mm)", "inliers",
            "seconds"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for (mm, deg, surf), d in table.groupby(
        ["offset_mm", "offset_deg", "surface"], sort=False
    ):
        a, w = d["angle_error_deg"], d["worst_error_mm"]
        cells = [
            f"{mm:g} mm, {deg:g} deg", str(surf),
            f"{a.mean():.2f} ({a.max():.2f})", f"{w.mean():.2f} ({w.max():.2f})",
            f"{d['rms_mm'].mean():.2f}", f"{d['inliers'].mean():.2f}",
            f"{d['seconds'].mean():.2g}",
        ]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def markdown_clouds(summary_table: pd.DataFrame) -> str:
    """The page's table of E from clouds in the model's and the camera's frame."""
    head = ["observation", "estimator", "ok runs", "E / E_true", "TRE (mm)",
            "E covered (95%)", "rate (Hz)", "registration error (deg, mm)"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in summary_table.iterrows():
        reg = "-"
        if r["observe"].endswith("registered"):
            reg = f"{r['registration_deg']:.2f}, {r['registration_mm']:.2f}"
        cells = [
            str(r["observe"]), str(r["estimator"]), _runs(r),
            _f(r["E_ratio"], ".3f"), _f(r["tre_mm"], ".3g"),
            _f(r["E_cover95_ref"], ".2f"), _f(r["rate_hz"], ".3g"), reg,
        ]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(table: pd.DataFrame, path: Path) -> None:
    """E against the known-support E per design and estimator (dots: seeds)."""
    import matplotlib.pyplot as plt

    ok = table[table["status"] == "ok"]
    designs = list(dict.fromkeys(ok["design"]))
    ests = list(dict.fromkeys(ok["estimator"]))
    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.8 / max(len(ests), 1)
    for j, est in enumerate(ests):
        for i, design in enumerate(designs):
            d = ok[(ok["design"] == design) & (ok["estimator"] == est)]
            x = i + (j - (len(ests) - 1) / 2) * width
            ax.bar(x, d["E_vs_known"].mean(), width, color=f"C{j}",
                   label=est if i == 0 else None)  # fmt: skip
            ax.plot([x] * len(d), d["E_vs_known"], "k.", ms=3)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xticks(range(len(designs)), designs)
    ax.set(ylabel="E / E found with the known springs", xlabel="the model's support")
    ax.legend(fontsize="x-small", ncol=4)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    args = _cli.parser(__doc__, "results/unknown_supports")
    ns = args.parse_args()
    pd.set_option("display.width", 250)
    ns.out.mkdir(parents=True, exist_ok=True)
    reg = registration(ns.quick, ns.out)
    reg.to_csv(ns.out / "registration.csv", index=False)
    print(reg.to_string(index=False))
    table = compute(ns.quick, ns.out)
    table.to_csv(ns.out / "unknown_supports.csv", index=False)
    designs = summary(table)
    print(designs.to_string(index=False))
    cl = clouds(ns.quick, ns.out)
    cl.to_csv(ns.out / "clouds.csv", index=False)
    by_cloud = summary(cl, by="observe")
    print(by_cloud.to_string(index=False))
    kid = kidney(ns.quick, ns.out)
    kid.to_csv(ns.out / "kidney.csv", index=False)
    print(kid.to_string(index=False))
    if not ns.quick:  # the numbers of docs/results/unknown-supports.md
        _cli.docs_data("unknown_supports", designs)
        _cli.docs_data("unknown_supports_registration", reg)
        _cli.docs_data("unknown_supports_clouds", by_cloud)
        _cli.docs_data("unknown_supports_kidney", kid)
    plot(table, ns.out / "unknown_supports.png")
