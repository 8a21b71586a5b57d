"""The beam plugin's ``idbench calibrate`` command (a beam tool, so it lives here)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from idbench import Command, ConfigError, ModelFailure, build_registry


def _floats(name: str) -> Any:
    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(",") if v.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"--{name} {text!r}: need comma-separated numbers"
            ) from None
        if not values:
            raise argparse.ArgumentTypeError(f"--{name} {text!r}: need a number")
        return values

    return parse


def _names(text: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in text.split(",") if v.strip())


def configure(k: argparse.ArgumentParser) -> None:
    """The arguments of ``idbench calibrate``."""
    from idbench_fem.tools.calibrate import ANGLES, HELD_BACK

    k.description = (
        "Map the effective E of a coarse beam mesh over load space: traction "
        "directions from stretching (0 deg, +x) to bending (90 deg, -y), each "
        "ramped over --steps levels, fitted against the truth mesh."
    )
    k.add_argument("--mesh", required=True, help="coarse model mesh spec")
    k.add_argument("--truth-mesh", default="80x11x11", help="truth mesh spec")
    k.add_argument(
        "--angles",
        type=_floats("angles"),
        help="traction directions, degrees from +x (stretch) to -y (bend), 0..90 "
        f"(default: {','.join(f'{a:g}' for a in ANGLES)})",
    )
    k.add_argument("--steps", type=int, default=10, help="load levels")
    k.add_argument(
        "--E-true", dest="E_true", type=float, default=5000.0, help="true E (Pa)"
    )
    k.add_argument("--nu", type=float, default=0.45, help="Poisson ratio")
    k.add_argument("--model", default="svk-beam", help="registered beam model name")
    k.add_argument(
        "--evaluate",
        type=_names,
        help=f"held-back scenarios to score (default: {','.join(HELD_BACK)}; "
        "'none' skips)",
    )
    k.add_argument(
        "--evaluate-angles",
        type=_floats("evaluate-angles"),
        default=(3.0, 10.0),
        help="also score ad-hoc paths at these angles (off the grid)",
    )
    k.add_argument("--seeds", type=int, default=3, help="RO-UKF seeds")
    k.add_argument(
        "--out", type=Path, default=Path("idbench-calibration"), help="output folder"
    )
    k.add_argument("-q", "--quiet", action="store_true", help="print only errors")


def run(args: argparse.Namespace) -> int:
    """``idbench calibrate``: the E_eff map, its collapse and held-back scores."""
    from idbench_fem.tools.calibrate import (
        ANGLES,
        HELD_BACK,
        CalibrationSettings,
        calibrate,
        collapse,
        evaluate,
    )

    if not str(args.out).strip():
        raise ConfigError("--out '': need a path")
    if args.out.exists() and not args.out.is_dir():
        raise ConfigError(f"--out {str(args.out)!r} is a file; need a directory")
    settings = CalibrationSettings(
        mesh=args.mesh,
        truth_mesh=args.truth_mesh,
        angles=args.angles or ANGLES,
        steps=args.steps,
        E_true=args.E_true,
        nu=args.nu,
        model=args.model,
    )
    scenarios = HELD_BACK if args.evaluate is None else args.evaluate
    if tuple(scenarios) == ("none",):
        scenarios = ()
    if args.seeds < 1:
        raise ConfigError(f"--seeds {args.seeds}: must be >= 1")
    for angle in args.evaluate_angles:
        if not 0 <= angle <= 90:
            raise ConfigError(f"--evaluate-angles {angle:g}: must be in 0..90")
    registry = build_registry()
    for name, table in (("scenario", registry.scenarios), ("model", registry.models)):
        wanted = scenarios if name == "scenario" else (args.model,)
        for value in wanted:
            if value not in table:
                raise ConfigError(
                    f"unknown {name} {value!r}; known: {', '.join(sorted(table))}"
                )

    def progress(done: int, total: int, angle: float) -> None:
        if not args.quiet:
            print(f"calibrated {done}/{total}: {angle:g} deg", file=sys.stderr)

    try:
        result = calibrate(settings, registry, progress)
    except OSError as exc:
        raise ConfigError(str(exc)) from None
    except ModelFailure as exc:
        print(f"idbench: calibration failed: {exc}", file=sys.stderr)
        return 1
    written = result.save(args.out)
    fit = collapse(result)
    fit.to_csv(args.out / "collapse.csv", index=False)
    written.append(args.out / "collapse.csv")
    if scenarios:
        paths = [*scenarios, *(result.manipulation(a) for a in args.evaluate_angles)]
        try:
            scores = evaluate(
                result, paths, seeds=args.seeds, registry=registry,
                out=args.out / "ro-ukf",
            )  # fmt: skip
        except ModelFailure as exc:
            print(f"idbench: evaluation failed: {exc}", file=sys.stderr)
            return 1
        scores.to_parquet(args.out / "evaluation.parquet", index=False)
        scores.to_csv(args.out / "evaluation.csv", index=False)
        written += [args.out / "evaluation.parquet", args.out / "evaluation.csv"]
    if not args.quiet:
        wide = result.table.pivot(index="fraction", columns="angle", values="ratio")
        print("E_eff / E_true by load fraction (rows) and angle in degrees (columns)")
        print(wide.round(3).to_string())
        print(fit.round(4).to_string(index=False))
        if scenarios:
            print(scores.round(6).to_string(index=False))
        for path in written:
            print(f"wrote {path}")
    return 0


CALIBRATE = Command(
    help="map the effective E of a coarse beam mesh over load space",
    configure=configure,
    run=run,
)
