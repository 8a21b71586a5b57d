"""The ``idbench`` command line: a thin layer over the Python API."""

from __future__ import annotations

import argparse
import json
import logging
import sys
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

    _names: dict[str, str] | None = None

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
        if cls._names is None:
            from idbench.plugins import build_registry

            reg = build_registry()
            cls._names = {
                "scenarios": ", ".join(reg.scenarios),
                "models": ", ".join(reg.models),
                "estimators": ", ".join(reg.estimators),
            }
        return cls._names


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{self.prog}: {message}")


def _config_default(name: str) -> str:
    """A CompareConfig field's default as the command line writes it."""
    from idbench.config import CompareConfig

    value = getattr(CompareConfig(), name)
    if isinstance(value, tuple):
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


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
        help="small truth (40x5x5), models 14x3x3,20x4x4, one seed",
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
        help=f"noise sigma(s) in metres, comma list (default: {d('noise')})",
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
        "--E-true",
        dest="E_true",
        type=_number("E-true"),
        help=f"true E in Pa (default: {d('E_true')})",
    )
    c.add_argument(
        "--nu", type=_number("nu"), help=f"Poisson ratio (default: {d('nu')})"
    )
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
        "--out", type=Path, default=Path("idbench-out"), help="results directory"
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

    k = sub.add_parser(
        "calibrate", help="map the effective E of a coarse mesh over load space"
    )
    k.add_argument("--mesh", required=True, help="coarse model mesh spec")
    k.add_argument("--truth-mesh", default="80x11x11", help="truth mesh spec")
    k.add_argument(
        "--angles",
        type=_floats("angles"),
        help="traction directions, degrees from +x (stretch) to -y (bend), 0..90 "
        "(default: 0,0.5,1,2,5,15,45,75,90)",
    )
    k.add_argument(
        "--steps", type=_number("steps", int), default=10, help="load levels"
    )
    k.add_argument(
        "--E-true", dest="E_true", type=_number("E-true"), default=5000.0,
        help="true E (Pa)",
    )  # fmt: skip
    k.add_argument("--nu", type=_number("nu"), default=0.45, help="Poisson ratio")
    k.add_argument("--model", default="svk-beam", help="registered model name")
    k.add_argument(
        "--evaluate",
        type=_names,
        help="held-back scenarios to score (default: mixed-30,mixed-60,bend-z,"
        "stretch-x; 'none' skips)",
    )
    k.add_argument(
        "--evaluate-angles",
        type=_floats("evaluate-angles"),
        default=(3.0, 10.0),
        help="also score ad-hoc paths at these angles (default: 3,10, off the grid)",
    )
    k.add_argument(
        "--seeds", type=_number("seeds", int), default=3, help="RO-UKF seeds"
    )
    k.add_argument(
        "--out",
        type=Path,
        default=Path("idbench-calibration"),
        help="output directory",
    )
    k.add_argument("-q", "--quiet", action="store_true", help="print only errors")

    s = sub.add_parser("simulate", help="simulate a load path and write ParaView files")
    s.add_argument("--mesh", required=True, help="mesh spec")
    s.add_argument("--scenario", required=True, help="scenario name")
    s.add_argument(
        "--E", type=_number("E"), default=5000.0, help="Young's modulus (Pa)"
    )
    s.add_argument("--nu", type=_number("nu"), default=0.45, help="Poisson ratio")
    s.add_argument("--steps", type=_number("steps", int), default=20, help="load steps")
    s.add_argument("--model", default="svk-beam", help="registered model name")
    s.add_argument("--out", type=Path, required=True, help="output .xdmf file")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``idbench`` console script."""
    try:
        args = build_parser().parse_args(argv)
        args.prior_text = _raw_option(sys.argv[1:] if argv is None else argv, "--prior")
        if args.command is None:
            build_parser().print_help()
            return 2
        level = logging.WARNING
        if getattr(args, "verbose", 0):
            level = logging.INFO if args.verbose == 1 else logging.DEBUG
        logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
        handler = {
            "report": cmd_report,
            "plugins": cmd_plugins,
            "compare": cmd_compare,
            "simulate": cmd_simulate,
            "calibrate": cmd_calibrate,
            "info": cmd_info,
        }[args.command]
        return handler(args)
    except (UsageError, ConfigError) as exc:
        print(f"idbench: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("idbench: interrupted; finished runs are kept", file=sys.stderr)
        return 130


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
    from idbench.harness import Session
    from idbench.plugins import build_registry
    from idbench.progress import CompareProgress
    from idbench.report import summary_text
    from idbench.sweep import compare, plan

    toml = load_toml(args.config) if args.config else None
    prior = args.prior
    if prior is not None and len(prior) != 2:
        raise UsageError(f"--prior {args.prior_text!r}: need MEAN,STD")
    config = build_config(
        quick=args.quick,
        toml=toml,
        estimators=args.estimators,
        meshes=args.meshes,
        truth_mesh=args.truth_mesh,
        scenarios=args.scenarios,
        obs_every=args.obs_every,
        obs_points=args.obs_points,
        noise=args.noise,
        seeds=args.seeds,
        steps=args.steps,
        E_true=args.E_true,
        nu=args.nu,
        prior=prior,
        timeout=args.timeout,
    )
    registry = build_registry()
    the_plan = plan(config, Session(registry))
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
            registry=registry,
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


def cmd_report(args: argparse.Namespace) -> int:
    """``idbench report DIR``: figures (PNG, SVG), report.md and report.html."""
    from idbench.report import write_report

    try:
        written = write_report(args.directory)
    except FileNotFoundError as exc:
        raise UsageError(str(exc)) from None
    for path in written:
        print(f"wrote {path}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    """``idbench info NAME``: a registered estimator's or model's settings."""
    from idbench.info import settings, summary_line
    from idbench.plugins import build_registry

    reg = build_registry()
    obj: Any
    if args.name in reg.estimators:
        kind, obj = "estimator", reg.estimator(args.name)
        plugin = reg.estimators[args.name].plugin
    elif args.name in reg.models:
        kind, obj = "model", reg.model(args.name)
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
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        print(f"  {r['name']:<{width}}  {r['type']} = {r['default']!r}")
        if r["meaning"]:
            print(f"  {'':<{width}}  {r['meaning']}")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    """``idbench calibrate``: the E_eff map, its collapse and held-back scores."""
    from rich.console import Console

    from idbench.calibrate import (
        ANGLES,
        HELD_BACK,
        CalibrationSettings,
        calibrate,
        collapse,
        evaluate,
    )
    from idbench.interfaces import ModelFailure
    from idbench.plugins import build_registry

    settings = CalibrationSettings(
        mesh=args.mesh,
        truth_mesh=args.truth_mesh,
        angles=args.angles or ANGLES,
        steps=args.steps,
        E_true=args.E_true,
        nu=args.nu,
        model=args.model,
    )
    scenarios = HELD_BACK if args.evaluate is None else args.evaluate
    if tuple(scenarios) == ("none",):
        scenarios = ()
    if args.seeds < 1:
        raise UsageError(f"--seeds {args.seeds}: must be >= 1")
    for angle in args.evaluate_angles:
        if not 0 <= angle <= 90:
            raise UsageError(f"--evaluate-angles {angle:g}: must be in 0..90")
    registry = build_registry()
    for name, table in (("scenario", registry.scenarios), ("model", registry.models)):
        wanted = scenarios if name == "scenario" else (args.model,)
        for value in wanted:
            if value not in table:
                raise UsageError(
                    f"unknown {name} {value!r}; known: {', '.join(sorted(table))}"
                )
    console = Console(stderr=True)

    def progress(done: int, total: int, angle: float) -> None:
        if not args.quiet:
            console.print(f"calibrated {done}/{total}: {angle:g} deg")

    try:
        result = calibrate(settings, registry, progress)
    except (ValueError, OSError) as exc:
        raise UsageError(str(exc)) from None
    except ModelFailure as exc:
        print(f"idbench: calibration failed: {exc}", file=sys.stderr)
        return 1
    written = result.save(args.out)
    fit = collapse(result)
    fit.to_csv(args.out / "collapse.csv", index=False)
    written.append(args.out / "collapse.csv")
    if scenarios:
        paths = [*scenarios, *(result.manipulation(a) for a in args.evaluate_angles)]
        try:
            scores = evaluate(
                result, paths, seeds=args.seeds, registry=registry,
                out=args.out / "ro-ukf",
            )  # fmt: skip
        except ModelFailure as exc:
            print(f"idbench: evaluation failed: {exc}", file=sys.stderr)
            return 1
        scores.to_parquet(args.out / "evaluation.parquet", index=False)
        scores.to_csv(args.out / "evaluation.csv", index=False)
        written += [args.out / "evaluation.parquet", args.out / "evaluation.csv"]
    if not args.quiet:
        wide = result.table.pivot(index="fraction", columns="angle", values="ratio")
        print("E_eff / E_true by load fraction (rows) and angle in degrees (columns)")
        print(wide.round(3).to_string())
        print(fit.round(4).to_string(index=False))
        if scenarios:
            print(scores.round(6).to_string(index=False))
        for path in written:
            print(f"wrote {path}")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    """``idbench simulate``: one load path, written as an XDMF time series."""
    import meshio
    import numpy as np

    from idbench.interfaces import ModelSpec
    from idbench.plugins import build_registry
    from idbench.truth import simulate_path

    if args.steps < 1:
        raise UsageError(f"--steps {args.steps}: must be >= 1")
    if not 0 < args.E:
        raise UsageError(f"--E {args.E}: must be > 0")
    if not -1 < args.nu < 0.5:
        raise UsageError(f"--nu {args.nu}: must be in (-1, 0.5)")
    reg = build_registry()
    try:
        scenario = reg.scenario(args.scenario)
        factory = reg.model(args.model)
    except KeyError as exc:
        raise UsageError(str(exc.args[0])) from None
    spec = ModelSpec(mesh=args.mesh, scenario=scenario, n_steps=args.steps, nu=args.nu)
    try:
        model = factory(spec)
    except (ValueError, OSError) as exc:
        raise UsageError(f"--mesh {args.mesh!r}: {exc}") from None
    theta = np.full(model.parameters.p, args.E)
    states = simulate_path(model, theta)
    points, tets = model.mesh()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with meshio.xdmf.TimeSeriesWriter(args.out, data_format="XML") as writer:
        writer.write_points_cells(points, [("tetra", tets)])
        for k, state in enumerate(states, start=1):
            u = model.displacement_field(state)
            writer.write_data(k / args.steps, point_data={"displacement": u})
            tip = model.tip(state)
            print(
                f"step {k:3d}  load {k / args.steps:5.2f}  tip displacement "
                f"{tip[0]: .5f} {tip[1]: .5f} {tip[2]: .5f} m"
            )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
