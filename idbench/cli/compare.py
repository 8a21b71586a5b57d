"""``idbench compare``: the config of its options, the sweep, its summary.

:func:`compare_config` turns the parsed options (and ``--config``'s TOML) into
a :class:`~idbench.plan.config.CompareConfig`; :func:`cmd_compare` plans it
(the door: :func:`idbench.plan.check.plan`), prints a dry run's runs, skips
and cost, or runs the sweep under the output folder's lock and prints the
summary (and with ``--plot`` writes the report).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

from idbench.cli.parser import (
    model_options,
    observe_options,
    shorthand_model,
    shorthand_settings,
)
from idbench.cli.values import UsageError
from idbench.registry.registry import cached_registry as registry


def compare_config(args: argparse.Namespace, reg: Any) -> Any:
    """The :class:`~idbench.plan.config.CompareConfig` of ``idbench compare``'s args.

    ``--config``'s TOML, then the options given (they win), for ``reg``.
    """
    from idbench.plan.config import build_config, load_toml

    toml = load_toml(args.config, shorthand_settings(reg)) if args.config else None
    prior = args.prior
    if prior is not None and len(prior) != 2:
        raise UsageError(f"--prior {args.prior_text!r}: need MEAN,STD")
    model = args.model or shorthand_model(args, reg)
    options = model_options(args)  # may move a shorthand into args.true
    return build_config(
        quick=args.quick,
        toml=toml,
        registry=reg,
        estimators=args.estimators,
        meshes=args.meshes,
        truth_mesh=args.truth_mesh,
        scenarios=args.scenarios,
        obs_every=args.obs_every,
        obs_points=args.obs_points,
        noise=args.noise,
        observe=args.observe,
        observe_settings=observe_options(args),
        seeds=args.seeds,
        steps=args.steps,
        true=args.true,
        prior=prior,
        timeout=args.timeout,
        posterior=args.posterior,
        calibration=(
            {"mesh": args.calibration_mesh} if args.calibration_mesh else None
        ),
        model=model,
        shorthand_settings=options or None,
        data=str(args.data) if args.data else None,
        registration=args.registration,
    )


def cmd_compare(args: argparse.Namespace) -> int:
    """``idbench compare``: run a comparison, write the tables, print a summary."""
    from idbench.plan.check import plan
    from idbench.run.session import Session
    from idbench.store import lock
    from idbench.store.results import lock_folder

    if args.out is None:
        args.out = Path("idbench-out-quick" if args.quick else "idbench-out")
    reg = registry()
    if args.jobs < 1:
        raise UsageError(f"--jobs {args.jobs}: must be a whole number >= 1")
    config = compare_config(args, reg)
    if args.scheduler and logging.getLogger().getEffectiveLevel() > logging.INFO:
        from idbench.run.executors import quiet_logging

        quiet_logging()  # a lost scheduler is said once, below, not by Dask
    session = Session(reg)
    the_plan = plan(config, session)
    if args.dry_run:
        _dry_run(the_plan, session)
        return 0
    # one hold of the folder's lock over the sweep and its report, taken
    # before the progress bar starts (--wait may wait here)
    lock_folder(args.out, wait=args.wait)
    try:
        return _compare_and_report(args, config, the_plan.runs)
    finally:
        lock.release(args.out)


PROBE_BATCH = 8
"""Parameter/state pairs of the dry run's batched probe."""


def _dry_run(the_plan: Any, session: Any) -> None:
    """Print what a comparison will run, skip and roughly cost (``--dry-run``).

    The cost is the estimators' guessed forward solves times one load step of
    each mesh, timed once here (the second step at the prior mean, warm
    started; a batch of :data:`PROBE_BATCH` where the model steps batches):
    a rough figure, without the truth's simulation and the scoring.
    """
    import collections
    import time

    import numpy as np

    from idbench.core.capabilities import step_many_of
    from idbench.core.sanitize import printable

    nodes = ", ".join(f"{m}: {n} nodes" for m, n in the_plan.nodes.items())
    print(
        f"{len(the_plan.runs)} runs; meshes {nodes}; "
        f"about {the_plan.solves} forward solves"
    )
    seconds: dict[str, float] = {}
    for spec in the_plan.runs:
        if spec.mesh in seconds:
            continue
        model = session.model(spec, spec.mesh)
        theta = np.array(spec.setup.prior[0], dtype=float) * np.ones(
            model.parameters.p
        )
        k = 2 if model.n_steps > 1 else 1
        many = step_many_of(model)
        try:
            first = model.step(theta, 1, model.reset())  # compiles, warms caches
            start = time.perf_counter()
            if many is None:
                model.step(theta, k, first)
                seconds[spec.mesh] = time.perf_counter() - start
            else:  # sigma points: a batch shares its factorizations
                spread = theta * (1 + 0.01 * np.arange(PROBE_BATCH))[:, None]
                many(spread, k, np.tile(first, (PROBE_BATCH, 1)))
                seconds[spec.mesh] = (time.perf_counter() - start) / PROBE_BATCH
        except Exception:  # the run itself will say why
            seconds[spec.mesh] = float("nan")
    total = sum(the_plan.guesses.get(s.run_id, 0) * seconds[s.mesh]
                for s in the_plan.runs)  # fmt: skip
    probe = ", ".join(f"{m}: {1000 * t:.1f} ms" for m, t in seconds.items())
    print(
        f"one forward solve (a probe) {probe}; the runs' forward solves take "
        f"about {total:.0f} s in one process"
    )
    skipped = set(the_plan.skipped)
    if skipped:
        count = collections.Counter(
            (s.estimator, s.mesh) for s in the_plan.runs if s.run_id in skipped
        )
        print(f"{len(skipped)} runs will be skipped by their estimator:")
        for (estimator, mesh), n in sorted(count.items()):
            print(printable(f"  {estimator} on {mesh}: {n} runs"))


def _compare_and_report(args: argparse.Namespace, config: Any, planned: Any) -> int:
    """The sweep of ``cmd_compare``, its summary and (``--plot``) its report."""
    from idbench.cli.progress import CompareProgress
    from idbench.report.write import summary_text
    from idbench.run.compare import compare

    with CompareProgress(planned, args.out, args.jobs, quiet=args.quiet) as progress:
        runs, _ = compare(
            config,
            args.out,
            jobs=args.jobs,
            scheduler=args.scheduler,
            progress=progress,
            wait=args.wait,
        )
    machine = args.format in ("csv", "json")
    say = sys.stderr if machine else sys.stdout
    if not args.quiet or machine:
        width = None
        if args.format == "table" and sys.stdout.isatty():
            import shutil

            width = shutil.get_terminal_size().columns
        print(summary_text(runs, args.format, width=width))
    if not args.quiet:
        print(
            f"wrote {args.out / 'runs.parquet'} and {args.out / 'traces.parquet'}",
            file=say,
        )
    if args.plot:
        from idbench.report.write import write_report

        for path in write_report(args.out, wait=args.wait):
            if not args.quiet:
                print(f"wrote {path}", file=say)
    return 0
