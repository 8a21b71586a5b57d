"""The ``idbench`` command line's parser: options, their types, help, plugins' parts.

:func:`build_parser` builds every subcommand's arguments, adding the models'
shorthand options and the plugins' commands from the registry (built once per
process: :func:`idbench.registry.registry.cached_registry`); a plugin part
that cannot be added is reported in ``idbench plugins``, never fatal.
:mod:`idbench.cli.commands` runs the commands.
"""

from __future__ import annotations

import argparse
import functools
import logging
from pathlib import Path
from typing import Any, NoReturn

from idbench.cli import view
from idbench.cli.values import (
    UsageError,
    add_option_argument,
    assignments,
    names,
    number,
    numbers,
    path,
    toml_value,
)
from idbench.core.sanitize import printable
from idbench.plan.config import ConfigError
from idbench.registry.registry import cached_registry as registry

log = logging.getLogger("idbench")


class _HelpFormatter(argparse.HelpFormatter):
    """Help that shows each option's default and the registered names.

    A default is appended as "(default: X)" unless it is None, False or already
    in the text. ``%(scenarios)s``, ``%(models)s`` and ``%(estimators)s`` in a
    help text become the registered names, ``%(meshes)s`` how each model
    reads a mesh spec (its defaults' ``mesh_help``); the registry is built
    only when help is printed.
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
        if any(f"%({k})" in text for k in ("scenarios", "models", "estimators",
                                             "meshes")):  # fmt: skip
            names = self.registered()
            for kind in ("scenarios", "models", "estimators", "meshes"):
                text = text.replace(f"%({kind})s", names[kind])
            action = argparse.Action(
                action.option_strings, action.dest, default=action.default,
                help=text, choices=action.choices, metavar=action.metavar,
            )  # fmt: skip
        return super()._expand_help(action)

    def _format_text(self, text: str) -> str:
        for kind in ("scenarios", "models", "estimators", "meshes"):
            if f"%({kind})s" in text:
                text = text.replace(f"%({kind})s", self.registered()[kind])
        return super()._format_text(text)

    @classmethod
    def registered(cls) -> dict[str, str]:
        """Registered names, comma-separated, and each model's mesh specs.

        Keys ``scenarios``, ``models``, ``estimators`` and ``meshes``.
        """
        reg = registry()
        meshes = [
            f"{name}: {e.defaults.mesh_help}"
            for name, e in reg.models.items()
            if e.defaults is not None and e.defaults.mesh_help
        ]
        return {
            "scenarios": ", ".join(reg.scenarios),
            "models": ", ".join(reg.models),
            "estimators": ", ".join(reg.estimators),
            "meshes": "; ".join(meshes) or "see idbench info MODEL",
        }


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def format_help(self) -> str:
        """The help, plugins' names and texts among it, as text (no control codes)."""
        return _text(super().format_help())

    def format_usage(self) -> str:
        """The usage line, as text."""
        return _text(super().format_usage())

    def error(self, message: str) -> NoReturn:
        where = "" if self.prog == "idbench" else f"{self.prog}: "
        raise UsageError(f"{where}{message}")


def _text(text: str) -> str:
    """``text`` line by line as visible characters (:func:`printable`)."""
    return "\n".join(printable(line) for line in text.split("\n"))


def _config_default(name: str, config: Any = None) -> str:
    """A CompareConfig field's default as the CLI writes it.

    Of ``config`` (a resolved config: the model and body the command line
    names), else of the default model's.
    """
    from idbench.plan.config import CompareConfig

    if config is None:
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


def build_parser(defaults: Any = None) -> argparse.ArgumentParser:
    """The argument parser of every subcommand.

    ``defaults``: a resolved :class:`~idbench.plan.config.CompareConfig` whose
    values ``compare --help`` shows as the defaults (None: the default
    model's), so that ``compare --help --body kidney`` shows the kidney's.
    """
    from idbench.core.version import __version__

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
    d = functools.partial(_config_default, config=defaults)
    c.add_argument("--config", type=Path, help="TOML file with any of these options")
    c.add_argument(
        "--data",
        type=Path,
        metavar="RECORDING",
        help="observe a recording folder (idbench simulate --record, or your own: "
        "see the README) instead of a simulated truth; it sets the scenario, "
        "steps, observation model, markers and noise",
    )
    c.add_argument(
        "--registration",
        choices=("rigid", "with-model"),
        help="a recording in the camera's frame: its rest cloud registered to each "
        "mesh (rigid, the default), or that pose refined with the model, the pose "
        "and the moduli fitted together on every frame (with-model)",
    )
    c.add_argument(
        "--quick",
        action="store_true",
        help="a small comparison: the model's quick truth and meshes, one seed",
    )
    c.add_argument(
        "--estimators",
        type=names,
        help="comma list of estimators (default: all registered: %(estimators)s)",
    )
    c.add_argument(
        "--meshes",
        type=names,
        help="model mesh specs, comma list: NXxNYxNZ, node count, or mesh file "
        f"(default: {d('meshes')}); per model: %(meshes)s",
    )
    c.add_argument("--truth-mesh", help=f"truth mesh spec (default: {d('truth_mesh')})")
    c.add_argument(
        "--calibration-mesh",
        help="finer mesh the runs of an estimator with correction = "
        '"approximation-error" are calibrated against (default: the truth mesh '
        "spec; the calibration simulates its own paths; more in a TOML "
        "[compare] calibration table)",
    )
    c.add_argument(
        "--scenarios",
        type=names,
        help=f"comma list of %(scenarios)s (default: {d('scenarios')})",
    )
    c.add_argument(
        "--obs-every",
        type=numbers("obs-every", int),
        help=f"observe every k-th step, comma list (default: {d('obs_every')})",
    )
    c.add_argument(
        "--obs-points",
        type=numbers("obs-points", int),
        help=f"marker counts M, comma list (default: {d('obs_points')})",
    )
    c.add_argument(
        "--noise",
        type=numbers("noise"),
        help="noise sigma(s) in the model's length unit (metres for the built-in "
        f"models), comma list (default: {d('noise')})",
    )
    c.add_argument(
        "--observe",
        type=names,
        help="observation models, comma list (a sweep axis): markers, cloud, force, "
        "a [observe.NAME] table's NAME, or blocks joined by + (cloud+force) "
        f"(default: {d('observe')})",
    )
    add_option_argument(
        c,
        "observe",
        "a setting of an observation model, NAME.SETTING=VALUE (repeatable; "
        "e.g. cloud.points=2048, cloud.outliers=0.05)",
    )
    c.add_argument(
        "--seeds",
        type=number("seeds", int),
        help=f"number of noise seeds (default: {d('seeds')}; --quick: 1). Each"
        " summary mean carries a 95%% interval over the seeds (none with one); its"
        " half-width h shrinks as 1/sqrt(n): a seed-to-seed spread s needs"
        " n ~ (t s / h)^2 seeds, and the summary says how many +-1%% on each"
        " x_final needs",
    )
    c.add_argument(
        "--steps",
        type=number("steps", int),
        help=f"load steps K (default: {d('steps')})",
    )
    _add_model_arguments(c, defaults)
    _add_shorthands(c)
    c.add_argument(
        "--prior",
        type=numbers("prior"),
        help=f"prior MEAN,STD of each parameter (default: {d('prior')})",
    )
    c.add_argument(
        "--timeout",
        type=number("timeout"),
        help="seconds per run before it is recorded as failed (default: none)",
    )
    c.add_argument(
        "--posterior",
        action="store_true",
        default=None,
        help="also compute each run's reference posterior (expensive: a grid of "
        "path simulations per data set and mesh; settings in a TOML "
        "[posterior_settings] table)",
    )
    c.add_argument(
        "--out",
        type=path("out"),
        help="results directory (default ./idbench-out; with --quick "
        "./idbench-out-quick)",
    )
    c.add_argument(
        "--jobs", type=number("jobs", int), default=1, help="local worker processes"
    )
    c.add_argument(
        "--wait",
        action="store_true",
        help="if another process is writing --out, wait until it is done "
        "(default: refuse, naming that process)",
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
    r.add_argument(
        "--versus",
        action="append",
        default=[],
        metavar="ESTIMATOR",
        help="also print (and add to the report) each other estimator's paired"
        " difference to ESTIMATOR: runs paired on everything else (seed, mesh,"
        " noise, ...), mean and 95%% interval per row, * where it excludes 0;"
        " repeatable",
    )
    r.add_argument(
        "--versus-mesh",
        action="append",
        default=[],
        metavar="MESH",
        help="the same for meshes: each other mesh minus MESH; repeatable",
    )
    r.add_argument(
        "--wait",
        action="store_true",
        help="if a compare is writing DIR, wait until it is done (default: refuse)",
    )

    i = sub.add_parser(
        "info",
        help="an estimator's, model's or observation's settings and meaning",
        description="Print the settings of a registered estimator, model or "
        "observation kind: name, type, default and one line of meaning. "
        "Estimators: %(estimators)s; models: %(models)s; observations: "
        "markers, cloud, force and the plugins'.",
    )
    i.add_argument(
        "name", help="a registered estimator, model or observation kind (e.g. cloud)"
    )
    i.add_argument("--json", action="store_true", help="machine-readable output")

    s = sub.add_parser(
        "simulate",
        help="simulate a load path and write ParaView files",
        description="Simulate one scenario with the true parameter values and "
        "write the displacement field as an XDMF time series (for ParaView).",
    )
    s.add_argument("--mesh", required=True, help="the model's discretisation")
    s.add_argument("--scenario", required=True, help="one of %(scenarios)s")
    _add_model_arguments(s)
    _add_shorthands(s)
    s.add_argument("--steps", type=number("steps", int), default=20, help="load steps")
    s.add_argument("--out", type=path("out"), help="output .xdmf file")
    s.add_argument(
        "--record",
        type=path("record"),
        metavar="DIR",
        help="write a recording folder (recording.toml + frames.npz) of what the "
        "observation model sees, noise included, for compare --data",
    )
    s.add_argument(
        "--observe", help="observation model of the recording (default: markers)"
    )
    add_option_argument(
        s,
        "observe",
        "a setting of the observation model, NAME.SETTING=VALUE (repeatable)",
    )
    s.add_argument(
        "--noise", type=number("noise"), help="the markers' noise sigma (m)"
    )
    s.add_argument("--obs-points", type=number("obs-points", int), help="markers M")
    s.add_argument(
        "--seed", type=number("seed", int), default=0, help="noise seed (default 0)"
    )
    view.add_parser(sub)
    _add_plugin_commands(sub)
    return parser


BUILTIN_COMMANDS = ("plugins", "compare", "report", "info", "simulate", "view")


def _add_plugin_commands(sub: Any) -> None:
    """Subcommands contributed by plugins; a broken one is reported, not fatal."""
    reg = registry()
    for name, entry in sorted(reg.commands.items()):
        command = entry.obj
        try:
            if name in BUILTIN_COMMANDS:
                raise ValueError(f"command {name!r} is one of idbench's own")
            command.configure(_Parser(prog=f"idbench {name}"))  # a dry run
        except Exception as exc:
            _disable(entry.plugin, f"command {name!r} unusable: {exc!r}")
            continue
        q = sub.add_parser(name, help=f"{command.help} (plugin {entry.plugin})")
        command.configure(q)


def _disable(plugin: str, message: str) -> None:
    """Record a plugin's broken contribution in the registry (``idbench plugins``)."""
    log.warning("plugin %r: %s", plugin, message)
    errors = registry().errors
    errors[plugin] = f"{errors[plugin]}; {message}" if plugin in errors else message


def _add_model_arguments(parser: argparse.ArgumentParser, defaults: Any = None) -> None:
    """``--model``, ``--model-option`` and ``--true`` (compare and simulate)."""
    parser.add_argument(
        "--model",
        help="registered model, one of %(models)s "
        f"(default: {_config_default('model', defaults)})",
    )
    add_option_argument(
        parser,
        "model",
        "a setting of the model, NAME=VALUE (repeatable; 'idbench info MODEL' "
        "lists them)",
    )
    parser.add_argument(
        "--true",
        type=assignments("true"),
        help="true parameter values, NAME=VALUE[,...] (default: the model's)",
    )


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
            try:
                _shorthand(parser, model, option, setting, text)
            except (argparse.ArgumentError, ValueError, TypeError) as exc:
                _disable(entry.plugin, f"shorthand --{option} unusable: {exc}")


def _shorthand(
    parser: argparse.ArgumentParser, model: str, option: str, setting: str, text: str
) -> None:
    """Add ``--option``: a model setting or (``true.NAME``) a true value."""
    if setting.startswith("true."):
        meaning = f"{text} (same as --true {setting[5:]}=VALUE)"
    else:
        meaning = (
            f"{text}: sets the {model} setting {setting!r} "
            f"(same as --model-option {setting}=VALUE)"
        )
    parser.add_argument(
        f"--{option}",
        dest=f"shorthand:{setting}",
        metavar="VALUE",
        type=toml_value,
        help=meaning,
    )


def shorthand_settings(reg: Any) -> dict[str, str]:
    """Every model's shorthand option -> the setting it sets."""
    out: dict[str, str] = {}
    for entry in reg.models.values():
        if entry.defaults:
            for option, (setting, _) in entry.defaults.shorthands.items():
                out.setdefault(option, setting)
    return out


def shorthand_model(args: argparse.Namespace, reg: Any) -> str | None:
    """The model the given shorthand options belong to, when only one has them all.

    So ``--body kidney`` alone picks the model whose shorthand ``--body`` is;
    None when no shorthand is given or several models have them.
    """
    given = {
        key.split(":", 1)[1]
        for key, value in vars(args).items()
        if key.startswith("shorthand:") and value is not None
    }
    if not given:
        return None
    owners = [
        name
        for name, entry in reg.models.items()
        if entry.defaults
        and given <= {setting for setting, _ in entry.defaults.shorthands.values()}
    ]
    return owners[0] if len(owners) == 1 else None


def model_options(args: argparse.Namespace) -> dict[str, Any]:
    """``--model-option`` values and the models' shorthand options, merged.

    A shorthand whose target is ``true.NAME`` goes to ``args.true`` instead.
    """
    given: dict[str, Any] = {}
    for item in getattr(args, "model_options", None) or ():
        given.update(item)
    for key, value in vars(args).items():
        if key.startswith("shorthand:") and value is not None:
            target = key.split(":", 1)[1]
            if target.startswith("true."):
                args.true = {**(args.true or {}), target.removeprefix("true."): value}
            else:
                given[target] = value
    return given


def observe_options(args: argparse.Namespace) -> dict[str, dict[str, Any]] | None:
    """``--observe-option NAME.SETTING=VALUE`` values as ``[observe.NAME]`` tables."""
    out: dict[str, dict[str, Any]] = {}
    for item in getattr(args, "observe_options", None) or ():
        for key, value in item.items():
            name, sep, setting = key.partition(".")
            if not sep or not name or not setting:
                raise UsageError(
                    f"--observe-option {key}={value!r}: need NAME.SETTING=VALUE, "
                    "e.g. cloud.points=2048"
                )
            out.setdefault(name, {})[setting] = value
    return out or None
