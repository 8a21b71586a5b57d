"""The optional members of estimators, estimates, observations, settings, plugins.

A forward model's optional members are protocols
(:mod:`idbench.core.optional`); every other object's are declared here, each
with the default the core takes when the object lacks it and what it means.
:mod:`idbench.core.capabilities` looks them up, and nothing else does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Member:
    """One optional member of an estimator, observation model, settings class, ...

    Attributes
    ----------
    default
        What the core takes when the object lacks it (or has None).
    meaning
        What it says, and who reads it.
    method
        Whether it is a method (a value that is not callable counts as lacking).
    """

    default: Any
    meaning: str
    method: bool = False


ESTIMATOR_OPTIONAL: dict[str, Member] = {
    "abstract": Member(
        False,
        "class attribute (idbench.Filter's class keyword abstract=True): a base "
        "for other estimators, not one itself; it cannot be registered",
    ),
    "reference": Member(
        False,
        "class attribute: True marks the estimator whose fit on a run's data is "
        "that run's reference value (E_ref); one registered estimator has it "
        "(idbench.registry.registry.Registry.reference_estimator)",
    ),
    "by_default": Member(
        True,
        "class attribute: False leaves the estimator out of a comparison that "
        "names none (e.g. estimators meant for parameter fields only)",
    ),
    "handles_nan": Member(
        False,
        "class attribute: True when the estimator takes observations with NaN "
        "(occluded) entries; otherwise such a run is refused in one line "
        "(idbench.observe.occlusion.refusal); idbench.Filter masks them",
    ),
    "seed": Member(
        None,
        "a setting (field) seeding the estimator's own draws; the harness gives "
        "each run its seed unless the user set one",
    ),
    "innovation": Member(
        None,
        "(v, S) after an observed step: the innovation v (m,) of the forecast "
        "and its covariance S (m, m); the traces' nis column is v^T S^-1 v "
        "(an Estimate's own innovation, if it has one, is read first)",
    ),
    "estimate_solves": Member(
        None,
        "estimate_solves(n_state, p, steps) -> int: the forward steps a run is "
        "expected to take (0 for a run start() would skip), for --dry-run and "
        "to start the costliest runs first; default 2 a step",
        method=True,
    ),
    "correction": Member(
        "none",
        'a setting: "approximation-error" hands the estimator the model '
        "corrected by its calibration (an idbench.DiscrepancyModel)",
    ),
    "ensemble": Member(
        None,
        "after the last step: the members (N, n), rows [u (model state), ...]; "
        "the targets' and the grid's predicted covariance is then the "
        "ensemble's (idbench.score.targets)",
    ),
}
"""Each optional member of an estimator (:class:`~idbench.core.interfaces.Estimator`).

:class:`idbench.Filter` gives each its default as a class attribute."""

ESTIMATE_OPTIONAL: dict[str, Member] = {
    "state": Member(
        None,
        "the estimator's own model state at the step, for the shape error "
        "(else one forward solve with the estimate)",
    ),
    "innovation": Member(None, "as the estimator's innovation, for this step"),
}
"""Each optional member of an estimator's answer (an :class:`~idbench.Estimate`)."""

OBSERVATION_OPTIONAL: dict[str, Member] = {
    "needs_theta": Member(
        False,
        "class attribute: True when predict() uses theta itself, not only the "
        "state (force): the prediction is carried in the estimators' state "
        "(idbench.observe.observed_model)",
    ),
    "check": Member(
        None,
        "check(model) -> None: before any run, on each model of the comparison "
        "(truth and model meshes), raise ValueError naming a setting that "
        "cannot work on it (a camera inside the body, or seeing too little of "
        "it); idbench.plan.check refuses the comparison with that line",
        method=True,
    ),
    "linearize": Member(
        None,
        "linearize(model, frame, theta, k, state) -> (H_u, H_theta): dh/du "
        "(m, n) and dh/dtheta (m, p) of predict at the state, for adjoint "
        "gradients (idbench.observe.observed_model.ObservedModel)",
        method=True,
    ),
    "positions": Member(
        None,
        "positions(model, frame, k) -> (m, d): where each predicted value is "
        "(NaN rows: nowhere in particular), for localized estimators",
        method=True,
    ),
}
"""Each optional member of an observation model.

See :class:`~idbench.core.observation_model.ObservationModel`."""

SETTINGS_OPTIONAL: dict[str, Member] = {
    "EXECUTION": Member(
        (),
        "class attribute: names of the settings that change where or how fast "
        "work runs, not its results (idbench.core.settings.execution_names)",
    ),
    "identity": Member(
        None,
        "identity() -> sequence: what of the settings identifies the data "
        "(default: every setting)",
        method=True,
    ),
    "proposed_defaults": Member(
        None,
        "proposed_defaults() -> idbench.ModelDefaults | None: the comparison "
        "these settings propose (idbench.core.settings.proposed_defaults)",
        method=True,
    ),
    "proposed_scenarios": Member(
        None,
        "proposed_scenarios() -> scenarios these settings bring "
        "(idbench.core.settings.proposed_scenarios)",
        method=True,
    ),
}
"""Each optional member of a model's settings class (or of an instance of it)."""

PLUGIN_OPTIONAL: dict[str, Member] = {
    "__version__": Member(
        "",
        "the plugin module's version, where its distribution does not say one",
    ),
}
"""Each optional member of a plugin object (the module an entry point names)."""

PROGRESS_OPTIONAL: dict[str, Member] = {
    "tick": Member(
        None,
        "tick(): called about once a second while workers run, so a display "
        "can move without news",
        method=True,
    ),
}
"""Each optional member of a comparison's ``progress`` callback."""
