"""Write a recording of a simulated comparison (``idbench simulate --record``).

The frames are exactly those a comparison with the same set-up feeds its
estimators (:meth:`idbench.run.session.Session.frames`: the same truth, noise
draws and observation model), so ``compare --data`` on the recording gives
the numbers of the synthetic comparison. Held out: the truth's noise-free
marker displacements, where the model has them its targets, and with a
cloud observed a noise-free cloud of the same camera on the truth (pixels
drawn independently of the frames', so some may coincide with theirs; no
holes, outliers or noise; :func:`held_out_points`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from idbench.observe import kinds
from idbench.observe.cloud import Cloud, clean_points
from idbench.plan.config import CompareConfig, ConfigError
from idbench.registry.registry import Registry, build_registry
from idbench.run.compare import plan, prepare
from idbench.run.session import Session
from idbench.store import recording


def record(
    config: CompareConfig,
    path: str | Path,
    *,
    seed: int = 0,
    registry: Registry | None = None,
) -> Path:
    """Simulate ``config``'s first (scenario, observe, sparsity) on its truth mesh.

    Parameters
    ----------
    config
        The comparison whose data to record: model and options, truth mesh,
        scenario, steps, true values, ``observe`` and its settings, markers
        (``obs_points``) and noise (the first of each axis).
    path
        The recording folder to write.
    seed
        The noise seed (the comparison's ``seed`` column).

    Raises
    ------
    ConfigError
        For a bad set-up (one line).
    """
    if config.data:
        raise ConfigError("simulate --record writes a recording; it reads none")
    session = Session(registry or build_registry())
    truth_mesh = config.truth_mesh or config.resolve(session.registry).truth_mesh
    one = dataclasses.replace(
        config,
        truth_mesh=truth_mesh,
        meshes=(truth_mesh,),  # type: ignore[arg-type]
        scenarios=config.scenarios[:1] if config.scenarios else None,
        observe=config.observe[:1],
        obs_points=config.obs_points[:1],
        noise=config.noise[:1],
        obs_every=(1,),
        seeds=seed + 1,
        estimators=config.estimators[:1] if config.estimators else None,
    )
    the_plan = plan(one, session)
    spec = next(r for r in the_plan.runs if r.seed == seed)
    prepare([spec], session)
    frames = session.frames(spec)
    truth = session.truth(spec)
    held: dict[str, Any] = {"markers": truth.observations}
    if truth.targets is not None:
        held["targets"] = truth.targets
    clouds = [b for _, b in kinds.leaves(session.observation_model(spec))]
    clouds = [b for b in clouds if isinstance(b, Cloud)]
    if clouds:  # a second, noise-free draw of the first cloud's camera
        held["points"] = held_out_points(session, spec, clouds[0], seed)
    setup = spec.setup
    given = the_plan.config.model_settings.get(setup.model, {})
    manifest: dict[str, Any] = {
        "model": setup.model,
        "scenario": spec.scenario,
        "observe": spec.observe,
        "noise": spec.noise,
        "markers": spec.obs_points,
        "steps": setup.steps,
        "held_out": sorted(held),
        "model_settings": {k: v for k, v in given.items() if v is not None},
        "true": {n: float(v) for n, v in setup.true},
    }
    tables = {
        block: {k: list(v) if isinstance(v, tuple) else v for k, v in items}
        for block, items in spec.observe_settings
    }
    if tables:
        manifest["observe_settings"] = {
            block: {k: v for k, v in t.items() if v is not None}
            for block, t in tables.items()
        }
    return recording.write(path, manifest, frames, held)


HELD_OUT_STREAM = 27
"""Seeds the held-out cloud's pixel draws, with the run's seed (not the frames')."""


def held_out_points(session: Session, spec: Any, cloud: Cloud, seed: int) -> Any:
    """(K, N, 3) noise-free points of ``cloud``'s camera on the truth, per step.

    Pixels drawn independently of the frames' (generator seeded by ``seed``
    and :data:`HELD_OUT_STREAM`; some may be pixels a frame also drew), no
    holes, outliers or noise: the truth's surface without the frames' noise,
    for ``heldout_points_mm``.
    """
    truth = session.truth(spec)
    model = session.model(spec, spec.setup.truth_mesh, role="truth")
    theta = session.theta_true(spec)
    rng = np.random.default_rng([seed, HELD_OUT_STREAM])
    rows = []
    for k, state in enumerate(truth.states, start=1):
        clean = cloud.sense(model, theta, k, state)
        rows.append(clean_points(cloud, clean, rng))
    n = max(len(r) for r in rows)
    out = np.full((len(rows), n, 3), np.nan)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
    return out
