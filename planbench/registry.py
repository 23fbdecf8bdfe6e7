"""The plugin registries: entry points found lazily, plus decorators for scripts and tests.

One :class:`Registry` class serves each kind of plugin: planners (:data:`REGISTRY`, entry-point group
``planbench.planners``) and closed-loop controllers (:data:`CONTROLLERS`, group
``planbench.controllers``). A separate package adds one with one line in its ``pyproject.toml``::

    [project.entry-points."planbench.planners"]
    my-planner = "my_package.module:MyPlanner"

    [project.entry-points."planbench.controllers"]
    my-controller = "my_package.module:MyController"

A registry reads entry-point *names* only; a plugin module is imported when it is first used, and a
plugin that fails to import is reported with the reason and an install hint instead of vanishing.
Each spec records the distribution and version it came from. Presets (``family:variant``) work the
same for every kind; messages name the kind. A name is registered once: a second, different plugin
under it is a :class:`~planbench.errors.DuplicatePluginError`. Settings are read by
:mod:`planbench.settings`.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import re
import traceback
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from planbench.errors import DuplicatePluginError, PlanbenchError, PlannerUnavailableError, UnknownNameError
from planbench.settings import PlannerSetup, configure_class

__all__ = [
    "CONTROLLERS",
    "PlannerSpec",
    "PluginSpec",
    "PluginUnavailableError",
    "Registry",
    "REGISTRY",
    "register_planner",
    "register_controller",
    "make_planner",
    "make_controller",
    "get_planner",
    "get_controller",
]

ENTRY_POINT_GROUP = "planbench.planners"
CONTROLLER_GROUP = "planbench.controllers"
NAME_PATTERN = re.compile(r"^[a-z0-9]+(-[a-z0-9]+)*$")

# What to install when a plugin's import fails on a missing module.
INSTALL_HINTS = {
    "ompl": "pip install ompl",
    "qpsolvers": "pip install qpsolvers",
    "osqp": "pip install osqp",
    "coal": "pip install coal",
    "pinocchio": "pip install pin",
    "vamp": 'pip install "planbench[vamp]" (builds vamp-planner from source; docs/planners.md, "VAMP")',
}


class PluginUnavailableError(PlannerUnavailableError):
    """A registered plugin of another kind than a planner (a controller) whose module cannot be
    imported; a :class:`~planbench.errors.PlannerUnavailableError`, so one ``except`` catches both,
    whose message names its kind."""

    def __init__(self, kind: str, name: str, reason: str, hint: str = "") -> None:
        super().__init__(name, reason, hint)
        self.kind = kind
        msg = f"{kind} {name!r} is registered but cannot be loaded: {reason}"
        self.args = (msg + (f" ({hint})" if hint else ""),)


def _unavailable(kind: str, name: str, reason: str, hint: str) -> PlannerUnavailableError:
    if kind == "planner":
        return PlannerUnavailableError(name, reason, hint)
    return PluginUnavailableError(kind, name, reason, hint)


@dataclass
class PlannerSpec:
    """A registered plugin (a planner, or the registry's ``kind``): its name, where its class
    lives, and where it came from."""

    name: str
    entry_point: str  # "module:Attr"
    origin: str  # "entry point" or "decorator"
    distribution: str = ""
    version: str = ""
    loaded: Any = None  # the class, once imported
    error: str = ""  # why it could not be imported
    hint: str = ""  # what to install
    traceback: str = ""  # of an import that raised something else than a missing module
    kind: str = "planner"  # the registry's kind, for messages
    rival: PlannerSpec | None = field(default=None, repr=False)
    """Another registration of this entry point's name: a second installed entry point (loading is
    then a :class:`~planbench.errors.DuplicatePluginError`), or a class registered before this entry
    point was imported that may be the one it names (loading checks that it is)."""
    importing: bool = field(default=False, repr=False)  # its module is being imported (load)

    def load(self) -> type:
        if self.loaded is not None:
            return self.loaded  # type: ignore[no-any-return]
        if self.rival is not None and self.rival.loaded is None:  # two installed plugins, one name
            raise self._claimed_twice(self.rival)
        module_name, _, attr = self.entry_point.partition(":")
        self.importing = True
        try:
            obj: Any = importlib.import_module(module_name)
            for part in attr.split("."):
                obj = getattr(obj, part)
        except ModuleNotFoundError as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            top = (exc.name or "").split(".")[0]
            self.hint = INSTALL_HINTS.get(top, f"pip install {top}" if top else "")
            raise _unavailable(self.kind, self.name, self.error, self.hint) from exc
        except Exception as exc:  # a broken plugin must not take the registry down
            self.error = f"{type(exc).__name__}: {exc}"
            self.hint = "the plugin raised while importing; see the traceback with --verbose"
            self.traceback = traceback.format_exc()
            raise _unavailable(self.kind, self.name, self.error, self.hint) from exc
        finally:
            self.importing = False
        if self.rival is not None:  # a class registered under this name before: the one imported?
            if self.rival.loaded is not obj:
                raise self._claimed_twice(self.rival)
            self.rival = None
        self.loaded = obj
        return obj  # type: ignore[no-any-return]

    @property
    def available(self) -> bool:
        try:
            self.load()
        except (PlannerUnavailableError, DuplicatePluginError):
            return False
        return True

    def _claimed_twice(self, other: PlannerSpec) -> DuplicatePluginError:
        """The error of ``other`` claiming this spec's name (recorded as why it cannot be loaded)."""
        exc = _duplicate(self, other)
        self.error, self.hint = str(exc), ""
        return exc


PluginSpec = PlannerSpec
"""A registered plugin of any kind (the planner registry's historical name is kept)."""


class Registry:
    """Plugin names to specs, for one kind of plugin. ``Registry()`` gives an isolated planner
    registry (tests); :data:`REGISTRY` is the process-wide one the CLI and ``planbench.plan`` use,
    :data:`CONTROLLERS` the closed-loop controllers'.

    ``group``: the entry-point group discovered; ``kind``: the word for one plugin in messages and
    in :class:`~planbench.errors.UnknownNameError` (``"planner"``, ``"controller"``).
    """

    def __init__(self, discover: bool = True, *, group: str = ENTRY_POINT_GROUP, kind: str = "planner") -> None:
        if not kind or not isinstance(kind, str):
            raise ValueError(f"a registry's kind must be a word such as 'planner', got {kind!r}")
        self._specs: dict[str, PlannerSpec] = {}
        self._discover = discover
        self._discovered = False
        self.group = group
        self.kind = kind

    def _ensure_discovered(self) -> None:
        if self._discovered or not self._discover:
            return
        self._discovered = True
        for ep in importlib.metadata.entry_points(group=self.group):
            dist = getattr(ep, "dist", None)
            spec = PlannerSpec(
                ep.name,
                ep.value,
                "entry point",
                distribution=dist.metadata["Name"] if dist else "",
                version=dist.version if dist else "",
                kind=self.kind,
            )
            first = self._specs.setdefault(ep.name, spec)
            if first is not spec and first.entry_point != spec.entry_point and first.rival is None:
                # two installed distributions, one name: the name stays listed and says so when used,
                # so that one bad install does not take `planbench list` (or every other plugin) down
                first.rival = spec

    def register(self, cls: type | str, name: str | None = None) -> PlannerSpec:
        """Register a class (or a ``"module:Attr"`` string) under ``name`` (default: the class's
        ``name``); the spec of that name.

        A name is registered once: registering the same plugin again (the same class, or the same
        ``module:Attr``, as when a module is imported again or a notebook cell runs again) is a no-op
        that keeps the newest class, and so is an entry point's own module registering the class that
        entry point names while it is imported. Another plugin under a taken name is a
        :class:`~planbench.errors.DuplicatePluginError` naming both; tests that need a plugin of
        their own register it into an isolated ``Registry(discover=False)``.
        """
        kind = self.kind
        if isinstance(cls, str):
            if name is None:
                raise ValueError("registering by entry-point string needs a name")
            spec = PlannerSpec(name, cls, "decorator", kind=kind)
        else:
            name = name or getattr(cls, "name", "")
            if not name:
                raise ValueError(f"{cls.__qualname__} has no 'name'; set name = 'my-{kind}' on the class")
            module = getattr(cls, "__module__", "")
            dist, version = _distribution_of(module)
            spec = PlannerSpec(name, f"{module}:{cls.__qualname__}", "decorator", dist, version, loaded=cls, kind=kind)
        if not NAME_PATTERN.match(name):
            raise ValueError(f"{kind} name {name!r} must be kebab-case (lowercase words joined by '-')")
        self._ensure_discovered()  # an installed plugin of that name is a duplicate now, not later
        first = self._specs.setdefault(name, spec)
        if first is spec:
            return spec
        if _same_plugin(first, spec):
            if spec.loaded is not None:
                first.loaded = spec.loaded  # the newest class of a module imported again
            return first
        if first.loaded is None and first.rival is None and (first.importing or _may_be_same(first, spec)):
            first.rival = spec  # e.g. the entry point's package re-exports this class: load() checks it exactly
            return first
        raise _duplicate(first, spec)

    def names(self) -> list[str]:
        self._ensure_discovered()
        return sorted(self._specs)

    def spec(self, name: str) -> PlannerSpec:
        self._ensure_discovered()
        if name not in self._specs:
            raise UnknownNameError(self.kind, name, list(self._specs))
        return self._specs[name]

    def get(self, name: str) -> type:
        """The class registered as ``name`` (imports its module on first use)."""
        return self.spec(name).load()

    def resolve(self, planner: str | type) -> tuple[str, type, dict[str, Any]]:
        """The name, class and implied settings of ``planner``.

        ``planner`` is a planner class, a registered name, ``family:variant``, or a
        ``"module:Attr"`` entry point. ``family:variant`` is planner ``family`` with the settings of
        its preset ``variant`` when the class declares one (``presets = {"paper": {...}}``, e.g.
        ``matrix-field:paper``), else with the setting ``planner="variant"`` (``ompl:AORRTC``: a
        plugin can offer every algorithm of a library by name).
        """
        if isinstance(planner, type):
            return getattr(planner, "name", "") or planner.__qualname__, planner, {}
        family, sep, variant = planner.partition(":")
        if not sep or planner in self.names():
            return planner, self.get(planner), {}
        if family in self.names():
            cls = self.get(family)
            presets = getattr(cls, "presets", None) or {}
            if variant in presets:
                return planner, cls, dict(presets[variant])
            return planner, cls, {"planner": variant}
        return planner, _load_entry_point(planner, self.kind), {}

    def configure(
        self,
        planner: str | type,
        settings: Mapping[str, Any] | None = None,
        *,
        text: Mapping[str, str] | None = None,
    ) -> PlannerSetup:
        """``planner`` (see :meth:`resolve`) with its settings checked and its ``Config`` built: the one
        place where planbench turns settings into a planner (:meth:`make`, ``planbench.plan``, the
        command line, the benchmark's probe and workers, the conformance checker all come here).

        ``settings`` are values (Python, a suite file); ``text`` are values as written on a command
        line (``--set key=value``) and win over ``settings``; both are read by
        :func:`planbench.settings.configure_class` (each parsed to the type its ``Config`` field
        declares; every refusal an :class:`~planbench.errors.InvalidSettingError` naming the planner,
        the setting, the value and what is accepted).
        """
        name, cls, implied = self.resolve(planner)
        return configure_class(name, cls, settings, implied=implied, text=text, kind=self.kind)

    def make(self, planner: str | type, /, **settings: Any) -> Any:
        """An instance of ``planner`` (see :meth:`resolve`) with its ``Config`` built from ``settings``
        (see :meth:`configure`)."""
        return self.configure(planner, settings).build()


def _same_plugin(a: PlannerSpec, b: PlannerSpec) -> bool:
    """Whether two registrations are one plugin: the same class, or the same ``module:Attr``."""
    return (a.loaded is not None and a.loaded is b.loaded) or a.entry_point == b.entry_point


def _may_be_same(entry: PlannerSpec, spec: PlannerSpec) -> bool:
    """Whether ``spec``'s class may be the one the not yet imported entry point ``entry`` names under
    another module path (``pkg:Cls`` re-exporting ``pkg.impl:Cls``): same package, same class name."""
    (a_module, _, a_attr), (b_module, _, b_attr) = entry.entry_point.partition(":"), spec.entry_point.partition(":")
    return a_module.split(".")[0] == b_module.split(".")[0] and a_attr.split(".")[-1] == b_attr.split(".")[-1]


def _source(spec: PlannerSpec) -> str:
    """Where a registration came from, for a message."""
    if spec.origin == "entry point":
        dist = f" of {spec.distribution} {spec.version}".rstrip() if spec.distribution else ""
        return f"entry point {spec.name} = {spec.entry_point}{dist}"
    return f"{spec.entry_point} (registered in this process)"


def _duplicate(first: PlannerSpec, second: PlannerSpec) -> DuplicatePluginError:
    """The error of ``second`` claiming the name of ``first``, with what to do about it."""
    kind = first.kind
    if second.origin == "entry point":
        dists = " or ".join(sorted({f"pip uninstall {s.distribution}" for s in (first, second) if s.distribution}))
        hint = (
            f"One name, one {kind}: uninstall one of the two distributions ({dists or 'pip uninstall'}), "
            "or rename the entry point in one of them."
        )
    else:
        hint = (
            f"One name, one {kind}: give the new class another name (its `name` attribute, or `name=` "
            f"when registering it); a test registers into an isolated planbench.Registry(discover=False)."
        )
    return DuplicatePluginError(kind, first.name, _source(first), _source(second), hint)


def _load_entry_point(planner: str, kind: str = "planner") -> type:
    """The class named by a ``"module:Attr"`` entry point (imports the module)."""
    module_name, _, attr = planner.partition(":")
    try:
        obj: Any = importlib.import_module(module_name)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as exc:
        raise PlanbenchError(f"cannot load {kind} entry point {planner!r}: {type(exc).__name__}: {exc}") from exc
    if not isinstance(obj, type):
        raise PlanbenchError(f"{kind} entry point {planner!r} is a {type(obj).__name__}, not a class")
    return obj


def _distribution_of(module: str) -> tuple[str, str]:
    top = module.split(".")[0]
    for dist_name in importlib.metadata.packages_distributions().get(top, []):
        try:
            return dist_name, importlib.metadata.version(dist_name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return "", ""


REGISTRY = Registry()
"""The planners (entry-point group ``planbench.planners``)."""
CONTROLLERS = Registry(group=CONTROLLER_GROUP, kind="controller")
"""The closed-loop controllers (entry-point group ``planbench.controllers``;
:mod:`planbench.reactive.controller`)."""


def register_planner(cls: type | None = None, *, name: str | None = None, registry: Registry | None = None) -> Any:
    """Class decorator: ``@register_planner`` or ``@register_planner(name="x", registry=r)``."""

    def wrap(c: type) -> type:
        (registry or REGISTRY).register(c, name)
        return c

    return wrap(cls) if cls is not None else wrap


def register_controller(cls: type | None = None, *, name: str | None = None, registry: Registry | None = None) -> Any:
    """Class decorator: ``@register_controller`` or ``@register_controller(name="x", registry=r)``
    (default registry: :data:`CONTROLLERS`)."""
    return register_planner(cls, name=name, registry=registry or CONTROLLERS)


def get_planner(name: str) -> type:
    return REGISTRY.get(name)


def get_controller(name: str) -> type:
    return CONTROLLERS.get(name)


def make_planner(planner: str | type, /, **settings: Any) -> Any:
    """An instance of ``planner`` with ``settings`` (see :meth:`Registry.configure`)."""
    return REGISTRY.make(planner, **settings)


def make_controller(controller: str | type, /, **settings: Any) -> Any:
    """An instance of ``controller`` (a registered name, ``name:preset``, a class or a
    ``"module:Attr"`` entry point) with ``settings`` (see :meth:`Registry.configure`)."""
    return CONTROLLERS.make(controller, **settings)
