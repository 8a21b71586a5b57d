"""A model that is no beam: a spring chain whose parameter is k, and its plugin.

The report, uncertainty and validity tests run it through ``compare()``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

import idbench


class SpringChain:
    """n nodes on a line, springs of stiffness k (or k_0, k_1 for two halves).

    The state is the n nodal displacements under an end load ramped over the
    steps; a coarse chain is stiffer than a fine one by a factor 1 + 2/n, so
    coarse chains identify a lower k, as coarse meshes do for E.
    """

    def __init__(self, spec: idbench.ModelSpec) -> None:
        settings = spec.settings or SpringSettings()
        self.n_nodes = int(spec.mesh)
        self.n_steps = spec.n_steps
        self.markers = spec.markers
        self.load = float(spec.scenario.load["force"])
        p = settings.p
        names = ("k",) if p == 1 else tuple(f"k_{i}" for i in range(p))
        self.parameters = idbench.ParameterSpec(
            names, (1e-3,) * p, (1e6,) * p, default=(settings.k,) * p
        )
        self.x = np.linspace(0.0, 1.0, self.n_nodes)
        self._solves = 0

    def reset(self) -> np.ndarray:
        return np.zeros(self.n_nodes)

    def _compliance(self, theta: np.ndarray) -> np.ndarray:
        """Displacement per unit load at each node, (n,)."""
        theta = np.asarray(theta, dtype=float)
        half = np.minimum((self.x * len(theta)).astype(int), len(theta) - 1)
        stiff = 1.0 + 2.0 / self.n_nodes
        dx = np.diff(self.x, prepend=0.0)
        return np.cumsum(dx / (theta[half] * stiff))

    def step(
        self, theta: np.ndarray, k: int, state: np.ndarray, *, substeps: int = 1
    ) -> np.ndarray:
        self._solves += 1
        return (k / self.n_steps) * self.load * self._compliance(theta)

    def observe(self, state: np.ndarray) -> np.ndarray:
        at = np.linspace(1.0, 0.5, self.markers)
        return np.interp(at, self.x, state)

    def grid(self, state: np.ndarray) -> np.ndarray:
        return np.interp(np.linspace(0, 1, 10), self.x, state)[:, None]

    def probes(self, state: np.ndarray) -> dict[str, float]:
        return {"end": float(state[-1])}

    def cost(self) -> idbench.Cost:
        return idbench.Cost(self._solves, self._solves, self._solves)

    def describe(self) -> dict[str, Any]:
        return {
            "model": "spring-chain",
            "mesh": str(self.n_nodes),
            "n_steps": self.n_steps,
            "load": self.load,
            "names": list(self.parameters.names),
        }


@dataclass(frozen=True)
class SpringSettings:
    """Settings of the chain.

    Attributes
    ----------
    p
        Number of parameters (stiffness of p equal parts).
    k
        Default true stiffness of each part.
    """

    p: int = 1
    k: float = 50.0


class SpringPlugin:
    @idbench.hookimpl
    def register_scenarios(self, register):
        register(idbench.Scenario("pull", {"force": 1.0}, "pull-hard", "pull"))
        register(idbench.Scenario("pull-hard", {"force": 3.0}, "pull", "harder"))

    @idbench.hookimpl
    def register_models(self, register):
        register(
            "spring-chain",
            SpringChain,
            settings=SpringSettings,
            defaults=idbench.ModelDefaults(
                truth_mesh="200", meshes=("5", "20"), scenarios=("pull",),
                prior=(30.0, 20.0),
            ),
        )  # fmt: skip
