"""The ``idbench`` command line's parser: options, their types, help, plugins' parts.

:func:`build_parser` builds every subcommand's arguments, adding the models'
shorthand options and the plugins' commands from the registry (built once per
process: :func:`idbench.registry.registry.cached_registry`); a plugin part
that cannot be added is reported in ``idbench plugins``, never fatal.
:mod:`idbench.cli.commands` runs the commands.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any, NoReturn

from idbench.core.sanitize import printable
from idbench.plan.config import ConfigError
from idbench.registry.registry import cached_registry as registry

log = logging.getLogger("idbench")


class UsageError(Exception):
    """Bad command-line input; printed as one line, exit status 2."""


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


def _config_default(name: str) -> str:
    """A CompareConfig field's default (the default model's) as the CLI writes it."""
    from idbench.plan.config import CompareConfig

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


def _add_option_argument(parser: argparse.ArgumentParser, what: str, help: str) -> None:
    """``--WHAT-option NAME=VALUE[,...]``, repeatable, into ``WHAT_options``."""
    parser.add_argument(
        f"--{what}-option",
        dest=f"{what}_options",
        type=_assignments(f"{what}-option"),
        action="append",
        help=help,
    )


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


def _numbers(name: str, kind: type = float) -> Any:
    """Parser of ``--name`` as comma-separated ``kind`` values (at least one)."""
    what = "whole number" if kind is int else "number"

    def parse(text: str) -> tuple[Any, ...]:
        try:
            values = tuple(kind(v) for v in text.split(",") if v.strip())
        except ValueError:
            raise UsageError(
                f"--{name} {text!r}: need comma-separated {what}s"
            ) from None
        if not values:
            raise UsageError(f"--{name} {text!r}: need at least one {what}")
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


def raw_option(argv: list[str], name: str) -> str | None:
    """The text given for option ``name`` (for error messages)."""
    for i, arg in enumerate(argv):
        if arg == name and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(name + "="):
            return arg.split("=", 1)[1]
    return None


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
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
    d = _config_default
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
        type=_names,
        help=f"comma list of %(scenarios)s (default: {d('scenarios')})",
    )
    c.add_argument(
        "--obs-every",
        type=_numbers("obs-every", int),
        help=f"observe every k-th step, comma list (default: {d('obs_every')})",
    )
    c.add_argument(
        "--obs-points",
        type=_numbers("obs-points", int),
        help=f"marker counts M, comma list (default: {d('obs_points')})",
    )
    c.add_argument(
        "--noise",
        type=_numbers("noise"),
        help="noise sigma(s) in the model's length unit (metres for the built-in "
        f"models), comma list (default: {d('noise')})",
    )
    c.add_argument(
        "--observe",
        type=_names,
        help="observation models, comma list (a sweep axis): markers, cloud, force, "
        "a [observe.NAME] table's NAME, or blocks joined by + (cloud+force) "
        f"(default: {d('observe')})",
    )
    _add_option_argument(
        c,
        "observe",
        "a setting of an observation model, NAME.SETTING=VALUE (repeatable; "
        "e.g. cloud.points=2048, cloud.outliers=0.05)",
    )
    c.add_argument(
        "--seeds",
        type=_number("seeds", int),
        help=f"number of noise seeds (default: {d('seeds')}; --quick: 1). Each"
        " summary mean carries a 95%% interval over the seeds (none with one); its"
        " half-width h shrinks as 1/sqrt(n): a seed-to-seed spread s needs"
        " n ~ (t s / h)^2 seeds, and the summary says how many +-1%% on each"
        " x_final needs",
    )
    c.add_argument(
        "--steps",
        type=_number("steps", int),
        help=f"load steps K (default: {d('steps')})",
    )
    _add_model_arguments(c)
    _add_shorthands(c)
    c.add_argument(
        "--prior",
        type=_numbers("prior"),
        help=f"prior MEAN,STD of each parameter (default: {d('prior')})",
    )
    c.add_argument(
        "--timeout",
        type=_number("timeout"),
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
        type=_path("out"),
        help="results directory (default ./idbench-out; with --quick "
        "./idbench-out-quick)",
    )
    c.add_argument(
        "--jobs", type=_number("jobs", int), default=1, help="local worker processes"
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
    _add_model_arguments(s)
    _add_shorthands(s)
    s.add_argument("--steps", type=_number("steps", int), default=20, help="load steps")
    s.add_argument("--out", type=_path("out"), help="output .xdmf file")
    s.add_argument(
        "--record",
        type=_path("record"),
        metavar="DIR",
        help="write a recording folder (recording.toml + frames.npz) of what the "
        "observation model sees, noise included, for compare --data",
    )
    s.add_argument(
        "--observe", help="observation model of the recording (default: markers)"
    )
    _add_option_argument(
        s,
        "observe",
        "a setting of the observation model, NAME.SETTING=VALUE (repeatable)",
    )
    s.add_argument(
        "--noise", type=_number("noise"), help="the markers' noise sigma (m)"
    )
    s.add_argument("--obs-points", type=_number("obs-points", int), help="markers M")
    s.add_argument(
        "--seed", type=_number("seed", int), default=0, help="noise seed (default 0)"
    )
    _add_plugin_commands(sub)
    return parser


BUILTIN_COMMANDS = ("plugins", "compare", "report", "info", "simulate")


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


def _add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """``--model``, ``--model-option`` and ``--true`` (compare and simulate)."""
    parser.add_argument(
        "--model",
        help="registered model, one of %(models)s "
        f"(default: {_config_default('model')})",
    )
    _add_option_argument(
        parser,
        "model",
        "a setting of the model, NAME=VALUE (repeatable; 'idbench info MODEL' "
        "lists them)",
    )
    parser.add_argument(
        "--true",
        type=_assignments("true"),
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
        type=_value,
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
