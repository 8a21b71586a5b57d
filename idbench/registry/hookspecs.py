"""Hook specifications: what a plugin may contribute.

Every hook receives a ``register`` callback owned by the core. The core checks
each registration, rejects duplicate names (naming both plugins) and keeps the
registry, so plugins never see each other.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pluggy

hookspec = pluggy.HookspecMarker("idbench")


@hookspec
def register_models(register: Callable[..., None]) -> None:
    """Register forward-model factories.

    Call ``register(name, factory, settings=Settings, defaults=ModelDefaults(...))``
    once per model, where ``factory(spec)`` takes an :class:`idbench.ModelSpec`
    and returns an object implementing :class:`idbench.ForwardModel` (and
    optionally ``sensitivity``, ``probes``, ``n_nodes``, ``bounds``,
    ``volume``). ``settings`` is the dataclass of the model's own settings (all
    fields with defaults; set with ``--model-option NAME=VALUE`` or
    ``[model.NAME]`` in TOML), ``defaults`` what a comparison uses when the user
    does not say (:class:`idbench.ModelDefaults`); both optional. A settings
    object may define ``proposed_defaults()`` (a ModelDefaults or None,
    replacing ``defaults`` for those settings) and ``proposed_scenarios()``
    (Scenarios that exist for those settings only; see
    :func:`idbench.core.settings.proposed_scenarios`).

    Parameters
    ----------
    register
        ``register(name, factory, *, settings=None, defaults=None)``.

    Examples
    --------
    A model whose settings are one stiffness, with its defaults
    (``make_chain(spec)`` returns the :class:`idbench.ForwardModel`; the
    tutorial "A model plugin" writes one):

    >>> from dataclasses import dataclass
    >>> import idbench
    >>> @dataclass(frozen=True)
    ... class ChainSettings:
    ...     k: float = 50.0
    >>> @idbench.hookimpl
    ... def register_models(register):
    ...     register("spring-chain", make_chain, settings=ChainSettings,
    ...              defaults=idbench.ModelDefaults(truth_mesh="200",
    ...                                             meshes=("5", "20")))
    """


@hookspec
def register_estimators(register: Callable[[str, type], None]) -> None:
    """Register estimator classes.

    Call ``register(name, cls)`` once per estimator, where ``cls`` is a
    dataclass whose fields are the estimator's settings (all with defaults) and
    whose instances implement :class:`idbench.Estimator`. Building on
    :class:`idbench.Filter` gives the run and step checks, the cost, the
    transforms and occluded observations for free: the class then writes only
    ``begin`` and ``assimilate`` (checked when the class is defined). A class
    whose settings are no dataclass fields (one of its classes not decorated
    with ``@dataclass``), or an abstract base (``abstract=True``), disables
    its plugin when it registers.

    Parameters
    ----------
    register
        ``register(name, cls)``.

    Examples
    --------
    An estimator that keeps its prior (the tutorial "An estimator plugin"
    writes a recursive least squares):

    >>> from dataclasses import dataclass
    >>> import idbench
    >>> @dataclass
    ... class PriorOnly(idbench.Filter):
    ...     def begin(self, model, prior):
    ...         self.xi, self.P = self.prior_xi(prior)
    ...     def assimilate(self, k, observation):
    ...         return idbench.Analysis(self.xi, self.P)
    >>> @idbench.hookimpl
    ... def register_estimators(register):
    ...     register("prior-only", PriorOnly)
    """


@hookspec
def register_scenarios(register: Callable[[Any], None]) -> None:
    """Register load paths.

    Call ``register(scenario)`` once per :class:`idbench.Scenario`; its
    ``name`` is the registry key. Its ``load`` is a JSON-able dict that only
    the model interprets; its ``transfer`` names the registered scenario on
    which the transfer error is scored (checked when a comparison is planned).

    Parameters
    ----------
    register
        ``register(scenario)``.

    Examples
    --------
    >>> import idbench
    >>> @idbench.hookimpl
    ... def register_scenarios(register):
    ...     register(idbench.Scenario("pull", {"force": 1.0}, transfer="pull-hard",
    ...                               description="end force 1 N"))
    ...     register(idbench.Scenario("pull-hard", {"force": 3.0}, transfer="pull"))
    """


@hookspec
def register_commands(register: Callable[[str, Any], None]) -> None:
    """Register ``idbench`` subcommands.

    Call ``register(name, idbench.Command(help, configure, run))`` once per
    command: ``configure(parser)`` adds its arguments, ``run(args)`` executes
    it and returns the exit status. Tools that only make sense for one model
    (the beam's ``calibrate``) live in its plugin this way. A command or
    option that clashes with idbench's own is disabled and reported in
    ``idbench plugins``.

    Parameters
    ----------
    register
        ``register(name, command)``, ``command`` an :class:`idbench.Command`.

    Examples
    --------
    ``idbench hello --name X`` (raise :class:`idbench.ConfigError` for bad
    input: one line, exit status 2):

    >>> import idbench
    >>> def configure(parser):
    ...     parser.add_argument("--name", default="world")
    >>> def run(args):
    ...     print(f"hello, {args.name}")
    ...     return 0
    >>> @idbench.hookimpl
    ... def register_commands(register):
    ...     register("hello", idbench.Command("say hello", configure, run))
    """


@hookspec
def register_observations(register: Callable[[str, type], None]) -> None:
    """Register observation models (what a sensor makes of the body).

    Call ``register(name, cls)`` once per observation model, where ``cls`` is
    a frozen dataclass whose fields are its settings (all with defaults;
    ``[observe.NAME]`` in TOML, ``--observe-option NAME.SETTING=VALUE``) and
    whose instances implement :class:`idbench.ObservationModel`
    (``requires``, ``sense``, ``measure``, ``values``, ``noise_std``,
    ``predict``, ``identity``), checked when it registers. The core's own,
    ``markers``, ``cloud`` and ``force``, cannot be replaced.

    Parameters
    ----------
    register
        ``register(name, cls)``.

    Examples
    --------
    A sketch: a strain gauge whose settings are its noise (N); the methods
    are those of :class:`idbench.ObservationModel`, as the
    core's ``force`` implements them:

    >>> from dataclasses import dataclass
    >>> import idbench
    >>> @dataclass(frozen=True)
    ... class Gauge:
    ...     noise: float = 0.01
    ...     # requires, sense, measure, values, noise_std, predict, identity
    >>> @idbench.hookimpl
    ... def register_observations(register):
    ...     register("gauge", Gauge)
    """


@hookspec
def register_versions(register: Callable[[str, str], None]) -> None:
    """Report the versions a plugin's results depend on.

    Call ``register(package, version)`` once per package whose version can
    change the numbers the plugin's models or estimators produce (the plugin's
    libraries: a finite-element library, a sparse solver, a filter library).
    A results folder's manifest records them beside the core's own, so the
    core never names a plugin's packages. The plugin's own distribution
    version is recorded without this hook.

    Parameters
    ----------
    register
        ``register(package, version)``, both strings.

    Examples
    --------
    A plugin whose numbers depend on filterpy (as the built-in filters do):

    >>> import importlib.metadata
    >>> import idbench
    >>> @idbench.hookimpl
    ... def register_versions(register):
    ...     register("filterpy", importlib.metadata.version("filterpy"))
    """

