"""The ``idbench`` command line: a thin layer over the Python API."""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import json
import logging
import os
import sys
import traceback
from pathlib import Path
from typing import Any

from idbench.cli.compare import cmd_compare, compare_config
from idbench.cli.parser import (
    build_parser,
    model_options,
    observe_options,
)
from idbench.cli.values import UsageError, raw_option
from idbench.plan.config import ConfigError
from idbench.registry.registry import cached_registry as registry
from idbench.registry.registry import reset_registry_cache

log = logging.getLogger("idbench")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``idbench`` console script.

    Bad input, an unusable output folder or a failed write end in one line on
    stderr and exit status 2; an unexpected error in one line and status 1
    (``--debug`` shows its traceback); a Dask scheduler lost mid-sweep in one
    line and status 3 (rerun to resume); Ctrl-C in status 130.
    """
    from idbench.core.interfaces import ModelFailure
    from idbench.run.executors import ClusterLost
    from idbench.store.lock import FolderBusy
    from idbench.store.results import ResultsError

    argv = sys.argv[1:] if argv is None else list(argv)
    reset_registry_cache()  # plugins may have changed since the last call (tests)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    with contextlib.suppress(Exception):  # stderr may have no file descriptor
        faulthandler.enable()  # a crash in compiled code at least says where
    try:
        args = build_parser(_help_config(argv)).parse_args(argv)
        args.prior_text = raw_option(argv, "--prior")
        if args.command is None:
            build_parser().print_help()
            return 2
        _logging(getattr(args, "verbose", 0), debug)
        handlers = {
            "report": cmd_report,
            "plugins": cmd_plugins,
            "compare": cmd_compare,
            "simulate": cmd_simulate,
            "info": cmd_info,
            "view": _view,
        }
        if args.command in handlers:
            return handlers[args.command](args)
        try:
            return int(registry().commands[args.command].obj.run(args))
        except ValueError as exc:  # a plugin command's bad input
            raise UsageError(str(exc)) from None
    except (UsageError, ConfigError, ResultsError, FolderBusy) as exc:
        return _fail(exc, 2, debug)
    except ModelFailure as exc:
        return _fail(exc, 2, debug, "the simulation failed (check the settings): ")
    except ClusterLost as exc:  # no bad input, no bug: the cluster went away
        return _fail(exc, 3, debug)
    except OSError as exc:
        if isinstance(exc, BrokenPipeError):  # e.g. `idbench plugins | head`
            _silence_stdout()
            return 0
        return _fail(exc, 2, debug, "cannot read or write a file: ")
    except KeyboardInterrupt:
        print("idbench: interrupted; finished runs are kept", file=sys.stderr)
        return 130
    except Exception as exc:
        return _fail(
            exc, 1, debug, f"unexpected {type(exc).__name__}: ", " (--debug shows more)"
        )


def _help_config(argv: list[str]) -> Any:
    """For ``compare --help`` with a model or body: the config its defaults come from.

    None (the default model's defaults) for any other command line, or when
    the other options cannot be read.
    """
    if not {"-h", "--help"} & set(argv) or "compare" not in argv:
        return None
    rest = [a for a in argv if a not in ("-h", "--help")]
    try:
        args = build_parser().parse_args(rest)
        args.prior_text = raw_option(rest, "--prior")
        if args.command != "compare":
            return None
        return compare_config(args, registry()).resolve(registry())
    except (Exception, SystemExit):
        return None


def _fail(
    exc: BaseException, code: int, debug: bool, pre: str = "", post: str = ""
) -> int:
    """Print ``exc`` as one line (with its traceback under --debug); return code."""
    if debug:
        traceback.print_exception(exc)
    from idbench.core.sanitize import printable

    text = printable(" ".join(str(exc).split()), join_lines=True)
    text = text or type(exc).__name__
    print(f"idbench: error: {pre}{text}{'' if debug else post}", file=sys.stderr)
    return code


def _silence_stdout() -> None:
    """After a broken pipe: send what Python still flushes at exit nowhere."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def _logging(verbose: int, debug: bool) -> None:
    """Log level from -v; Python warnings (e.g. numpy's) only with -v or --debug."""
    level = logging.WARNING
    if verbose or debug:
        level = logging.INFO if verbose == 1 and not debug else logging.DEBUG
    handler = logging.StreamHandler()
    handler.setFormatter(_Printable("%(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=level, handlers=[handler])
    logging.captureWarnings(True)
    if not (verbose or debug):
        logging.getLogger("py.warnings").setLevel(logging.ERROR)


class _Printable(logging.Formatter):
    """Log lines as text: messages from plugins cannot send control sequences."""

    def format(self, record: logging.LogRecord) -> str:
        from idbench.core.sanitize import printable

        return "\n".join(printable(x) for x in super().format(record).split("\n"))


CORE = "idbench (core)"
"""The ``idbench plugins`` row of what the core has built in (observation models)."""


def cmd_plugins(args: argparse.Namespace) -> int:
    """``idbench plugins``: each plugin, its version, what it registered.

    The first row is the core's own (``markers``, ``cloud``, ``force``); every
    row lists its observation models (``register_observations``).
    """
    from idbench.registry.registry import (
        build_registry,
        get_plugin_manager,
        plugin_version,
    )

    pm = get_plugin_manager()
    reg = build_registry(pm)
    for plugin, message in registry().errors.items():  # incl. unusable commands
        reg.errors.setdefault(plugin, message)
        if message not in reg.errors[plugin]:
            reg.errors[plugin] += f"; {message}"
    from idbench.core.version import __version__
    from idbench.observe import kinds

    # the core's own observation models first: no plugin registers them
    rows: list[dict[str, Any]] = [
        {
            "name": CORE,
            "version": __version__,
            "models": [],
            "estimators": [],
            "scenarios": [],
            "observations": sorted(kinds.BUILTIN),
            "error": "",
        }
    ]
    names = [pm.get_name(p) for p in pm.get_plugins()]
    for name in sorted(n for n in names if n) + sorted(set(reg.errors) - set(names)):
        rows.append(
            {
                "name": name,
                "version": plugin_version(pm, name) if name in names else "",
                "models": sorted(k for k, e in reg.models.items() if e.plugin == name),
                "estimators": sorted(
                    k for k, e in reg.estimators.items() if e.plugin == name
                ),
                "scenarios": sorted(
                    k for k, e in reg.scenarios.items() if e.plugin == name
                ),
                "observations": sorted(
                    k for k, e in reg.observations.items() if e.plugin == name
                ),
                "error": reg.errors.get(name, ""),
            }
        )
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    from idbench.core.sanitize import rich_text

    table = Table(title="idbench plugins")
    columns = ("plugin", "version", "models", "estimators", "scenarios")
    for col in (*columns, "observations", "error"):
        table.add_column(col)
    for r in rows:  # plugin strings as text: no markup, no control sequences
        table.add_row(
            rich_text(r["name"]),
            rich_text(r["version"]),
            rich_text(", ".join(r["models"])),
            rich_text(", ".join(r["estimators"])),
            rich_text(", ".join(r["scenarios"])),
            rich_text(", ".join(r["observations"])),
            rich_text(r["error"], join_lines=True),
        )
    Console().print(table)
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    """``idbench report DIR``: figures (PNG, SVG), report.md and report.html.

    With ``--versus`` (``--versus-mesh``): the paired differences against
    that estimator (mesh) first, printed and added to the report.
    """
    from idbench.report.write import write_report

    try:
        paired = _paired(args)
        written = write_report(args.directory, paired=paired, wait=args.wait)
    except FileNotFoundError as exc:
        raise UsageError(str(exc)) from None
    except (OSError, ValueError, KeyError) as exc:  # e.g. not parquet, no columns
        raise UsageError(
            f"{args.directory} does not hold readable idbench results "
            f"({type(exc).__name__}: {exc})"
        ) from None
    for path in written:
        print(f"wrote {path}")
    return 0


def _view(args: argparse.Namespace) -> int:
    """``idbench view DIR``: :func:`idbench.cli.view.cmd_view`, its refusals usage."""
    from idbench.cli.view import ViewError, cmd_view

    try:
        return cmd_view(args)
    except ViewError as exc:
        raise UsageError(str(exc)) from None


def _paired(args: argparse.Namespace) -> list[Any]:
    """The paired tables ``report`` asked for, printed; bad names a UsageError."""
    import pandas as pd

    from idbench.report.paired import paired_differences, paired_text

    wanted = [("estimator", v) for v in args.versus]
    wanted += [("mesh", v) for v in args.versus_mesh]
    if not wanted:
        return []
    path = Path(args.directory) / "runs.parquet"
    if not path.exists():
        raise FileNotFoundError(
            f"{path} not found: is {args.directory} a compare output?"
        )
    runs = pd.read_parquet(path)
    width = None
    if sys.stdout.isatty():
        import shutil

        width = shutil.get_terminal_size().columns
    out = []
    for by, versus in wanted:
        try:
            p = paired_differences(runs, versus, by)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        print(paired_text(p, width), end="\n\n")
        out.append(p)
    return out


def cmd_info(args: argparse.Namespace) -> int:
    """``idbench info NAME``: an estimator's, model's or observation's settings."""
    from idbench.core.sanitize import printable
    from idbench.observe import kinds as observe
    from idbench.registry.info import settings, summary_line

    reg = registry()
    obj: Any
    if args.name in reg.estimators:
        kind, obj = "estimator", reg.estimator(args.name)
        plugin = reg.estimators[args.name].plugin
    elif args.name in reg.models:
        kind, obj = "model", reg.models[args.name].settings or reg.model(args.name)
        plugin = reg.models[args.name].plugin
    elif args.name in observe.kinds(reg):
        kind, obj = "observation", observe.kinds(reg)[args.name]
        entry = reg.observations.get(args.name)
        plugin = entry.plugin if entry is not None else "idbench"
    else:
        known = sorted({*reg.estimators, *reg.models, *observe.kinds(reg)})
        raise UsageError(f"unknown name {args.name!r}; known: {', '.join(known)}")
    rows = settings(obj)
    summary = printable(summary_line(obj), join_lines=True)
    defaults = reg.models[args.name].defaults if kind == "model" else None
    mesh_help = defaults.mesh_help if defaults is not None else ""
    if args.json:
        out = {"name": args.name, "kind": kind, "plugin": plugin, "summary": summary}
        if mesh_help:
            out["mesh_help"] = mesh_help
        print(json.dumps({**out, "settings": rows}, indent=2, default=repr))
        return 0
    print(printable(f"{args.name} ({kind}, plugin {plugin}): {summary}"))
    if mesh_help:
        print(printable(f"mesh specs (--meshes): {mesh_help}"))
    if not rows:
        print("no declared settings")
        return 0
    if kind == "estimator":
        print(f"set in a TOML file as [estimators.{args.name}] NAME = VALUE")
    elif kind == "observation":
        print(
            f"set with --observe-option {args.name}.NAME=VALUE or in a TOML file "
            f"as [observe.{args.name}] NAME = VALUE"
        )
    else:
        print(
            f"set with --model-option NAME=VALUE or in a TOML file as "
            f"[model.{args.name}] NAME = VALUE"
        )
    import shutil
    import textwrap

    width = max(len(printable(r["name"])) for r in rows)
    indent = " " * (width + 4)
    columns = max(shutil.get_terminal_size().columns, width + 44)
    for r in rows:
        name, kind_ = printable(r["name"]), printable(r["type"])
        print(f"  {name:<{width}}  {kind_} = {printable(repr(r['default']))}")
        if r["meaning"]:  # in full, wrapped (never cut)
            meaning = printable(r["meaning"], join_lines=True)
            print(textwrap.fill(meaning, columns - 1, initial_indent=indent,
                                subsequent_indent=indent))  # fmt: skip
    return 0


def _record(args: argparse.Namespace, reg: Any) -> None:
    """``simulate --record DIR``: the recording of one comparison's data."""
    from idbench.plan.config import build_config
    from idbench.run.record import record

    config = build_config(
        registry=reg,
        model=args.model,
        shorthand_settings=model_options(args) or None,
        truth_mesh=args.mesh,
        scenarios=(args.scenario,),
        steps=args.steps,
        true=args.true,
        observe=(args.observe,) if args.observe else None,
        observe_settings=observe_options(args),
        noise=(args.noise,) if args.noise is not None else None,
        obs_points=(args.obs_points,) if args.obs_points is not None else None,
    )
    path = record(config, args.record, seed=args.seed, registry=reg)
    print(f"wrote recording {path} ({args.steps} frames)")


def cmd_simulate(args: argparse.Namespace) -> int:
    """``idbench simulate``: one load path, written as an XDMF time series.

    Needs a model that can show its field: ``mesh() -> (points, tets)`` and
    ``displacement_field(state) -> (N, 3)``; its probes are printed per step,
    and its optional ``cell_data() -> {name: (T,) array}`` (e.g. region tags)
    is written with every step.
    """
    import meshio
    import numpy as np

    from idbench.core.capabilities import cell_data_of, field_model, probes_of
    from idbench.core.interfaces import ModelSpec
    from idbench.core.settings import (
        model_settings,
        proposed_scenarios,
        true_values,
    )
    from idbench.truth.simulate import simulate_path

    if args.out is None and args.record is None:
        raise UsageError("simulate needs --out FILE.xdmf, --record DIR, or both")
    if args.out is not None and (
        args.out.is_dir() or args.out.suffix.lower() != ".xdmf"
    ):
        raise UsageError(f"--out {str(args.out)!r}: need a file name ending in .xdmf")
    if args.steps < 1:
        raise UsageError(f"--steps {args.steps}: must be >= 1")
    reg = registry()
    if args.record is not None:
        _record(args, reg)
        if args.out is None:
            return 0
    try:
        model_name = args.model or reg.default_model()
    except KeyError as exc:
        raise UsageError(str(exc.args[0])) from None
    if model_name not in reg.models:
        raise UsageError(
            f"unknown model {model_name!r}; allowed: {', '.join(sorted(reg.models))}"
        )
    settings = model_settings(reg, model_name, model_options(args))
    own = {sc.name: sc for sc in proposed_scenarios(settings, model_name)}
    try:
        scenario = own.get(args.scenario) or reg.scenario(args.scenario)
    except KeyError as exc:
        raise UsageError(str(exc.args[0])) from None
    spec = ModelSpec(args.mesh, scenario, n_steps=args.steps, settings=settings)
    try:
        model = reg.model(model_name)(spec)
    except (ValueError, OSError) as exc:
        raise UsageError(f"--mesh {args.mesh!r}: {exc}") from None
    field = field_model(model)
    if field is None:
        raise UsageError(
            f"model {model_name!r} has no mesh() and displacement_field(): "
            "it cannot be written for ParaView"
        )
    true = true_values(model.parameters, args.true or {}, model_name)
    states = simulate_path(model, np.array([v for _, v in true]))
    points, tets = field.mesh()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    probes = probes_of(model)
    cells = cell_data_of(model)
    cell_data = {n: [np.asarray(v)] for n, v in (cells() if cells else {}).items()}
    with meshio.xdmf.TimeSeriesWriter(args.out, data_format="XML") as writer:
        writer.write_points_cells(points, [("tetra", tets)])
        for k, state in enumerate(states, start=1):
            u = field.displacement_field(state)
            writer.write_data(
                k / args.steps,
                point_data={"displacement": u},
                cell_data=cell_data or None,
            )
            named = probes(state) if probes else {}
            shown = "  ".join(f"{n} {v: .5g}" for n, v in named.items())
            print(f"step {k:3d}  load {k / args.steps:5.2f}  {shown}".rstrip())
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
