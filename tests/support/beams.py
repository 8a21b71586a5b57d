"""The beam model for tests, by the arguments of the former ``SvkBeam`` class."""

from __future__ import annotations

import warnings
from typing import Any

from idbench_fem.models.beam import SvkBeam
from idbench_fem.models.solid import SolidModel


def beam_model(*args: Any, **kwargs: Any) -> SolidModel:
    """:func:`idbench_fem.models.beam.SvkBeam` without its deprecation warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return SvkBeam(*args, **kwargs)
