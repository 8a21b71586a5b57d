"""What the door refuses about observations, before any run.

The observation models a comparison names, resolved and checked against its
models (:func:`resolve`); no more markers than a model can place
(:func:`check_markers`); an observation that can identify the parameters at
all (:func:`check_observed`). :func:`idbench.plan.check.plan` calls each.
"""

from __future__ import annotations

from typing import Any

from idbench.core.capabilities import (
    inputs_of,
    max_markers_of,
    needs_observed_of,
    observation_check_of,
    requirement_met,
)
from idbench.core.interfaces import ConfigError, ForwardModel
from idbench.observe import kinds
from idbench.plan.config import CompareConfig
from idbench.plan.runspec import Items, RunSpec

__all__ = ["check_markers", "check_observed", "resolve"]


def check_markers(config: CompareConfig, models: dict[str, ForwardModel]) -> None:
    """Refuse more markers than a model can place (before any is allocated).

    See :class:`~idbench.core.optional.MarkerLimitModel`.

    Raises
    ------
    ConfigError
        One line naming the marker count, the mesh and the maximum.
    """
    limits = {mesh: max_markers_of(model) for mesh, model in models.items()}
    known = {mesh: n for mesh, n in limits.items() if n is not None}
    if not known:
        return
    mesh = min(known, key=lambda m: known[m])
    most = known[mesh]
    asked = max(config.obs_points)
    if asked > most:
        raise ConfigError(
            f"obs_points = {asked}: model {config.model!r} on mesh {mesh!r} can "
            f"place at most {most} markers (its candidate points); give "
            f"--obs-points between 1 and {most}"
        )


def check_observed(spec: RunSpec, model: ForwardModel, session: Any) -> None:
    """Refuse a run whose observation cannot identify the model's parameters.

    Its every block uses only members the model says are its input
    (:class:`~idbench.core.optional.InputsModel`: the force of a force-controlled
    load), or it uses none of the members the model needs
    (:class:`~idbench.core.optional.ObservationNeedsModel`: a solid whose tool
    moves by a prescribed displacement needs its ``reaction``, the force).

    Raises
    ------
    ConfigError
        One line naming the scenario and the observations that would do.
    """
    blocks = kinds.leaves(session.observation_model(spec))
    inputs = set(inputs_of(model))
    if inputs and all(set(b.requires) <= inputs for _, b in blocks):
        members = sorted({m for _, b in blocks for m in b.requires})
        raise ConfigError(
            f"scenario {spec.scenario!r}: observe {spec.observe!r} uses only the "
            f"model's {' and '.join(f'{n}()' for n in members)}, which its load "
            "prescribes whatever the parameters (the input, not a measurement): "
            "it cannot identify anything; observe markers or cloud (alone or "
            "with it)"
        )
    needs = needs_observed_of(model)
    if not needs:
        return
    used = {m for _, b in blocks for m in b.requires}
    if used & set(needs):
        return
    would = []
    for kind in sorted(kinds.kinds(session.registry)):
        try:
            block = kinds.build(kind, {}, session.registry)
        except (ConfigError, TypeError, ValueError):  # a kind with required settings
            continue
        if set(block.requires) & set(needs):
            would.append(kind)
    fix = (
        f"add --observe {would[0]} or markers+{would[0]}"
        if would
        else "use an observation model that does"
    )
    raise ConfigError(
        f"scenario {spec.scenario!r}: its parameters are identifiable only if an "
        f"observation uses the model's {' or '.join(f'{n}()' for n in needs)} "
        f"(observe {spec.observe!r} does not: displacements alone do not depend "
        f"on them); {fix}"
    )


def resolve(
    config: CompareConfig, registry: Any, models: list[ForwardModel]
) -> dict[str, Items]:
    """Each ``config.observe`` name -> its resolved settings per block.

    ``models`` are built models of the comparison (a model mesh and the
    truth): each must have every member the observation models require, and
    pass each block's own ``check(model)`` where it has one (a camera that
    sees the body, see :class:`~idbench.observe.cloud.Cloud`; not for a
    recording, whose frames no camera renders). A table named
    after a kind may configure that kind only (not define another).

    Raises
    ------
    ConfigError
        Naming the bad value and what is allowed.
    """
    tables = config.observe_settings
    known = kinds.kinds(registry)
    used = {b for name in config.observe for b in kinds.block_names(name)}
    for table in tables:
        if table not in used and table not in known:
            raise ConfigError(
                f"[observe.{table}] is not used: observe names "
                f"{', '.join(config.observe)}"
            )
        kind = tables[table].get("kind", table)
        if table in known and kind != table:
            raise ConfigError(
                f"[observe.{table}] kind = {kind!r} shadows the observation model "
                f"{table!r}: a table named after a kind configures that kind; "
                f"name the variant otherwise (e.g. [observe.{kind}-variant])"
            )
    out: dict[str, Items] = {}
    for name in config.observe:
        obs = kinds.build(name, tables, registry)
        for member in obs.requires:
            for model in models:
                if not requirement_met(model, member):
                    raise ConfigError(
                        f"observe {name!r} needs the model's {member}(); model "
                        f"{config.model!r} ({type(model).__name__}) has none"
                    )
        for block, leaf in kinds.leaves(obs):
            # a recording's frames are given: no camera renders them (its pose
            # may be in the camera's own frame)
            check = None if config.data is not None else observation_check_of(leaf)
            for model in models:
                try:
                    if check is not None:
                        check(model)
                except ValueError as exc:
                    raise ConfigError(f"observe {block or name!r}: {exc}") from None
        out[name] = kinds.settings_items(name, tables, registry)
    return out
