"""Reproduces the stiffness-maps table: where the tissue is stiffer, and who finds it.

A stiff spherical inclusion in the kidney (its tumour's place, 8 mm under the
anterior surface) and in the liver's right lobe, identified as a modulus
field of k-means cells with a smoothness prior (:mod:`idbench.estimate.prior`:
correlation length :data:`LENGTH`, std :data:`STD` of ln E), seen by
markers, by a depth-camera cloud (both under the body's force-controlled
grasp) and by the cloud plus the force of a displacement-controlled probe
pressing 4 mm over the inclusion. Compared on the same data (common random
numbers): MAP + Laplace (``map-laplace``: adjoint Gauss-Newton, low-rank
Laplace posterior), the localized ETKF (``local-etkf``) and per-region
estimation with the inclusion's region known (``field_cells = "known"``: two
cells, the background and the inclusion, each with its own prior, by the
same MAP + Laplace). Each run's map is scored by :mod:`idbench.score.maps`
(field error, the inclusion's centroid distance and Dice, coverage of the 95%
band) with its cost. One control case solves on the truth's own mesh (no
discretization error) to separate what the data and prior allow from what
the coarse mesh does; the *corrected* cases add to each predicted value the
mean approximation error at the prior mean (``correction = "prior-mean"``,
:mod:`idbench.calibrate.prior_mean`: one path on a finer mesh that is not the
truth's, :data:`CALIBRATION`), and :func:`limits` measures why.

The cases are :data:`CASES` (not a full grid: the observation comparison at
contrast 3, radius 12 mm; contrasts and radii for MAP + Laplace on the
cloud + force; the liver; the control). Run ``python studies/stiffness_maps.py
[--quick] [--out DIR]``; ``--quick``: the kidney on 500 nodes against a
2,000-node truth, 40 cells, 4 steps, the cloud + force: MAP + Laplace, the
known region, and MAP + Laplace on the truth's mesh (the control). A full
run writes the table to ``docs/results/data/stiffness_maps.csv``, the
limits to ``docs/results/data/stiffness_maps_limits.csv`` and the maps to
``docs/figures/stiffness_maps.png`` (the results page's).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import _cli
import numpy as np
import pandas as pd

from idbench.plan.config import CompareConfig
from idbench.run.compare import compare
from idbench.score.maps import cells_of
from idbench_fem.bodies.catalog import body_path

BODIES: dict[str, dict[str, Any]] = {
    "kidney": {
        "E": 6000.0,
        "centre": (0.02, 0.003, 0.0),  # the body's tumour
        "palpate": "grasp-pole",  # force-controlled: markers, cloud
        "probe": {"point": (0.02, 0.003, 0.02), "radius": 0.012,
                  "displacement": (0.0, 0.0, -0.004)},
        "camera": {"position": (0.02, 0.0, 0.2), "look_at": (0.02, 0.0, 0.0)},
    },
    "liver": {
        "E": 4000.0,
        "centre": (0.05, 0.02, 0.0),  # in the right lobe, 2 cm under its front
        "palpate": "grasp-lift",
        "probe": {"point": (0.05, 0.05, 0.0), "radius": 0.012,
                  "displacement": (0.0, -0.004, 0.0)},
        "camera": {"position": (0.05, 0.25, 0.0), "look_at": (0.05, 0.0, 0.0)},
    },
}  # fmt: skip
"""Per body: its E, the inclusion's centre, the palpation (force-controlled),
the probe over the inclusion (displacement-controlled, its force observed)
and the camera."""
MESHES = {"kidney": "2000", "liver": "1000"}
TRUTH = {"kidney": "8000", "liver": "4000"}
CALIBRATION = {"kidney": "4000", "liver": "2000"}
"""The finer mesh (not the truth's) of the prior-mean correction's one path."""
CELLS = 200
LENGTH = 0.015  # m: the prior's correlation length
STD = 0.5  # the prior's std of ln E
STEPS = 10
MARKERS = {"kidney": 20, "liver": 8}
"""Markers observed (the liver's body lists 8 points; the kidney's anterior
face's nodes give 20 spread ones)."""
MARKER_NOISE = 1e-4  # m
CLOUD = {"kind": "cloud", "points": 400, "noise": 2e-4, "holes": 0.1}
FORCE_NOISE = 1e-2  # N
LOCALIZATION = 0.04  # m: the localized ETKF's taper support
MEMBERS = 40
SEEDS = 1
ESTIMATORS = ("map-laplace", "local-etkf", "known-region")


def _case(
    body: str, contrast: float, radius: float, observe: str, estimator: str,
    control: bool = False, corrected: bool = False, seeds: int = SEEDS,
    length: float | None = None, cloud_noise: float | None = None,
    mesh: str | None = None,
) -> dict[str, Any]:  # fmt: skip
    return {"body": body, "contrast": contrast, "radius": radius,
            "observe": observe, "estimator": estimator, "control": control,
            "corrected": corrected, "seeds": seeds, "length": length,
            "cloud_noise": cloud_noise, "mesh": mesh}  # fmt: skip


CASES = [
    *(_case("kidney", 3.0, 0.012, o, e)
      for o in ("markers", "cloud", "cloud+force") for e in ESTIMATORS),
    *(_case("kidney", c, 0.012, "cloud+force", "map-laplace") for c in (2.0, 5.0)),
    _case("kidney", 3.0, 0.008, "cloud+force", "map-laplace"),
    *(_case("kidney", 3.0, 0.012, "cloud+force", e, control=True)
      for e in ("map-laplace", "local-etkf")),
    *(_case("liver", 3.0, 0.012, "cloud+force", e) for e in ESTIMATORS),
    *(_case("kidney", 3.0, 0.012, "cloud+force", e, corrected=True,
            seeds=3 if e == "map-laplace" else SEEDS)
      for e in ESTIMATORS),
    _case("kidney", 3.0, 0.012, "cloud", "map-laplace", corrected=True),
    *(_case("kidney", c, 0.012, "cloud+force", "map-laplace", corrected=True)
      for c in (2.0, 5.0)),
    _case("kidney", 3.0, 0.008, "cloud+force", "map-laplace", corrected=True),
    *(_case("liver", 3.0, 0.012, "cloud+force", e, corrected=True)
      for e in ("map-laplace", "local-etkf")),
    *(_case("kidney", 3.0, 0.012, "cloud+force", "map-laplace", corrected=True,
            length=rho) for rho in (0.008, 0.03)),
    _case("kidney", 3.0, 0.012, "cloud+force", "map-laplace", corrected=True,
          cloud_noise=5e-5),
    _case("kidney", 3.0, 0.012, "cloud+force", "map-laplace", mesh="4000"),
]  # fmt: skip
"""The study's runs (each one comparison, one seed)."""

QUICK: dict[str, Any] = {
    "cases": [_case("kidney", 3.0, 0.012, "cloud+force", "map-laplace"),
              _case("kidney", 3.0, 0.012, "cloud+force", "known-region"),
              _case("kidney", 3.0, 0.012, "cloud+force", "map-laplace", True),
              _case("kidney", 3.0, 0.012, "cloud+force", "map-laplace",
                    corrected=True)],
    "calibration": {"kidney": "1000"},
    "meshes": {"kidney": "500"},
    "truth": {"kidney": "2000"},
    "cells": 40,
    "steps": 4,
}  # fmt: skip


def write_body(
    folder: Path, body: str, contrast: float, radius: float, cells: int
) -> Path:
    """The shipped ``body`` with an inclusion field and the probe, in ``folder``.

    The body's own regions' moduli and parameters are dropped (the truth is
    E times ``contrast`` in a sphere of ``radius`` at the body's inclusion
    centre), a displacement-controlled ``probe-indent`` over the inclusion is
    added, and its meshes are those of the shipped body (generated on use).
    """
    spec = BODIES[body]
    source = body_path(body)
    text = source.read_text()
    text = re.sub(r"(?m)^E_regions.*\n", "", text)
    text = re.sub(r"(?ms)^\[parameters\].*?(?=^\[|\Z)", "", text)
    # the reduced models' offline design ranges the regions' moduli: not a field's
    text = re.sub(r"(?ms)^\[\[?design[^\n]*\].*?(?=^\[(?!\[?design)|\Z)", "", text)
    base = source.parent
    text = re.sub(r'"(meshes/[^"]+)"', lambda m: f'"{(base / m[1]).as_posix()}"', text)
    probe = spec["probe"]
    manipulation = (
        '\n[[manipulation]]\nname = "probe-indent"\nkind = "grasp"\n'
        f"point = {list(probe['point'])}\nradius = {probe['radius']}\n"
        f"displacement = {list(probe['displacement'])}\n"
    )
    text = text.replace("\n[markers]", manipulation + "\n[markers]", 1)
    sphere = f"{{ centre = {list(spec['centre'])}, radius = {radius} }}"
    text += (f"\n[field]\ncells = {cells}\nlength = {LENGTH}\nstd = {STD}\n"
             f"[[field.inclusion]]\nregion = {{ sphere = {sphere} }}\n"
             f"contrast = {contrast}\n")
    out = folder / f"{body}-c{contrast:g}-r{1000 * radius:g}mm.toml"
    folder.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    return out


def config(case: dict[str, Any], body_file: Path, q: dict[str, Any]) -> CompareConfig:
    """The comparison of one case: one estimator, one observation, one scenario."""
    body, estimator, observe = case["body"], case["estimator"], case["observe"]
    spec = BODIES[body]
    truth = q.get("truth", TRUTH)[body]
    mesh = truth if case["control"] else case["mesh"] or q.get("meshes", MESHES)[body]
    settings: dict[str, Any] = {"body": str(body_file), "reference": truth}
    if case["length"] is not None:  # the prior's correlation length, varied
        settings["field_length"] = case["length"]
    est_settings: dict[str, Any] = {}
    name = estimator
    if estimator == "known-region":  # two cells, independent priors
        settings["field_cells"] = "known"
        name = "map-laplace"
    elif estimator == "local-etkf":
        est_settings = {"localization": LOCALIZATION, "members": MEMBERS,
                        "init": "random"}  # fmt: skip
    calibration: dict[str, Any] = {}
    if case["corrected"]:  # + the mean approximation error at the prior mean
        est_settings["correction"] = "prior-mean"
        calibration = {"mesh": q.get("calibration", CALIBRATION)[body]}
    return CompareConfig(
        calibration=calibration,
        model="solid",
        model_settings={"solid": settings},
        scenarios=("probe-indent" if "force" in observe else spec["palpate"],),
        meshes=(mesh,),
        truth_mesh=truth,
        estimators=(name,),
        estimator_settings={name: est_settings} if est_settings else {},
        reference="map-laplace",
        seeds=case["seeds"],
        steps=q.get("steps", STEPS),
        obs_every=(1,),
        obs_points=(MARKERS[body],),
        noise=(MARKER_NOISE,),
        observe=(observe,),
        observe_settings={
            "cloud": {**CLOUD, **spec["camera"], **(
                {} if case["cloud_noise"] is None else {"noise": case["cloud_noise"]})},
            "force": {"noise": FORCE_NOISE},
        },
        prior=(spec["E"], spec["E"] / 2),
    )


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """One row per case and seed: the map's scores, its cost, the map itself."""
    q = QUICK if quick else {}
    folder = Path(out) if out is not None else Path("results/stiffness_maps")
    cells = q.get("cells", CELLS)
    rows = []
    for case in q.get("cases", CASES):
        body_file = write_body(folder / "bodies", case["body"], case["contrast"],
                               case["radius"], cells)  # fmt: skip
        where = folder / body_file.stem / case["observe"] / (
            case["estimator"] + ("-control" if case["control"] else "")
            + ("-prior-mean" if case["corrected"] else "")
            + ("" if case["length"] is None else f"-length{1000 * case['length']:g}")
            + ("" if case["cloud_noise"] is None else f"-noise{case['cloud_noise']:g}")
            + ("" if case["mesh"] is None else f"-mesh{case['mesh']}"))
        runs, _ = compare(config(case, body_file, q), where)
        rows += [row(r, case) for _, r in runs.iterrows()]
    return pd.DataFrame(rows)


def limits(folder: Path, body: str = "kidney", meshes: tuple[str, ...] = ("1000",
           "2000", "4000", "8000"), truth: str = "8000") -> pd.DataFrame:  # fmt: skip
    """What the data hold of the inclusion, against what a coarse mesh gets wrong.

    The probe's last step (contrast 3, 12 mm), noise-free, the cloud's RMS
    (mm) and the force (N) of: each model mesh's prediction at the true cell
    values against the truth's data (the mesh's own error); the part of it
    that changes with the field, (h(true) - h(uniform E)) minus the truth
    mesh's (what a correction at the prior mean cannot remove, and what can
    look like an inclusion); what the study's correction leaves (its
    :data:`CALIBRATION` mesh's prediction minus this mesh's, at the uniform
    E, added); and the inclusion's whole signal, the truth mesh's
    h(true) - h(uniform E).
    """
    import idbench
    from idbench import ModelSpec, Scenario
    from idbench.core.observation_model import Frame
    from idbench.observe.cloud import Cloud
    from idbench.observe.kinds import Combined, Force
    from idbench.observe.observed_model import ObservedModel

    body_file = write_body(folder / "bodies", body, 3.0, 0.012, CELLS)
    load = {"body": str(body_file), "manipulation": "probe-indent"}

    def model(mesh: str) -> Any:
        spec = ModelSpec(mesh=mesh, scenario=Scenario("probe-indent", load),
                         n_steps=STEPS, settings={"body": str(body_file),
                                                  "reference": truth})  # fmt: skip
        return idbench.build_registry().model("solid")(spec)

    fine = model(truth)
    true = np.array(fine.parameters.default)
    cam = BODIES[body]["camera"]
    cloud = Cloud(points=CLOUD["points"], noise=0.0, **cam)
    obs = Combined((("cloud", cloud), ("force", Force(noise=FORCE_NOISE))))
    u = fine.reset()
    for k in range(1, STEPS + 1):
        u = fine.step(true, k, u)
    rng = np.random.default_rng(0)
    data = Combined.merge([
        ("cloud", cloud.measure([cloud.sense(fine, true, STEPS, u)], rng, 0.0)[0]),
        ("force", {"force": fine.reaction(true, STEPS, u)}),
    ])  # fmt: skip
    frame = Frame(STEPS, data)
    y = obs.values(frame)
    uniform = np.full_like(true, BODIES[body]["E"])

    def last(mesh: str, theta: np.ndarray) -> np.ndarray:
        seen = ObservedModel(model(mesh), obs, [frame] * STEPS)
        x = seen.reset()
        for k in range(1, STEPS + 1):
            x = seen.step(theta, k, x)
        return np.asarray(seen.observe(x))

    def rms(r: np.ndarray) -> tuple[float, float]:
        """The cloud's RMS (mm) and the force's norm (N) of a residual."""
        cloud = 1000 * float(np.sqrt(np.mean(r[:-3] ** 2)))
        return cloud, float(np.linalg.norm(r[-3:]))

    signal = last(truth, true) - last(truth, uniform)
    calibrated = last(CALIBRATION[body], uniform)
    rows = []
    for mesh in meshes:
        at_true, at_uniform = last(mesh, true), last(mesh, uniform)
        row: dict[str, Any] = {"body": body, "mesh": mesh}
        for name, r in (
            ("error", y - at_true),  # the mesh's own error at the true field
            ("field_part", (at_true - at_uniform) - signal),  # what changes with it
            ("corrected", y - at_true - (calibrated - at_uniform)),  # the study's
        ):
            row[f"{name}_cloud_mm"], row[f"{name}_force_N"] = rms(r)
        rows.append(row)
    cloud, force = rms(signal)
    rows.append({"body": body, "mesh": "signal", "error_cloud_mm": cloud,
                 "error_force_N": force})  # fmt: skip
    return pd.DataFrame(rows)


def limits_markdown(table: pd.DataFrame) -> str:
    """The results page's table of :func:`limits` (the signal's row last)."""
    lines = ["| model mesh (nodes) | error at the true cells: cloud (mm), force (N) "
             "| of which changes with the field | left by the study's correction |",
             "|---|---|---|---|"]  # fmt: skip
    for _, t in table.iterrows():
        if t["mesh"] == "signal":
            lines.append(
                f"| the inclusion's whole signal | {t['error_cloud_mm']:.3f}, "
                f"{t['error_force_N']:.3f} | | |"
            )
            continue
        cells = [f"{t[f'{n}_cloud_mm']:.3f}, {t[f'{n}_force_N']:.3f}"
                 for n in ("error", "field_part", "corrected")]  # fmt: skip
        lines.append(f"| {t['mesh']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def row(r: pd.Series, case: dict[str, Any]) -> dict[str, Any]:
    """The table's row of one run (``map``: JSON of its cells, for the figure)."""
    out: dict[str, Any] = {
        "body": case["body"], "contrast": case["contrast"],
        "radius_mm": 1000 * case["radius"], "observe": case["observe"],
        "estimator": case["estimator"],
        "mesh": "truth's" if case["control"] else str(r["mesh"]),
        "corrected": bool(case["corrected"]),
        "length_mm": 1000 * (LENGTH if case["length"] is None else case["length"]),
        "cloud_noise_mm": 1000 * (CLOUD["noise"] if case["cloud_noise"] is None
                                  else case["cloud_noise"]),
        "seed": int(r["seed"]), "status": r["status"],
    }  # fmt: skip
    names = sorted(c[: -len("_final")] for c in r.index
                   if c.startswith("E_") and c.endswith("_final")
                   and not c.endswith("_std_final"))  # fmt: skip
    est = np.array([r[f"{n}_final"] for n in names], dtype=float)
    true = np.array([r[f"{n}_true"] for n in names], dtype=float)
    x, inside = cells_of(r["field_cells"]) if isinstance(
        r.get("field_cells"), str) else (None, None)
    out["cells"] = len(names)
    out["found_contrast"] = np.nan
    if inside is not None and np.all(np.isfinite(est)):
        w = inside > 0.5
        background = np.exp(np.sum(np.log(est) * (1 - inside)) / np.sum(1 - inside))
        if w.any():
            out["found_contrast"] = np.exp(np.mean(np.log(est[w]))) / background
    for name in ("field_error", "inclusion_centroid_mm", "inclusion_dice",
                 "field_cover95", "n_solves"):  # fmt: skip
        out[name] = r.get(name, np.nan)
    out["wall_s"] = r.get("wall_s_step", np.nan) * r.get("steps", np.nan)
    out["map"] = json.dumps({
        "x": None if x is None else x.tolist(), "inside": None if inside is None
        else inside.tolist(), "est": est.tolist(), "true": true.tolist(),
    })  # fmt: skip
    return out


def markdown(table: pd.DataFrame) -> str:
    """The results page's table (one line per case)."""
    head = ("| body | contrast | radius (mm) | observed | estimator | mesh | "
            "corrected | rho (mm) | cloud noise (mm) | seed | found contrast | "
            "field error | centroid off (mm) | Dice | cells in 95% band | wall (s) |")
    lines = [head, "|" + "---|" * 16]
    for _, t in table.iterrows():
        lines.append(
            f"| {t['body']} | {t['contrast']:g} | {t['radius_mm']:g} | "
            f"{t['observe']} | {t['estimator']} | {t['mesh']} | "
            f"{'prior mean' if t['corrected'] else '-'} | {t['length_mm']:g} | "
            f"{t['cloud_noise_mm']:g} | {t['seed']} | "
            f"{_num(t['found_contrast'], '.2f')} | {_num(t['field_error'], '.2f')} | "
            f"{_num(t['inclusion_centroid_mm'], '.1f')} | "
            f"{_num(t['inclusion_dice'], '.2f')} | "
            f"{_num(100 * t['field_cover95'], '.0f')}% | {_num(t['wall_s'], '.1f')} |"
        )
    return "\n".join(lines) + "\n"


def _num(value: Any, fmt: str) -> str:
    return "-" if value is None or not np.isfinite(value) else format(value, fmt)


def section(x: np.ndarray, values: np.ndarray, z: float, n: int = 120):
    """The cells' values on the plane at height ``z``: an image by nearest cell.

    Returns the grid's x and y (mm) and the image, NaN farther from every
    cell centroid than the centroids' median nearest-neighbour distance
    (outside the body, roughly).
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(x)
    spacing = float(np.median(tree.query(x, k=2)[0][:, 1]))
    gx = np.linspace(x[:, 0].min() - spacing, x[:, 0].max() + spacing, n)
    gy = np.linspace(x[:, 1].min() - spacing, x[:, 1].max() + spacing, n // 2)
    X, Y = np.meshgrid(gx, gy)
    points = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], axis=1)
    dist, cell = tree.query(points)
    image = np.where(dist <= spacing, values[cell], np.nan).reshape(X.shape)
    return 1000 * gx, 1000 * gy, image


def plot(table: pd.DataFrame, path: Path) -> None:
    """The kidney at contrast 3, 12 mm, cloud + force: truth and maps.

    Each panel is the section z = the inclusion's centre (the kidney's
    thinnest axis), every point coloured by its cell's log10(E / E_tissue);
    the circle is the true inclusion.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pick = table[(table["body"] == "kidney") & (table["observe"] == "cloud+force")
                 & (table["contrast"] == 3.0) & (table["radius_mm"] == 12.0)
                 & (table["cells"] > 2) & (table["seed"] == 0)
                 & (table["length_mm"] == 1000 * LENGTH)
                 & (table["cloud_noise_mm"] == 1000 * CLOUD["noise"])]  # fmt: skip
    if pick.empty:
        return
    panels = [("truth (its cells)", pick.iloc[0], "true")]
    panels += [(f"{t['estimator']}, {t['mesh']} mesh"
                + (", corrected" if t["corrected"] else ""), t, "est")
               for _, t in pick.iterrows()]  # fmt: skip
    rows = (len(panels) + 1) // 2
    fig, axs = plt.subplots(rows, 2, figsize=(9.0, 2.2 * rows), squeeze=False,
                            layout="constrained")  # fmt: skip
    image = None
    centre = np.array(BODIES["kidney"]["centre"])
    for ax in axs.ravel()[len(panels):]:
        ax.set_visible(False)
    for ax, (title, t, which) in zip(axs.ravel(), panels, strict=False):
        data = json.loads(t["map"])
        x = np.array(data["x"])
        v = np.log10(np.array(data[which]) / BODIES["kidney"]["E"])
        gx, gy, im = section(x, v, centre[2])
        image = ax.pcolormesh(gx, gy, im, cmap="RdBu_r", vmin=-0.5, vmax=0.5,
                              shading="auto")  # fmt: skip
        ax.add_patch(plt.Circle(1000 * centre[:2], 1000 * t["radius_mm"] / 1000,
                                fill=False, color="k", lw=0.8))  # fmt: skip
        ax.set_title(title, fontsize=8)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    for ax in axs[:, 0]:
        ax.set_ylabel("y (mm)", fontsize=8)
    for ax in axs[-1, :]:
        ax.set_xlabel("x (mm)", fontsize=8)
    if image is not None:
        fig.colorbar(image, ax=axs.ravel().tolist(), shrink=0.6,
                     label="log10(E / E_tissue)")  # fmt: skip
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    args = _cli.parser(__doc__, "results/stiffness_maps").parse_args()
    result = compute(quick=args.quick, out=args.out)
    print(markdown(result))
    args.out.mkdir(parents=True, exist_ok=True)
    plot(result, args.out / "maps.png")
    if not args.quick:
        _cli.docs_data("stiffness_maps", result.drop(columns=["map"]))
        plot(result, _cli.DOCS_DATA.parent.parent / "figures" / "stiffness_maps.png")
        bounds = limits(args.out)
        print(limits_markdown(bounds))
        _cli.docs_data("stiffness_maps_limits", bounds)
