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
from typing import Any, NoReturn

from idbench.config import ConfigError

log = logging.getLogger("idbench")


class UsageError(Exception):
    """Bad command-line input; printed as one line, exit status 2."""


class _HelpFormatter(argparse.HelpFormatter):
    """Help that shows each option's default and the registered names.

    A default is appended as "(default: X)" unless it is None, False or already
    in the text. ``%(scenarios)s``, ``%(models)s`` and ``%(estimators)s`` in a
    help text become the registered names; the registry is built only when
    help is printed.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (
            action.option_strings
            and "%(default)" not in text
            and "default" not in text
            and default not in (None, False, argparse.SUPPRESS)
        ):
            text += " (default: %(default)s)"
        return text

    def _expand_help(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "%(scenarios)" in text or "%(models)" in text or "%(estimators)" in text:
            names = self.registered()
            text = text.replace("%(scenarios)s", names["scenarios"])
            text = text.replace("%(models)s", names["models"])
            text = text.replace("%(estimators)s", names["estimators"])
            action = argparse.Action(
                action.option_strings, action.dest, default=action.default,
                help=text, choices=action.choices, metavar=action.metavar,
            )  # fmt: skip
        return super()._expand_help(action)

    def _format_text(self, text: str) -> str:
        for kind in ("scenarios", "models", "estimators"):
            if f"%({kind})s" in text:
                text = text.replace(f"%({kind})s", self.registered()[kind])
        return super()._format_text(text)

    @classmethod
    def registered(cls) -> dict[str, str]:
        """Registered scenario, model and estimator names, comma-separated."""
        reg = registry()
        return {
            "scenarios": ", ".join(reg.scenarios),
            "models": ", ".join(reg.models),
            "estimators": ", ".join(reg.estimators),
        }


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{self.prog}: {message}")


_REGISTRY: list[Any] = []


def registry() -> Any:
    """The plugin registry, built once per process (plugins are imported here)."""
    if not _REGISTRY:
        from idbench.plugins import build_registry

        _REGISTRY.append(build_registry())
    return _REGISTRY[0]


def _config_default(name: str) -> str:
    """A CompareConfig field's default (the default model's) as the CLI writes it."""
    from idbench.config import CompareConfig

    try:
        config = CompareConfig().resolve(registry())
    except ConfigError:
        config = CompareConfig()
    value = getattr(config, name)
    if value is None:
        return "none"
    if isinstance(value, tuple):
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def _value(text: str) -> Any:
    """A setting's value as TOML would read it (number, bool, list), else the text."""
    import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _assignments(name: str) -> Any:
    """Parse ``KEY=VALUE[,KEY=VALUE...]`` into a dict (values as TOML reads them)."""

    def parse(text: str) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for part in _split_top_level(text):
            key, sep, value = part.partition("=")
            if not sep or not key.strip() or not value.strip():
                raise UsageError(f"--{name} {text!r}: need NAME=VALUE[,NAME=VALUE]")
            out[key.strip()] = _value(value.strip())
        return out

    return parse


def _split_top_level(text: str) -> list[str]:
    """Split at commas that are not inside brackets (``grid=[20,4,4],nu=0.3``)."""
    parts, depth, cur = [], 0, ""
    for ch in text:
        depth += (ch in "[{(" and 1) or 0
        depth -= (ch in "]})" and 1) or 0
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    return [p for p in [*parts, cur] if p.strip()]


def _floats(name: str) -> Any:
    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(",") if v.strip())
        except ValueError:
            raise UsageError(
                f"--{name} {text!r}: need comma-separated numbers"
            ) from None
        if not values:
            raise UsageError(f"--{name} {text!r}: need at least one number")
        return values

    return parse


def _ints(name: str) -> Any:
    def parse(text: str) -> tuple[int, ...]:
        try:
            values = tuple(int(v) for v in text.split(",") if v.strip())
        except ValueError:
            raise UsageError(
                f"--{name} {text!r}: need comma-separated whole numbers"
            ) from None
        if not values:
            raise UsageError(f"--{name} {text!r}: need at least one whole number")
        return values

    return parse


def _names(text: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in text.split(",") if v.strip())


def _number(name: str, kind: type = float) -> Any:
    def parse(text: str) -> Any:
        try:
            return kind(text)
        except ValueError:
            what = "a whole number" if kind is int else "a number"
            raise UsageError(f"--{name} {text!r}: need {what}") from None

    return parse


def _path(name: str) -> Any:
    def parse(text: str) -> Path:
        if not text.strip():
            raise UsageError(f"--{name} {text!r}: need a path")
        return Path(text)

    return parse


def _raw_option(argv: list[str], name: str) -> str | None:
    """The text given for option ``name`` (for error messages)."""
    for i, arg in enumerate(argv):
        if arg == name and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(name + "="):
            return arg.split("=", 1)[1]
    return None


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    from idbench import __version__

    parser = _Parser(
        prog="idbench",
        description="Compare parameter estimators on coarse finite-element "
        "soft-body simulations. Run 'idbench COMMAND --help' for a command's "
        "options.",
    )
    parser.add_argument("--version", action="version", version=f"idbench {__version__}")
    sub = parser.add_subparsers(dest="command", parser_class=_Parser)

    p = sub.add_parser("plugins", help="list plugins and what they registered")
    p.add_argument("--json", action="store_true", help="machine-readable output")

    c = sub.add_parser(
        "compare",
        help="run a grid of identification runs",
        description="Run every combination of scenario, mesh, estimator, "
        "sparsity setting and seed; write runs.parquet and traces.parquet into "
        "--out and print a summary. Comma lists become sweep axes. Options not "
        "given come from --config, else from the defaults shown.",
    )
    d = _config_default
    c.add_argument("--config", type=Path, help="TOML file with any of these options")
    c.add_argument(
        "--quick",
        action="store_true",
        help="a small comparison: the model's quick truth and meshes, one seed",
    )
    c.add_argument(
        "--estimators",
        type=_names,
        help="comma list of estimators (default: all registered: %(estimators)s)",
    )
    c.add_argument(
        "--meshes",
        type=_names,
        help="model mesh specs, comma list: NXxNYxNZ, node count, or mesh file "
        f"(default: {d('meshes')})",
    )
    c.add_argument("--truth-mesh", help=f"truth mesh spec (default: {d('truth_mesh')})")
    c.add_argument(
        "--scenarios",
        type=_names,
        help=f"comma list of %(scenarios)s (default: {d('scenarios')})",
    )
    c.add_argument(
        "--obs-every",
        type=_ints("obs-every"),
        help=f"observe every k-th step, comma list (default: {d('obs_every')})",
    )
    c.add_argument(
        "--obs-points",
        type=_ints("obs-points"),
        help=f"marker counts M, comma list (default: {d('obs_points')})",
    )
    c.add_argument(
        "--noise",
        type=_floats("noise"),
        help="noise sigma(s) in the model's length unit (metres for the built-in "
        f"models), comma list (default: {d('noise')})",
    )
    c.add_argument(
        "--seeds",
        type=_number("seeds", int),
        help=f"number of noise seeds (default: {d('seeds')}; --quick: 1)",
    )
    c.add_argument(
        "--steps",
        type=_number("steps", int),
        help=f"load steps K (default: {d('steps')})",
    )
    c.add_argument(
        "--model",
        help=f"registered model, one of %(models)s (default: {d('model')})",
    )
    c.add_argument(
        "--model-option",
        dest="model_options",
        type=_assignments("model-option"),
        action="append",
        help="a setting of the model, NAME=VALUE (repeatable; 'idbench info MODEL' "
        "lists them)",
    )
    c.add_argument(
        "--true",
        type=_assignments("true"),
        help="true parameter values, NAME=VALUE[,...] (default: the model's)",
    )
    _add_shorthands(c)
    c.add_argument(
        "--prior",
        type=_floats("prior"),
        help=f"prior MEAN,STD of each parameter (default: {d('prior')})",
    )
    c.add_argument(
        "--timeout",
        type=_number("timeout"),
        help="seconds per run before it is recorded as failed (default: none)",
    )
    c.add_argument(
        "--out",
        type=_path("out"),
        help="results directory (default ./idbench-out; with --quick "
        "./idbench-out-quick)",
    )
    c.add_argument(
        "--jobs", type=_number("jobs", int), default=1, help="local worker processes"
    )
    c.add_argument(
        "--scheduler",
        help="Dask scheduler address tcp://HOST:PORT (default: none, run locally)",
    )
    c.add_argument(
        "--dry-run",
        action="store_true",
        help="validate, print the run count and a cost estimate",
    )
    c.add_argument(
        "--plot",
        action="store_true",
        help="also write figures, report.md and report.html into --out",
    )
    c.add_argument(
        "--format",
        choices=("table", "markdown", "csv", "json"),
        default="table",
        help="summary format on stdout: table, markdown, csv or json",
    )
    c.add_argument(
        "-v", "--verbose", action="count", default=0,
        help="log more (-v: info, -vv: debug)",
    )  # fmt: skip
    c.add_argument(
        "-q", "--quiet", action="store_true", help="no progress and no summary"
    )

    r = sub.add_parser(
        "report",
        help="figures, report.md and report.html for a compare output",
        description="Write figures (PNG and SVG), report.md and a self-contained "
        "report.html into DIR from its runs.parquet and traces.parquet.",
    )
    r.add_argument("directory", type=Path, help="the --out DIR of idbench compare")

    i = sub.add_parser(
        "info",
        help="an estimator's or model's settings, defaults and meaning",
        description="Print the settings of a registered estimator or model: "
        "name, type, default and one line of meaning. Estimators: "
        "%(estimators)s; models: %(models)s.",
    )
    i.add_argument("name", help="a registered estimator or model name")
    i.add_argument("--json", action="store_true", help="machine-readable output")

    s = sub.add_parser(
        "simulate",
        help="simulate a load path and write ParaView files",
        description="Simulate one scenario with the true parameter values and "
        "write the displacement field as an XDMF time series (for ParaView).",
    )
    s.add_argument("--mesh", required=True, help="the model's discretisation")
    s.add_argument("--scenario", required=True, help="one of %(scenarios)s")
    s.add_argument(
        "--model", help=f"registered model, one of %(models)s (default: {d('model')})"
    )
    s.add_argument(
        "--model-option",
        dest="model_options",
        type=_assignments("model-option"),
        action="append",
        help="a setting of the model, NAME=VALUE (repeatable)",
    )
    s.add_argument(
        "--true",
        type=_assignments("true"),
        help="parameter values, NAME=VALUE[,...] (default: the model's)",
    )
    s.add_argument("--steps", type=_number("steps", int), default=20, help="load steps")
    s.add_argument(
        "--out", type=_path("out"), required=True, help="output .xdmf file"
    )
    for name, entry in sorted(registry().commands.items()):
        command = entry.obj
        q = sub.add_parser(name, help=f"{command.help} (plugin {entry.plugin})")
        command.configure(q)
    return parser


def _add_shorthands(parser: argparse.ArgumentParser) -> None:
    """The models' shorthand options (e.g. the beam's ``--nu``)."""
    seen: set[str] = set()
    for model, entry in registry().models.items():
        for option, (setting, text) in (
            entry.defaults.shorthands.items() if entry.defaults else ()
        ):
            if option in seen:
                continue
            seen.add(option)
            parser.add_argument(
                f"--{option}",
                dest=f"shorthand:{setting}",
                type=_value,
                help=f"{text}: sets the {model} setting {setting!r} "
                f"(same as --model-option {setting}=VALUE)",
            )


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``idbench`` console script.

    Bad input, an unusable output folder or a failed write end in one line on
    stderr and exit status 2; an unexpected error in one line and status 1
    (``--debug`` shows its traceback); Ctrl-C in status 130.
    """
    from idbench.interfaces import ModelFailure
    from idbench.results import ResultsError

    argv = sys.argv[1:] if argv is None else list(argv)
    _REGISTRY.clear()  # plugins may have changed since the last call (tests)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    with contextlib.suppress(Exception):  # stderr may have no file descriptor
        faulthandler.enable()  # a crash in compiled code at least says where
    try:
        args = build_parser().parse_args(argv)
        args.prior_text = _raw_option(argv, "--prior")
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
        }
        if args.command in handlers:
            return handlers[args.command](args)
        try:
            return int(registry().commands[args.command].obj.run(args))
        except ValueError as exc:  # a plugin command's bad input
            raise UsageError(str(exc)) from None
    except (UsageError, ConfigError, ResultsError) as exc:
        return _fail(exc, 2, debug)
    except ModelFailure as exc:
        return _fail(exc, 2, debug, "the simulation failed (check the settings): ")
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


def _fail(
    exc: BaseException, code: int, debug: bool, pre: str = "", post: str = ""
) -> int:
    """Print ``exc`` as one line (with its traceback under --debug); return code."""
    if debug:
        traceback.print_exception(exc)
    text = " ".join(str(exc).split()) or type(exc).__name__
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
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    logging.captureWarnings(True)
    if not (verbose or debug):
        logging.getLogger("py.warnings").setLevel(logging.ERROR)


def cmd_plugins(args: argparse.Namespace) -> int:
    """``idbench plugins``: each plugin, its version, what it registered."""
    from idbench.plugins import build_registry, get_plugin_manager, plugin_version

    pm = get_plugin_manager()
    reg = build_registry(pm)
    rows: list[dict[str, Any]] = []
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
                "error": reg.errors.get(name, ""),
            }
        )
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="idbench plugins")
    for col in ("plugin", "version", "models", "estimators", "scenarios", "error"):
        table.add_column(col)
    for r in rows:
        table.add_row(
            r["name"],
            r["version"],
            ", ".join(r["models"]),
            ", ".join(r["estimators"]),
            ", ".join(r["scenarios"]),
            r["error"],
        )
    Console().print(table)
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """``idbench compare``: run a comparison, write the tables, print a summary."""
    from idbench.config import build_config, load_toml
    from idbench.progress import CompareProgress
    from idbench.report import summary_text
    from idbench.session import Session
    from idbench.sweep import compare, plan

    if args.out is None:
        args.out = Path("idbench-out-quick" if args.quick else "idbench-out")
    reg = registry()
    toml = load_toml(args.config, _shorthand_settings(reg)) if args.config else None
    prior = args.prior
    if prior is not None and len(prior) != 2:
        raise UsageError(f"--prior {args.prior_text!r}: need MEAN,STD")
    config = build_config(
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
        seeds=args.seeds,
        steps=args.steps,
        true=args.true,
        prior=prior,
        timeout=args.timeout,
        model=args.model,
        shorthand_settings=_model_options(args) or None,
    )
    the_plan = plan(config, Session(reg))
    if args.dry_run:
        nodes = ", ".join(f"{m}: {n} nodes" for m, n in the_plan.nodes.items())
        print(
            f"{len(the_plan.runs)} runs; meshes {nodes}; "
            f"about {the_plan.solves} forward solves"
        )
        return 0
    with CompareProgress(
        the_plan.runs, args.out, args.jobs, quiet=args.quiet
    ) as progress:
        runs, _ = compare(
            config,
            args.out,
            jobs=args.jobs,
            scheduler=args.scheduler,
            progress=progress,
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
        from idbench.report import write_report

        for path in write_report(args.out):
            if not args.quiet:
                print(f"wrote {path}", file=say)
    return 0


def _shorthand_settings(reg: Any) -> dict[str, str]:
    """Every model's shorthand option -> the setting it sets."""
    out: dict[str, str] = {}
    for entry in reg.models.values():
        if entry.defaults:
            for option, (setting, _) in entry.defaults.shorthands.items():
                out.setdefault(option, setting)
    return out


def _model_options(args: argparse.Namespace) -> dict[str, Any]:
    """``--model-option`` values and the models' shorthand options, merged."""
    given: dict[str, Any] = {}
    for item in getattr(args, "model_options", None) or ():
        given.update(item)
    for key, value in vars(args).items():
        if key.startswith("shorthand:") and value is not None:
            given[key.split(":", 1)[1]] = value
    return given


def cmd_report(args: argparse.Namespace) -> int:
    """``idbench report DIR``: figures (PNG, SVG), report.md and report.html."""
    from idbench.report import write_report

    try:
        written = write_report(args.directory)
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


def cmd_info(args: argparse.Namespace) -> int:
    """``idbench info NAME``: a registered estimator's or model's settings."""
    from idbench.info import settings, summary_line

    reg = registry()
    obj: Any
    if args.name in reg.estimators:
        kind, obj = "estimator", reg.estimator(args.name)
        plugin = reg.estimators[args.name].plugin
    elif args.name in reg.models:
        kind, obj = "model", reg.models[args.name].settings or reg.model(args.name)
        plugin = reg.models[args.name].plugin
    else:
        known = sorted({*reg.estimators, *reg.models})
        raise UsageError(f"unknown name {args.name!r}; known: {', '.join(known)}")
    rows = settings(obj)
    summary = summary_line(obj)
    if args.json:
        out = {"name": args.name, "kind": kind, "plugin": plugin, "summary": summary}
        print(json.dumps({**out, "settings": rows}, indent=2, default=repr))
        return 0
    print(f"{args.name} ({kind}, plugin {plugin}): {summary}")
    if not rows:
        print("no declared settings")
        return 0
    if kind == "estimator":
        print(f"set in a TOML file as [estimators.{args.name}] NAME = VALUE")
    else:
        print(
            f"set with --model-option NAME=VALUE or in a TOML file as "
            f"[model.{args.name}] NAME = VALUE"
        )
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        print(f"  {r['name']:<{width}}  {r['type']} = {r['default']!r}")
        if r["meaning"]:
            print(f"  {'':<{width}}  {r['meaning']}")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    """``idbench simulate``: one load path, written as an XDMF time series.

    Needs a model that can show its field: ``mesh() -> (points, tets)`` and
    ``displacement_field(state) -> (N, 3)``; its probes are printed per step,
    and its optional ``cell_data() -> {name: (T,) array}`` (e.g. region tags)
    is written with every step.
    """
    import meshio
    import numpy as np

    from idbench.config import CompareConfig
    from idbench.interfaces import ModelSpec
    from idbench.session import model_settings, true_values
    from idbench.truth import simulate_path

    if args.out.is_dir() or args.out.suffix.lower() != ".xdmf":
        raise UsageError(f"--out {str(args.out)!r}: need a file name ending in .xdmf")
    if args.steps < 1:
        raise UsageError(f"--steps {args.steps}: must be >= 1")
    reg = registry()
    model_name = CompareConfig(model=args.model).resolve(reg).model
    assert model_name is not None
    settings = model_settings(reg, model_name, _model_options(args))
    try:
        scenario = reg.scenario(args.scenario)
    except KeyError as exc:
        raise UsageError(str(exc.args[0])) from None
    spec = ModelSpec(args.mesh, scenario, n_steps=args.steps, settings=settings)
    try:
        model = reg.model(model_name)(spec)
    except (ValueError, OSError) as exc:
        raise UsageError(f"--mesh {args.mesh!r}: {exc}") from None
    if not (hasattr(model, "mesh") and hasattr(model, "displacement_field")):
        raise UsageError(
            f"model {model_name!r} has no mesh() and displacement_field(): "
            "it cannot be written for ParaView"
        )
    true = true_values(model.parameters, args.true or {}, model_name)
    states = simulate_path(model, np.array([v for _, v in true]))
    points, tets = model.mesh()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    probes = getattr(model, "probes", None)
    cells = getattr(model, "cell_data", None)
    cell_data = {n: [np.asarray(v)] for n, v in (cells() if cells else {}).items()}
    with meshio.xdmf.TimeSeriesWriter(args.out, data_format="XML") as writer:
        writer.write_points_cells(points, [("tetra", tets)])
        for k, state in enumerate(states, start=1):
            u = model.displacement_field(state)
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
