"""Load paths and observation sparsity settings."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Scenario:
    """A named quasi-static load path, ramped over K steps by the model.

    The core treats the load as opaque: the model plugin that registers a
    scenario also interprets its ``load`` (a beam reads an end traction, an
    organ a grasp force or gravity). Everything the core needs is the name,
    the transfer target and a description.

    Attributes
    ----------
    name
        Registry name.
    load
        The load description, JSON-serialisable (plain dicts, lists, strings,
        numbers); its meaning belongs to the model.
    transfer
        Name of another registered scenario, used for the transfer error
        (empty: none).
    description
        One line for listings.
    """

    name: str
    load: dict[str, Any] = field(default_factory=dict, hash=False)
    transfer: str = ""
    description: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"scenario name {self.name!r}: need a non-empty string")
        if not isinstance(self.load, dict):
            raise ValueError(f"scenario {self.name!r}: load must be a dict")
        try:
            json.dumps(self.load, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"scenario {self.name!r}: load is not JSON-serialisable ({exc})"
            ) from None
        if not isinstance(self.transfer, str) or self.transfer == self.name:
            raise ValueError(
                f"scenario {self.name!r}: transfer {self.transfer!r} must be the "
                "name of another scenario"
            )


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
