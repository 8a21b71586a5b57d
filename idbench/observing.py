"""Plan a comparison's observation models: validate them, sense the truth once.

:func:`resolve` checks every ``observe`` value of a comparison before any run
starts (unknown names and settings, and models that lack a member an
observation needs, are one :class:`~idbench.config.ConfigError` line) and
returns the resolved settings the runs carry; :func:`sense` computes, in the
parent process, the noise-free readings the workers then share.
"""

from __future__ import annotations

from typing import Any

from idbench import observe
from idbench.config import CompareConfig, ConfigError
from idbench.interfaces import ForwardModel
from idbench.runspec import Items, RunSpec
from idbench.session import Session


def resolve(
    config: CompareConfig, registry: Any, models: list[ForwardModel]
) -> dict[str, Items]:
    """Each ``config.observe`` name -> its resolved settings per block.

    ``models`` are built models of the comparison (a model mesh and the
    truth): each must have every member the observation models require.

    Raises
    ------
    ConfigError
        Naming the bad value and what is allowed.
    """
    tables = config.observe_settings
    known = observe.kinds(registry)
    used = {b for name in config.observe for b in observe.block_names(name)}
    for table in tables:
        if table not in used and table not in known:
            raise ConfigError(
                f"[observe.{table}] is not used: observe names "
                f"{', '.join(config.observe)}"
            )
    out: dict[str, Items] = {}
    for name in config.observe:
        obs = observe.build(name, tables, registry)
        for member in obs.requires:
            for model in models:
                if not callable(getattr(model, member, None)):
                    raise ConfigError(
                        f"observe {name!r} needs the model's {member}(); model "
                        f"{config.model!r} ({type(model).__name__}) has none"
                    )
        out[name] = observe.settings_items(name, tables, registry)
    return out


def sense(spec: RunSpec, session: Session) -> None:
    """Compute the run's noise-free readings now (a failure is a ConfigError)."""
    obs = session.observation_model(spec)
    for name, block in observe.leaves(obs):
        try:
            session.sensed(spec, block)
        except (ValueError, ArithmeticError) as exc:
            what = name or spec.observe
            raise ConfigError(f"observe {what!r} on the truth: {exc}") from None
