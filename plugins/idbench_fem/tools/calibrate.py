"""Calibrated effective stiffness: a map E_eff(direction, magnitude) for a coarse mesh.

A coarse mesh identifies a low, deformation-dependent Young's modulus. This
module measures that dependence once, offline, against a fine truth mesh, and
turns it into a smooth function a real-time simulation can evaluate at every
step from the load it applies, with no observations:

1. sweep traction directions at angles 0 (stretch, +x) to 90 degrees (bend,
   -y), each ramped over K load levels up to a magnitude interpolated between
   the registered ``stretch-x`` and ``bend-y`` end tractions;
2. at each (angle, level) fit the best constant E of the coarse model on the
   truth's shape-error grid (:func:`idbench.calibrate.effective.effective_path`);
3. interpolate log E_eff over (angle, load fraction) with monotone cubic
   (PCHIP) pieces: C1-smooth and without overshoot where E_eff changes fast.

:func:`evaluate` then drives the coarse model with the calibrated E on
manipulations held back from the calibration and scores its shape error against
E_true, one constant E and the RO-UKF with observations.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from idbench import (
    ConfigError,
    ForwardModel,
    ModelFailure,
    ModelSpec,
    Registry,
    Scenario,
    build_registry,
)
from idbench_fem.models.beam_settings import EndTraction, end_traction

if TYPE_CHECKING:  # pandas, scipy.interpolate, idbench's runs: loaded when used
    import pandas as pd

FloatArray = NDArray[np.float64]

log = logging.getLogger(__name__)

#: Calibration angles (degrees from +x towards -y), dense near 0 where E_eff
#: changes fastest (any transverse load soon dominates the response); 30 and
#: 60 degrees are held back.
ANGLES = (0.0, 0.5, 1.0, 2.0, 5.0, 15.0, 45.0, 75.0, 90.0)
#: Registered manipulations for :func:`evaluate`: mixed-30 and mixed-60 are off
#: the angle grid, bend-z out of the calibrated plane (the azimuth is ignored);
#: stretch-x lies on the 0-degree path, with its odd steps between levels.
HELD_BACK = ("mixed-30", "mixed-60", "bend-z", "stretch-x")


def direction(angle: float, azimuth: float = 0.0) -> FloatArray:
    """Unit traction direction ``angle`` degrees from +x towards -y.

    ``azimuth`` (degrees) turns the transverse part about x from -y towards -z.
    """
    a, b = np.radians(angle), np.radians(azimuth)
    return np.array([np.cos(a), -np.sin(a) * np.cos(b), -np.sin(a) * np.sin(b)])


def angle_of(vector: Sequence[float] | FloatArray) -> float:
    """Angle (degrees) between a traction direction and +x."""
    d = np.asarray(vector, dtype=float)
    norm = np.linalg.norm(d)
    if d.shape != (3,) or not norm > 0:
        raise ValueError(f"direction {tuple(d.ravel())}: need a non-zero 3-vector")
    return float(np.degrees(np.arccos(np.clip(d[0] / norm, -1.0, 1.0))))


def reference_magnitude(angle: float, stretch: float, bend: float) -> float:
    """End traction (Pa) of the calibration path at ``angle``.

    An ellipse between the stretching (0 deg) and bending (90 deg) end
    tractions, so every direction is taken to a comparable deformation.
    """
    a = np.radians(angle)
    return float(1.0 / np.hypot(np.cos(a) / stretch, np.sin(a) / bend))


@dataclass(frozen=True)
class CalibrationSettings:
    """What a calibration sweeps and on which meshes.

    Attributes
    ----------
    mesh
        The coarse model mesh spec to calibrate.
    truth_mesh
        The fine mesh spec whose response defines the truth.
    angles
        Traction directions, degrees from +x (stretch) towards -y (bend), in
        [0, 90]; at least two.
    steps
        Load levels per direction (the magnitude grid is k / steps, k = 1..steps).
    E_true, nu
        Truth Young's modulus (Pa) and Poisson ratio (also the model's nu).
    model
        Registered model name.
    stretch_magnitude, bend_magnitude
        End tractions (Pa) at 0 and 90 degrees; ``None`` takes them from the
        registered ``stretch-x`` and ``bend-y`` scenarios.
    grid
        Shape-error grid points per axis.
    """

    mesh: str
    truth_mesh: str = "80x11x11"
    angles: tuple[float, ...] = ANGLES
    steps: int = 10
    E_true: float = 5000.0
    nu: float = 0.45
    model: str = "svk-beam"
    stretch_magnitude: float | None = None
    bend_magnitude: float | None = None
    grid: tuple[int, int, int] = (20, 4, 4)

    def __post_init__(self) -> None:
        angles = tuple(float(a) for a in self.angles)
        if len(set(angles)) < 2 or any(not 0.0 <= a <= 90.0 for a in angles):
            raise ConfigError(
                f"angles {self.angles!r}: need at least two distinct values in "
                "[0, 90] degrees (compressing the beam buckles it)"
            )
        object.__setattr__(self, "angles", tuple(sorted(set(angles))))
        if isinstance(self.steps, bool) or not isinstance(self.steps, int):
            raise ConfigError(f"steps {self.steps!r}: must be a whole number >= 2")
        if self.steps < 2:
            raise ConfigError(f"steps {self.steps!r}: must be a whole number >= 2")
        if not (np.isfinite(self.E_true) and self.E_true > 0):
            raise ConfigError(f"E_true {self.E_true!r}: must be a number > 0")
        if not -1.0 < self.nu < 0.5:
            raise ConfigError(f"nu {self.nu!r}: must be in (-1, 0.5)")
        for name in ("stretch_magnitude", "bend_magnitude"):
            value = getattr(self, name)
            if value is not None and not (np.isfinite(value) and value > 0):
                raise ConfigError(f"{name} {value!r}: must be a number > 0")


class Calibration:
    """The calibration table and its interpolant ``E_eff(direction, magnitude)``.

    Parameters
    ----------
    table
        One row per (angle, step) with columns ``angle``, ``step``,
        ``fraction``, ``magnitude`` (Pa), ``E_eff`` (Pa), ``ratio``
        (E_eff / E_true), ``rms`` (m), ``tip`` (truth tip displacement norm,
        m), ``tip_angle`` (degrees of the truth tip displacement from +x).
    settings
        The settings that produced it, with both magnitudes filled in.
    """

    def __init__(self, table: pd.DataFrame, settings: CalibrationSettings) -> None:
        from scipy.interpolate import PchipInterpolator
        if settings.stretch_magnitude is None or settings.bend_magnitude is None:
            raise ValueError("settings must carry both end magnitudes")
        self.table = table.sort_values(["angle", "step"]).reset_index(drop=True)
        self.settings = settings
        angles = np.array(sorted(self.table["angle"].unique()))
        fractions = np.array(sorted(self.table["fraction"].unique()))
        log_e = np.log(
            self.table.pivot(index="angle", columns="fraction", values="E_eff")
            .loc[angles, fractions]
            .to_numpy()
        )
        if len(angles) < 2 or len(fractions) < 2 or not np.all(np.isfinite(log_e)):
            raise ValueError(
                "calibration table needs >= 2 angles and >= 2 levels, all fitted"
            )
        self._angles, self._fractions = angles, fractions
        self._by_level = [PchipInterpolator(fractions, row) for row in log_e]

    def magnitude_at(self, angle: float) -> float:
        """End traction (Pa) of the calibration path at ``angle``."""
        s = self.settings
        return reference_magnitude(angle, s.stretch_magnitude, s.bend_magnitude)  # type: ignore[arg-type]

    def manipulation(self, angle: float) -> Scenario:
        """A load path ``angle`` degrees off +x, to the calibration's traction.

        Named ``pull-<angle>`` (transfer target ``bend-y``); for
        :func:`evaluate` on directions off the angle grid, e.g. 3 or 10
        degrees, where E_eff changes fastest.
        """
        return end_traction(
            f"pull-{angle:g}",
            direction(angle),
            self.magnitude_at(angle),
            transfer="bend-y",
            description=f"end traction {angle:g} deg off +x towards -y",
        )

    def E_eff(self, direction: Sequence[float] | FloatArray, magnitude: float) -> float:
        """Calibrated effective E (Pa) for a traction of ``magnitude`` Pa.

        Outside the calibrated range the nearest edge value is used: below the
        first load level the first level's value (the small-strain limit is
        flat), above the end traction the last level's.

        Raises
        ------
        ValueError
            A compressive direction (x component < 0) or a negative magnitude.
        """
        from scipy.interpolate import PchipInterpolator
        angle = angle_of(direction)
        if angle > 90.0 + 1e-9:
            raise ValueError(
                f"direction {tuple(direction)}: compressive (x < 0) directions are "
                "outside the calibration (angles 0..90 degrees)"
            )
        if not (np.isfinite(magnitude) and magnitude >= 0):
            raise ValueError(f"magnitude {magnitude!r}: must be a number >= 0")
        a = float(np.clip(angle, self._angles[0], self._angles[-1]))
        f = magnitude / self.magnitude_at(angle)
        f = float(np.clip(f, self._fractions[0], self._fractions[-1]))
        across = np.array([float(level(f)) for level in self._by_level])
        return float(np.exp(PchipInterpolator(self._angles, across)(a)))

    def save(self, directory: str | Path) -> list[Path]:
        """Write ``calibration.parquet``, ``calibration.csv`` and the settings."""
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        paths = [out / "calibration.parquet", out / "calibration.csv"]
        self.table.to_parquet(paths[0], index=False)
        self.table.to_csv(paths[1], index=False)
        settings = out / "calibration.json"
        settings.write_text(json.dumps(asdict(self.settings), indent=2))
        return [*paths, settings]

    @classmethod
    def load(cls, directory: str | Path) -> Calibration:
        """Read a calibration written by :meth:`save` (or ``idbench calibrate``)."""
        import pandas as pd
        d = Path(directory)
        raw = json.loads((d / "calibration.json").read_text())
        raw["angles"] = tuple(raw["angles"])
        raw["grid"] = tuple(raw["grid"])
        table = pd.read_parquet(d / "calibration.parquet")
        return cls(table, CalibrationSettings(**raw))


def calibrate(
    settings: CalibrationSettings,
    registry: Registry | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> Calibration:
    """Sweep the directions of ``settings`` and fit E_eff at every load level.

    ``progress(done, total, angle)`` is called after each direction.
    """
    import pandas as pd

    from idbench import effective_path, simulate_truth
    registry = registry or build_registry()
    stretch = settings.stretch_magnitude or _magnitude(registry, "stretch-x")
    bend = settings.bend_magnitude or _magnitude(registry, "bend-y")
    settings = _replace(settings, stretch_magnitude=stretch, bend_magnitude=bend)
    rows: list[dict[str, Any]] = []
    for i, angle in enumerate(settings.angles, start=1):
        magnitude = reference_magnitude(angle, stretch, bend)
        scenario = end_traction(f"calibrate-{angle:g}", direction(angle), magnitude)
        truth_model = _model(registry, settings, settings.truth_mesh, scenario)
        truth = simulate_truth(truth_model, np.array([settings.E_true]))
        model = _model(registry, settings, settings.mesh, scenario)
        path = effective_path(model, truth.grid, np.array([settings.E_true]))
        tips = np.stack([truth.probes[f"tip_{a}"] for a in "xyz"], axis=1)
        for k in range(1, settings.steps + 1):
            tip = tips[k - 1]
            rows.append(
                {
                    "angle": angle,
                    "step": k,
                    "fraction": k / settings.steps,
                    "magnitude": k / settings.steps * magnitude,
                    "E_eff": float(path.theta[k - 1, 0]),
                    "ratio": float(path.theta[k - 1, 0]) / settings.E_true,
                    "rms": float(path.residual[k - 1]),
                    "tip": float(np.linalg.norm(tip)),
                    "tip_angle": _angle_from_x(tip),
                }
            )
        if progress:
            progress(i, len(settings.angles), angle)
        else:
            log.info("calibrated %d/%d: %g deg", i, len(settings.angles), angle)
    return Calibration(pd.DataFrame(rows), settings)


def collapse(calibration: Calibration) -> pd.DataFrame:
    """How well candidate coordinates explain the calibration data.

    For each coordinate set, the RMS relative error of log E_eff predicted
    without the point's own direction (leave one angle out, interior angles
    only), so a coordinate that merely interpolates is not rewarded:

    - ``angle, fraction``: the interpolant of :class:`Calibration`;
    - ``tip``: a cubic in the truth tip displacement norm alone;
    - ``tip_angle``: a cubic in the direction of the truth tip displacement.
    """
    import pandas as pd
    table = calibration.table
    angles = sorted(table["angle"].unique())
    interior = angles[1:-1]
    errors: dict[str, list[float]] = {"angle, fraction": [], "tip": [], "tip_angle": []}
    for held in interior:
        train = table[table["angle"] != held]
        test = table[table["angle"] == held]
        spline = Calibration(train, calibration.settings)
        d = direction(held)
        predicted = [spline.E_eff(d, m) for m in test["magnitude"]]
        errors["angle, fraction"] += list(np.log(predicted) - np.log(test["E_eff"]))
        for name in ("tip", "tip_angle"):
            deg = min(3, len(train) - 1)
            coef = np.polyfit(train[name], np.log(train["E_eff"]), deg)
            errors[name] += list(np.polyval(coef, test[name]) - np.log(test["E_eff"]))
    return pd.DataFrame(
        [
            {
                "coordinates": name,
                "rms_relative_error": float(np.sqrt(np.mean(np.square(e))))
                if e
                else np.nan,
                "held_out_angles": len(interior),
            }
            for name, e in errors.items()
        ]
    )


def evaluate(
    calibration: Calibration,
    scenarios: Sequence[str | Scenario] = HELD_BACK,
    *,
    steps: int = 20,
    seeds: int = 3,
    registry: Registry | None = None,
    out: str | Path | None = None,
) -> pd.DataFrame:
    """Shape error on held-back manipulations, four ways of choosing E.

    ``scenarios`` are registered names or :class:`~idbench.core.scenario.Scenario`
    objects (e.g. :meth:`Calibration.manipulation` at an angle off the grid).
    Methods: ``E_true`` (direct simulation), ``constant`` (one E for every
    manipulation, identified once on bending: the map at 90 degrees and full
    load, as a one-experiment calibration would give), ``calibrated``
    (E_eff(direction, magnitude) of the applied load at each step, no
    observations), ``ro-ukf`` (the filter with the default sparse data, mean
    over ``seeds``; results in ``out`` if given).

    Returns one row per (scenario, method): ``shape_error_final`` and
    ``shape_error_path`` (mean per grid point in m, at the last step and
    averaged over the steps), and the E range used.
    """
    import pandas as pd

    from idbench import CompareConfig, compare, simulate_truth

    registry = registry or build_registry()
    extra = {sc.name: sc for sc in scenarios if isinstance(sc, Scenario)}
    if extra:  # ad-hoc manipulations: a registry that knows them too
        registry = registry.with_scenarios(list(extra.values()), plugin="calibrate")
    names = [sc.name if isinstance(sc, Scenario) else sc for sc in scenarios]
    s = calibration.settings
    constant = calibration.E_eff(direction(90.0), calibration.magnitude_at(90.0))
    rows: list[dict[str, Any]] = []
    for name in names:
        scenario = registry.scenario(name)
        load = EndTraction.of(scenario)
        spec = _replace(s, steps=steps)
        truth = simulate_truth(
            _model(registry, spec, s.truth_mesh, scenario), np.array([s.E_true])
        )
        model = _model(registry, spec, s.mesh, scenario)
        loads = [
            calibration.E_eff(load.direction, k / steps * load.magnitude)
            for k in range(1, steps + 1)
        ]
        plans = {
            "E_true": np.full(steps, s.E_true),
            "constant": np.full(steps, constant),
            "calibrated": np.array(loads),
        }
        for method, moduli in plans.items():
            errors = _errors(model, moduli, truth.grid)
            rows.append(
                {
                    "scenario": name,
                    "method": method,
                    "shape_error_final": errors[-1],
                    "shape_error_path": float(np.mean(errors)),
                    "E_min": float(moduli.min()),
                    "E_max": float(moduli.max()),
                }
            )
    config = CompareConfig(
        estimators=("ro-ukf",),
        meshes=(s.mesh,),
        truth_mesh=s.truth_mesh,
        scenarios=tuple(names),
        seeds=seeds,
        steps=steps,
        true={"E": s.E_true},
        model=s.model,
        model_settings={s.model: {"nu": s.nu, "grid": list(s.grid)}},
    )
    runs, traces = compare(config, out, registry=registry)
    ok = runs[runs["status"] == "ok"]
    path = traces[traces["run_id"].isin(ok["run_id"])]
    path = path.merge(ok[["run_id", "scenario"]], on="run_id")
    for name in names:
        mine = ok[ok["scenario"] == name]
        estimates = mine["E_final"]
        rows.append(
            {
                "scenario": name,
                "method": "ro-ukf",
                "shape_error_final": float(mine["shape_error_mean_final"].mean()),
                "shape_error_path": float(
                    path[path["scenario"] == name]["shape_error_mean"].mean()
                ),
                "E_min": float(estimates.min()) if len(mine) else np.nan,
                "E_max": float(estimates.max()) if len(mine) else np.nan,
            }
        )
    return pd.DataFrame(rows)


def _angle_from_x(vector: FloatArray) -> float:
    """Angle (degrees) of a displacement from +x; 0 for a zero vector."""
    return float(np.degrees(np.arctan2(np.hypot(vector[1], vector[2]), vector[0])))


def _errors(
    model: ForwardModel, moduli: FloatArray, truth_grid: FloatArray
) -> FloatArray:
    """Mean shape error per step of ``model`` driven by one E per step."""
    from idbench import shape_error
    state = model.reset()
    errors = np.empty(len(moduli))
    for k, e in enumerate(moduli, start=1):
        try:
            state = model.step(np.array([e]), k, state)
        except ModelFailure:
            state = model.step(np.array([e]), k, state, substeps=8)
        errors[k - 1] = shape_error(model.grid(state), truth_grid[k - 1])[1]
    return errors


def _model(
    registry: Registry, settings: CalibrationSettings, mesh: str, scenario: Scenario
) -> ForwardModel:
    spec = ModelSpec(
        mesh=mesh,
        scenario=scenario,
        n_steps=settings.steps,
        settings={"nu": settings.nu, "grid": settings.grid},
    )
    model: ForwardModel = registry.model(settings.model)(spec)
    return model


def _magnitude(registry: Registry, name: str) -> float:
    """End traction (Pa) of the registered beam scenario ``name``."""
    return EndTraction.of(registry.scenario(name)).magnitude


def _replace(settings: CalibrationSettings, **changes: Any) -> CalibrationSettings:
    return CalibrationSettings(**{**asdict(settings), **changes})


__all__ = [
    "ANGLES",
    "HELD_BACK",
    "Calibration",
    "CalibrationSettings",
    "angle_of",
    "calibrate",
    "collapse",
    "direction",
    "evaluate",
    "reference_magnitude",
]
