"""The observation-model protocol and the frames it reads.

An observation model (:class:`ObservationModel`) turns what a sensor delivered
at a load step (a :class:`Frame`) into what an estimator sees and the model
side's prediction of it. The built-in ones and the combination of blocks are
in :mod:`idbench.observe.kinds`; plugins register their own, checked against
the protocol at registration (:mod:`idbench.registry.registry`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from idbench.core.interfaces import FloatArray, ForwardModel


@dataclass(frozen=True)
class Frame:
    """What a sensor delivered at one load step, before any model sees it.

    The same type holds a simulated frame and a recorded one, so both go
    through the same observation model.

    Attributes
    ----------
    step
        Load-step index k (1..K).
    data
        Arrays by name, the observation model's own (``markers`` (3M,) for
        markers, ``points`` (N, 3) and ``origin`` (3,) for a cloud, ``force``
        (c,) for force; ``"BLOCK/NAME"`` in a combination).
    """

    step: int
    data: Mapping[str, FloatArray]


@runtime_checkable
class ObservationModel(Protocol):
    """One way of observing a body: sensing, noise, and the model-side h(x).

    Implementations are frozen dataclasses whose fields are their settings
    (all with defaults); the core builds one per comparison from an
    ``[observe.NAME]`` table. A plugin registers the class
    (``register_observations``), which is checked against this protocol
    then. Optional: a class attribute ``needs_theta`` (default False), True
    when ``predict`` uses theta itself, not only the state (``force``); see
    :data:`idbench.core.members.OBSERVATION_OPTIONAL`.
    """

    requires: tuple[str, ...]
    """Forward-model members it calls (checked before a sweep starts)."""

    def sense(
        self, model: ForwardModel, theta: FloatArray, k: int, state: FloatArray
    ) -> dict[str, FloatArray]:
        """The noise-free reading of the truth (``model`` at ``theta``) at step k."""
        ...

    def measure(
        self, clean: Sequence[Mapping[str, FloatArray]], rng: np.random.Generator,
        noise: float,
    ) -> list[dict[str, FloatArray]]:  # fmt: skip
        """Frame data of every step (K,) from the clean readings, with noise.

        ``rng`` is the run's generator for this observation (common random
        numbers: the same for every estimator and mesh); ``noise`` is the
        run's ``--noise`` sigma (a model may use it or its own setting).
        """
        ...

    def values(self, frame: Frame) -> FloatArray:
        """The observation vector y of a frame, shape (m,); m the same every frame."""
        ...

    def noise_std(self, frame: Frame, noise: float) -> float | FloatArray:
        """Noise std of each value (a float: all the same), for R."""
        ...

    def predict(
        self, model: ForwardModel, frame: Frame, theta: FloatArray, k: int,
        state: FloatArray,
    ) -> FloatArray:  # fmt: skip
        """The prediction h(x) (m,) of ``frame`` for ``model`` at ``state`` (theta)."""
        ...

    def identity(self) -> list[Any]:
        """What the noise draws of this observation depend on (not its sigma)."""
        ...
