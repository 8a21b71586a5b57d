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
