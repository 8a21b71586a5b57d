"""The built-in load paths of the cantilever beam (docs/design.md section 1)."""

from __future__ import annotations

import math

from idbench import Scenario
from idbench_fem.models.beam_settings import end_traction

BEND_TRACTION = 8.9
"""End traction (Pa) for bending and mixed paths: tip moves about 0.05 m."""

STRETCH_TRACTION = 250.0
"""End traction (Pa) for stretching: about 5% elongation."""


def _mixed(angle_deg: float) -> Scenario:
    a = math.radians(angle_deg)
    return end_traction(
        f"mixed-{angle_deg:g}",
        (math.cos(a), -math.sin(a), 0.0),
        BEND_TRACTION,
        "stretch-x",
        f"traction in the x-y plane, {angle_deg:g} deg from +x to -y",
    )


SCENARIOS: tuple[Scenario, ...] = (
    end_traction("bend-y", (0.0, -1.0, 0.0), BEND_TRACTION, "stretch-x",
                 "bending in -y"),
    end_traction("bend-z", (0.0, 0.0, -1.0), BEND_TRACTION, "stretch-x",
                 "bending in -z"),
    end_traction("stretch-x", (1.0, 0.0, 0.0), STRETCH_TRACTION, "bend-y",
                 "stretching in +x"),
    _mixed(30.0),
    _mixed(60.0),
)  # fmt: skip


_T = 0.2 * BEND_TRACTION


def _pull_bend(angle: float, axis: int, tilt: float) -> tuple[float, float, float]:
    """A traction ``angle`` degrees from +x towards -(y, z)[axis], tilted."""
    a = math.radians(angle)
    t = [BEND_TRACTION * math.cos(a), tilt, tilt]
    t[1 + axis] = -BEND_TRACTION * math.sin(a)
    return (t[0], t[1], t[2])


DESIGN_TRACTIONS: dict[str, tuple[float, float, float]] = {
    "design-x": (STRETCH_TRACTION, _T, _T),
    "design-y": (-0.5, -BEND_TRACTION, _T),
    "design-z": (-0.5, _T, -BEND_TRACTION),
    "design-x2": (STRETCH_TRACTION, -_T, -_T),
    "design-y2": (0.5, -BEND_TRACTION, -_T),
    "design-z2": (0.5, -_T, -BEND_TRACTION),
    "design-xy15": _pull_bend(15.0, 0, _T),
    "design-xy75": _pull_bend(75.0, 0, -_T),
    "design-xz15": _pull_bend(15.0, 1, _T),
    "design-xz75": _pull_bend(75.0, 1, -_T),
    "design-xy15b": _pull_bend(15.0, 0, -_T),
    "design-xy75b": _pull_bend(75.0, 0, _T),
    "design-xz15b": _pull_bend(15.0, 1, -_T),
    "design-xz75b": _pull_bend(75.0, 1, _T),
}
"""The beam's offline design: the 14 end tractions (Pa) of the approximation-
error calibration's (``studies/physical_stiffness.py``), none a registered
path, whose cone holds every one of them; its reduced models (``rom:80x11x11:30``)
take their snapshots from them, at E from 2,500 Pa up (:data:`DESIGN_MODULI`)."""

DESIGN_MODULI = (2500.0, 20000.0)
"""The range of E (Pa) of the beam's design; its paths run at the lower end."""
