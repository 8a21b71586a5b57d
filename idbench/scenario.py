"""Load paths and observation sparsity settings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Scenario:
    """A quasi-static load path: dead end traction ramped over K steps.

    At step k of K the traction is ``(k / K) * magnitude * direction``.

    Attributes
    ----------
    name
        Registry name, e.g. ``"bend-y"``.
    direction
        Unit vector (3,).
    magnitude
        End traction in Pa.
    transfer
        Name of the scenario used for the transfer error.
    description
        One line for listings.
    """

    name: str
    direction: tuple[float, float, float]
    magnitude: float
    transfer: str = ""
    description: str = ""

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, dtype=float)
        if d.shape != (3,) or not np.isclose(np.linalg.norm(d), 1.0):
            raise ValueError(
                f"scenario {self.name!r}: direction must be a unit 3-vector"
            )
        if not self.magnitude > 0:
            raise ValueError(f"scenario {self.name!r}: magnitude must be > 0")

    def traction(self, k: int, n_steps: int) -> NDArray[np.float64]:
        """Traction vector (3,) at step ``k`` of ``n_steps``."""
        return (k / n_steps) * self.magnitude * np.asarray(self.direction, dtype=float)


@dataclass(frozen=True)
class Sparsity:
    """How sparse the data are.

    Attributes
    ----------
    obs_every
        An observation is available at steps k with ``k % obs_every == 0``.
    obs_points
        Number of marker points M (m = 3M observed values).
    noise
        Standard deviation sigma (m) of the Gaussian noise on each value.
    """

    obs_every: int = 2
    obs_points: int = 2
    noise: float = 1e-4

    def __post_init__(self) -> None:
        if self.obs_every < 1:
            raise ValueError(f"obs_every must be >= 1, got {self.obs_every}")
        if self.obs_points < 1:
            raise ValueError(f"obs_points must be >= 1, got {self.obs_points}")
        if not (np.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"noise must be finite and >= 0, got {self.noise}")

    def observed(self, k: int) -> bool:
        """Whether step ``k`` has an observation."""
        return k % self.obs_every == 0
