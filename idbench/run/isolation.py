"""Each run gets a model no other run can corrupt, and is checked after it.

A :class:`~idbench.run.session.Session` builds every model once and keeps it (the
*master*: building one, its sparse pattern and its first factorization cost
as much as a short run). A run never gets the master: it gets
:func:`private_copy`, ``copy.copy`` of it. What a run's plugin assigns to its
copy (``model.n_steps = 3``, ``model.parameters = ...``) stays in that copy,
and a model's run caches start from the master's unused state, so a run's
numbers depend on the run only. A model whose shallow copy would share state
its runs write (a factorization cache, a counter) defines ``__copy__`` to give
the copy its own; arrays a copy shares with its master should be read-only,
so that writing into them raises in the plugin that tries (its run fails,
naming it).

:func:`fingerprint` is what a run must leave unchanged: the model's
``n_steps``, its parameter spec, its ``describe()`` and the contents of the
arrays held directly by it. The harness compares the copy's and the master's
with the master's fingerprint when it was built; a change fails the run,
naming its estimator (:func:`changes` says what changed), and a changed
master is discarded, so later runs get a model built anew.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from idbench.core.interfaces import ForwardModel
from idbench.store.files import digest, stable_hash


def private_copy(model: ForwardModel) -> ForwardModel:
    """The model a run works with: ``copy.copy(model)`` (its ``__copy__``)."""
    return copy.copy(model)


def fingerprint(model: ForwardModel) -> dict[str, str]:
    """What a run must leave unchanged, by part: a digest each.

    ``n_steps``, ``parameters`` (names, bounds, defaults), ``describe`` and
    one entry per array held directly by the model (``array <name>``: dtype,
    shape and contents). Arrays held deeper (in a model's own helpers) are the
    model's to protect (read-only), as are its caches.
    """
    spec = model.parameters
    default = None if spec.default is None else list(spec.default)
    out = {
        "n_steps": repr(_n_steps(model)),
        "parameters": stable_hash(
            [list(spec.names), list(spec.lower), list(spec.upper), default]
        ),
        "describe": stable_hash(model.describe()),
    }
    for name, value in sorted(_attributes(model).items()):
        if isinstance(value, np.ndarray):
            out[f"array {name}"] = digest(value)
    return out


def changes(before: dict[str, str], after: dict[str, str]) -> list[str]:
    """The parts of ``before`` that ``after`` lacks or has otherwise (sorted).

    An array ``after`` has in addition is not a change: a model may add
    caches as it works (computed on first use).
    """
    return sorted(k for k in before if before[k] != after.get(k))


def _n_steps(model: Any) -> Any:
    """``model.n_steps``, or None if a run deleted it (a change too)."""
    try:
        return model.n_steps
    except AttributeError:
        return None


def _attributes(model: Any) -> dict[str, Any]:
    try:
        return dict(vars(model))
    except TypeError:  # __slots__ or a C type: nothing we can see
        return {}
