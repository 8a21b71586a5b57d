"""The beam model for tests, built by :func:`idbench_fem.models.beam.build`.

``beam_model`` takes the beam's mesh and load path and the settings tests
vary most as keywords (``nu``, ``grid``, ``parameters``; ``options`` for any
other :class:`~idbench_fem.models.beam_settings.BeamSettings` field, and
``chord_ratio``).
"""

from __future__ import annotations

from typing import Any

from idbench import Scenario
from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.models.beam import build
from idbench_fem.models.beam_settings import BeamSettings, EndTraction
from idbench_fem.models.solid import SolidModel


def beam_model(
    mesh: SolidMesh,
    scenario: Scenario | EndTraction,
    n_steps: int = 20,
    nu: float = 0.45,
    markers: int = 2,
    grid: tuple[int, int, int] = (20, 4, 4),
    parameters: str = "E",
    options: dict[str, Any] | None = None,
) -> SolidModel:
    """The beam on ``mesh`` under ``scenario`` with these settings."""
    opts = dict(options or {})
    chord_ratio = opts.pop("chord_ratio", None)
    settings = BeamSettings(nu=nu, parameters=parameters, grid=grid, **opts)
    return build(mesh, scenario, n_steps, markers, settings, chord_ratio)
