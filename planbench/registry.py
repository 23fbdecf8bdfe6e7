"""The planner registry: entry points found lazily, plus a decorator for scripts and tests.

A separate package adds a planner with one line in its ``pyproject.toml``::

    [project.entry-points."planbench.planners"]
    my-planner = "my_package.module:MyPlanner"

The registry reads entry-point *names* only; a plugin module is imported when its planner is first
used, and a plugin that fails to import is reported with the reason and an install hint instead of
vanishing. Each spec records the distribution and version it came from.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import re
import traceback
from dataclasses import dataclass
from typing import Any

from planbench.errors import InvalidConfigError, PlannerUnavailableError, UnknownNameError

__all__ = ["PlannerSpec", "Registry", "REGISTRY", "register_planner", "make_planner", "get_planner"]

ENTRY_POINT_GROUP = "planbench.planners"
NAME_PATTERN = re.compile(r"^[a-z0-9]+(-[a-z0-9]+)*$")

# What to install when a plugin's import fails on a missing module.
INSTALL_HINTS = {
    "ompl": "pip install ompl",
    "qpsolvers": "pip install qpsolvers",
    "osqp": "pip install osqp",
    "coal": "pip install coal",
    "pinocchio": "pip install pin",
}


@dataclass
class PlannerSpec:
    """A registered planner: its name, where its class lives, and where it came from."""

    name: str
    entry_point: str  # "module:Attr"
    origin: str  # "entry point" or "decorator"
    distribution: str = ""
    version: str = ""
    loaded: Any = None  # the class, once imported
    error: str = ""  # why it could not be imported
    hint: str = ""  # what to install
    traceback: str = ""  # of an import that raised something else than a missing module

    def load(self) -> type:
        if self.loaded is not None:
            return self.loaded  # type: ignore[no-any-return]
        module_name, _, attr = self.entry_point.partition(":")
        try:
            obj: Any = importlib.import_module(module_name)
            for part in attr.split("."):
                obj = getattr(obj, part)
        except ModuleNotFoundError as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            top = (exc.name or "").split(".")[0]
            self.hint = INSTALL_HINTS.get(top, f"pip install {top}" if top else "")
            raise PlannerUnavailableError(self.name, self.error, self.hint) from exc
        except Exception as exc:  # a broken plugin must not take the registry down
            self.error = f"{type(exc).__name__}: {exc}"
            self.hint = "the plugin raised while importing; see the traceback with --verbose"
            self.traceback = traceback.format_exc()
            raise PlannerUnavailableError(self.name, self.error, self.hint) from exc
        self.loaded = obj
        return obj  # type: ignore[no-any-return]

    @property
    def available(self) -> bool:
        try:
            self.load()
        except PlannerUnavailableError:
            return False
        return True


class Registry:
    """Planner names to specs. ``Registry()`` gives an isolated one (tests); ``REGISTRY`` is the
    process-wide one the CLI and ``planbench.plan`` use."""

    def __init__(self, discover: bool = True) -> None:
        self._specs: dict[str, PlannerSpec] = {}
        self._discover = discover
        self._discovered = False

    def _ensure_discovered(self) -> None:
        if self._discovered or not self._discover:
            return
        self._discovered = True
        for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
            if ep.name in self._specs:
                continue  # a decorator registration wins over an entry point of the same name
            dist = getattr(ep, "dist", None)
            self._specs[ep.name] = PlannerSpec(
                ep.name,
                ep.value,
                "entry point",
                distribution=dist.metadata["Name"] if dist else "",
                version=dist.version if dist else "",
            )

    def register(self, cls: type | str, name: str | None = None) -> PlannerSpec:
        """Register a planner class (or a ``"module:Attr"`` string) under ``name``."""
        if isinstance(cls, str):
            if name is None:
                raise ValueError("registering by entry-point string needs a name")
            spec = PlannerSpec(name, cls, "decorator")
        else:
            name = name or getattr(cls, "name", "")
            if not name:
                raise ValueError(f"{cls.__qualname__} has no 'name'; set name = 'my-planner' on the class")
            module = getattr(cls, "__module__", "")
            dist, version = _distribution_of(module)
            spec = PlannerSpec(name, f"{module}:{cls.__qualname__}", "decorator", dist, version, loaded=cls)
        if not NAME_PATTERN.match(name):
            raise ValueError(f"planner name {name!r} must be kebab-case (lowercase words joined by '-')")
        self._specs[name] = spec
        return spec

    def unregister(self, name: str) -> None:
        self._specs.pop(name, None)

    def names(self) -> list[str]:
        self._ensure_discovered()
        return sorted(self._specs)

    def spec(self, name: str) -> PlannerSpec:
        self._ensure_discovered()
        if name not in self._specs:
            raise UnknownNameError("planner", name, list(self._specs))
        return self._specs[name]

    def get(self, name: str) -> type:
        """The planner class registered as ``name`` (imports its module on first use)."""
        return self.spec(name).load()

    def make(self, name: str, **config: Any) -> Any:
        """An instance of planner ``name`` with its ``Config`` built from ``config``.

        ``family:variant`` (e.g. ``ompl:AORRTC``) makes planner ``family`` with the setting
        ``planner="variant"``, so a plugin can offer every algorithm of a library by name.
        """
        family, sep, variant = name.partition(":")
        if sep and family in self.names() and name not in self.names():
            return self.make(family, **{"planner": variant, **config})
        cls = self.get(name)
        Config: Any = getattr(cls, "Config", None)
        if Config is not None and dataclasses.is_dataclass(Config):
            allowed = {f.name for f in dataclasses.fields(Config)}
            unknown = set(config) - allowed
            if unknown:
                raise InvalidConfigError(
                    f"planner {name!r} has no setting(s) {sorted(unknown)}; its settings are {sorted(allowed)}"
                )
            try:
                return cls(Config(**config))  # type: ignore[operator]
            except (TypeError, ValueError) as exc:
                raise InvalidConfigError(f"planner {name!r}: {exc}") from exc
        return cls(**config)


def _distribution_of(module: str) -> tuple[str, str]:
    top = module.split(".")[0]
    for dist_name in importlib.metadata.packages_distributions().get(top, []):
        try:
            return dist_name, importlib.metadata.version(dist_name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return "", ""


REGISTRY = Registry()


def register_planner(cls: type | None = None, *, name: str | None = None, registry: Registry | None = None) -> Any:
    """Class decorator: ``@register_planner`` or ``@register_planner(name="x", registry=r)``."""

    def wrap(c: type) -> type:
        (registry or REGISTRY).register(c, name)
        return c

    return wrap(cls) if cls is not None else wrap


def get_planner(name: str) -> type:
    return REGISTRY.get(name)


def make_planner(name: str, **config: Any) -> Any:
    return REGISTRY.make(name, **config)
