"""Splits a coarse mesh's low E into load capture and stiffness: liver and kidney.

A coarse tetrahedral mesh identifies a low E for two reasons on an organ: it
is stiffer (the study's subject), and a load that a mesh captures, a
pressure inside a selector's sphere or gravity, puts less force on a coarse
mesh than on the truth (``idbench check liver``: 0.34 of the push's resultant
on 195 nodes). A manipulation's ``conserve = "resultant"`` scales each mesh's
load to the truth mesh's resultant (gravity: its mass). The same comparison
with and without it splits each coarse mesh's drop 1 - E / E_true into

- **load capture**: E / E_true conserved minus E / E_true not conserved;
- **stiffness**: 1 - E / E_true conserved (what is left);

with a grasp (a total force over its patch, the same on every mesh) as the
control. The liver's body ships ``lateral-push-kept`` and ``sag-90-kept``;
the kidney's conserving copies of ``probe-press`` and ``sag`` are appended
to a copy of its body file. Every default estimator, one seed, 8 markers,
0.1 mm noise; for the kidney the parenchyma's modulus (its tumour's too is
identified). Rows keep each run's load ratio (``load_resultant_ratio``).

Run ``python studies/load_capture.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import _cli
import numpy as np
import pandas as pd

from idbench import CompareConfig, compare
from idbench_fem.bodies.catalog import body_path

# Parameters (full size)
ORGANS: dict[str, dict[str, Any]] = {
    "liver": {"control": "grasp-lift", "parameter": "E", "prior": (2000.0, 2000.0),
              "pairs": {"lateral-push": "lateral-push-kept",
                        "sag-90": "sag-90-kept"}},
    "kidney": {"control": "grasp-pole", "parameter": "E_parenchyma",
               "prior": (3000.0, 3000.0),
               "pairs": {"probe-press": "probe-press-kept", "sag": "sag-kept"}},
}  # fmt: skip
MESHES = ("200", "500", "1000")
TRUTH = "4000"
STEPS = 10
MARKERS = 8
NOISE = 1e-4  # m
SEEDS = 1

QUICK: dict[str, Any] = {
    "organs": ("liver",),
    "meshes": ("150",),
    "truth": "600",
    "steps": 4,
    "estimators": ("batch-ls", "ro-ukf"),
}


def body_file(organ: str, folder: Path) -> str:
    """The organ's body: the shipped liver, or the kidney with conserving copies."""
    if organ == "liver":
        return organ
    source = body_path(organ)
    text = source.read_text().replace('"meshes/', f'"{source.parent / "meshes"}/')
    kept = "".join(
        f'\n[[manipulation]]\n{_copy(text, name)}conserve = "resultant"\n'
        f'name = "{copy}"\n'
        for name, copy in ORGANS[organ]["pairs"].items()
    )
    text = text.replace("\n[markers]", kept + "\n[markers]", 1)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{organ}-conserving.toml"
    path.write_text(text)
    return str(path)


def _copy(text: str, name: str) -> str:
    """The lines of manipulation ``name``'s table but its name (TOML text)."""
    start = text.index(f'name = "{name}"')
    start = text.rindex("[[manipulation]]", 0, start) + len("[[manipulation]]\n")
    end = text.index("\n[", start)
    lines = text[start:end].splitlines()
    return "".join(f"{line}\n" for line in lines
                   if line.strip() and not line.startswith(("name", "#")))  # fmt: skip


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """One row per (organ, manipulation, conserve, mesh, estimator).

    Columns: ``organ``, ``manipulation`` (the one without conservation),
    ``conserve`` (``none`` or ``resultant``), ``mesh``, ``model_nodes``,
    ``estimator``, ``E_ratio`` (the organ's modulus over its true value,
    last step), ``load_resultant_ratio`` (the mesh's resultant over the
    truth's) and ``status``.
    """
    s = {"organs": tuple(ORGANS), "meshes": MESHES, "truth": TRUTH,
         "steps": STEPS, "estimators": None, **(QUICK if quick else {})}  # fmt: skip
    folder = Path(out) if out is not None else None
    rows = []
    for organ in s["organs"]:
        spec = ORGANS[organ]
        bodies = (folder or Path(".")) / "bodies" if folder else _tmp()
        body = body_file(organ, bodies)
        scenarios = (spec["control"], *spec["pairs"], *spec["pairs"].values())
        settings: dict[str, Any] = {
            "model": "solid", "scenarios": scenarios, "meshes": s["meshes"],
            "truth_mesh": s["truth"], "seeds": SEEDS, "steps": s["steps"],
            "obs_points": (MARKERS,), "noise": (NOISE,), "prior": spec["prior"],
            "model_settings": {"solid": {"body": body, "reference": s["truth"]}},
        }  # fmt: skip
        if s["estimators"]:
            settings["estimators"] = s["estimators"]
        runs, _ = compare(CompareConfig(**settings),
                          None if folder is None else folder / organ)  # fmt: skip
        base = {v: k for k, v in spec["pairs"].items()}
        name = spec["parameter"]
        for _, r in runs.iterrows():
            scenario = str(r["scenario"])
            ok = r["status"] == "ok"
            rows.append({
                "organ": organ,
                "manipulation": base.get(scenario, scenario),
                "conserve": "resultant" if scenario in base else "none",
                "mesh": str(r["mesh"]),
                "model_nodes": int(r["model_nodes"]),
                "estimator": str(r["estimator"]),
                "E_ratio": float(r[f"{name}_final"] / r[f"{name}_true"])
                if ok else np.nan,
                "load_resultant_ratio": float(r.get("load_resultant_ratio", np.nan)),
                "status": str(r["status"]),
            })  # fmt: skip
    table = pd.DataFrame(rows)
    if not quick and folder is not None:
        _cli.docs_data("load_capture", table)
    return table


def _tmp() -> Path:
    import tempfile

    return Path(tempfile.mkdtemp(prefix="load-capture-"))


def split(table: pd.DataFrame) -> pd.DataFrame:
    """Per (organ, manipulation, mesh): the drop and its two parts (medians).

    ``E_none`` and ``E_kept`` are the median E / E_true over the estimators
    without and with conservation (``*_lo``, ``*_hi`` their range), ``load``
    the resultant ratio without conservation, ``drop`` = 1 - E_none,
    ``from_load`` = E_kept - E_none and ``from_stiffness`` = 1 - E_kept. The
    control (a grasp) has E_none only.
    """
    out = []
    keys = ["organ", "manipulation", "mesh", "model_nodes"]
    for key, d in table.groupby(keys, sort=False):
        row = dict(zip(keys, key, strict=True))
        for tag, part in (("none", "none"), ("kept", "resultant")):
            e = d.loc[d["conserve"] == part, "E_ratio"].dropna()
            row[f"E_{tag}"] = float(e.median()) if len(e) else np.nan
            row[f"E_{tag}_lo"] = float(e.min()) if len(e) else np.nan
            row[f"E_{tag}_hi"] = float(e.max()) if len(e) else np.nan
        row["load"] = float(d.loc[d["conserve"] == "none", "load_resultant_ratio"]
                            .median())  # fmt: skip
        row["drop"] = 1.0 - row["E_none"]
        row["from_load"] = row["E_kept"] - row["E_none"]
        row["from_stiffness"] = 1.0 - row["E_kept"]
        out.append(row)
    return pd.DataFrame(out)


def markdown(table: pd.DataFrame) -> str:
    """The page's table: per organ, manipulation and mesh, the split (medians)."""
    head = ["organ", "manipulation", "model nodes", "load / truth's",
            "E / E_true (range over estimators)", "conserved (range)",
            "drop", "from the load", "from stiffness"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in split(table).iterrows():

        def cell(tag: str, r: Any = r) -> str:
            if not np.isfinite(r[f"E_{tag}"]):
                return "-"
            return (f"{r[f'E_{tag}']:.2f} ({r[f'E_{tag}_lo']:.2f}-"
                    f"{r[f'E_{tag}_hi']:.2f})")  # fmt: skip

        kept = np.isfinite(r["E_kept"])
        cells = [
            str(r["organ"]), str(r["manipulation"]), f"{int(r['model_nodes']):,}",
            f"{r['load']:.3f}", cell("none"), cell("kept"), f"{r['drop']:.2f}",
            f"{r['from_load']:.2f}" if kept else "-",
            f"{r['from_stiffness']:.2f}" if kept else "-",
        ]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(table: pd.DataFrame, path: Path) -> None:
    """E / E_true against model nodes: not conserved (dots), conserved (squares)."""
    import matplotlib.pyplot as plt

    parts = split(table)
    organs = list(dict.fromkeys(parts["organ"]))
    fig, axes = plt.subplots(1, len(organs), figsize=(6 * len(organs), 4.2),
                             squeeze=False)  # fmt: skip
    for ax, organ in zip(axes[0], organs, strict=True):
        d = parts[parts["organ"] == organ]
        for i, (name, g) in enumerate(d.groupby("manipulation", sort=False)):
            colour = f"C{i}"
            ax.plot(g["model_nodes"], g["E_none"], "o-", color=colour, label=name)
            if np.isfinite(g["E_kept"]).any():
                ax.plot(g["model_nodes"], g["E_kept"], "s--", color=colour,
                        mfc="none", label=f"{name}, conserved")  # fmt: skip
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set(xscale="log", xlabel="model nodes", title=organ,
               ylabel="E / E_true (median over estimators)")  # fmt: skip
        ax.legend(fontsize="x-small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    _cli.main(__doc__, "results/load_capture", compute, plot, "load_capture",
              printed=lambda t: print(markdown(t)), csv=True)  # fmt: skip
