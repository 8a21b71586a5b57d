"""Built-in estimator plugin: RO-UKF, UKF, EnKF, ETKF, RLS, LMS, batch LS, fields.

For parameter fields: MAP + Laplace and the localized EnKF and ETKF.
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable

import idbench
from idbench_filters.batch_ls import BatchLs
from idbench_filters.enkf import Enkf
from idbench_filters.etkf import Etkf
from idbench_filters.lms import Lms
from idbench_filters.localized import LocalizedEnkf, LocalizedEtkf
from idbench_filters.map_laplace import MapLaplace
from idbench_filters.rls import Rls
from idbench_filters.ro_ukf import RoUkf
from idbench_filters.ukf import Ukf

__all__ = [
    "BatchLs",
    "Enkf",
    "Etkf",
    "Lms",
    "LocalizedEnkf",
    "LocalizedEtkf",
    "MapLaplace",
    "RoUkf",
    "Rls",
    "Ukf",
    "register_estimators",
    "register_versions",
]


@idbench.hookimpl
def register_estimators(register: Callable[[str, type], None]) -> None:
    """Register the ten estimators (``ro-ukf``, ``enkf``, ``map-laplace``, ...)."""
    register("ro-ukf", RoUkf)
    register("ukf", Ukf)
    register("enkf", Enkf)
    register("etkf", Etkf)
    register("rls", Rls)
    register("lms", Lms)
    register("batch-ls", BatchLs)
    register("map-laplace", MapLaplace)
    register("local-enkf", LocalizedEnkf)
    register("local-etkf", LocalizedEtkf)


@idbench.hookimpl
def register_versions(register: Callable[[str, str], None]) -> None:
    """Report filterpy's version (the full UKF's sigma points come from it)."""
    register("filterpy", importlib.metadata.version("filterpy"))

