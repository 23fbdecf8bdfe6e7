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
Each spec records the distribution and version it came from. Settings, presets
(``family:variant``) and their errors work the same for every kind; messages name the kind.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import difflib
import enum
import importlib
import importlib.metadata
import json
import math
import numbers
import re
import traceback
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from planbench.errors import (
    InvalidSettingError,
    PlanbenchError,
    PlannerUnavailableError,
    UnknownNameError,
    show_value,
)

__all__ = [
    "CONTROLLERS",
    "PlannerSetup",
    "PlannerSpec",
    "PluginSetup",
    "PluginSpec",
    "PluginUnavailableError",
    "Registry",
    "REGISTRY",
    "coerce_settings",
    "config_types",
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
            raise _unavailable(self.kind, self.name, self.error, self.hint) from exc
        except Exception as exc:  # a broken plugin must not take the registry down
            self.error = f"{type(exc).__name__}: {exc}"
            self.hint = "the plugin raised while importing; see the traceback with --verbose"
            self.traceback = traceback.format_exc()
            raise _unavailable(self.kind, self.name, self.error, self.hint) from exc
        self.loaded = obj
        return obj  # type: ignore[no-any-return]

    @property
    def available(self) -> bool:
        try:
            self.load()
        except PlannerUnavailableError:
            return False
        return True


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
            if ep.name in self._specs:
                continue  # a decorator registration wins over an entry point of the same name
            dist = getattr(ep, "dist", None)
            self._specs[ep.name] = PlannerSpec(
                ep.name,
                ep.value,
                "entry point",
                distribution=dist.metadata["Name"] if dist else "",
                version=dist.version if dist else "",
                kind=self.kind,
            )

    def register(self, cls: type | str, name: str | None = None) -> PlannerSpec:
        """Register a class (or a ``"module:Attr"`` string) under ``name``."""
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
        self._specs[name] = spec
        return spec

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
        line (``--set key=value``) and win over ``settings``. Each is parsed to the type its
        ``Config`` field declares (:func:`coerce_settings`), then ``Config(**settings)`` is built;
        every refusal is an :class:`InvalidSettingError` naming the planner, the setting, the value
        and what is accepted. Building the ``Config`` runs no planner code besides its own checks.
        """
        name, cls, implied = self.resolve(planner)
        Config = config_class(cls)
        given = {**(settings or {}), **(text or {})}
        if Config is None:
            values = {k: _json_or_text(v) if k in (text or {}) else v for k, v in given.items()}
            return PlannerSetup(name, cls, None, {**implied, **values}, values, kind=self.kind)
        try:
            values = coerce_settings(name, Config, {**implied, **(settings or {})}, text=text, kind=self.kind)
            try:
                config = Config(**values)
            except (TypeError, ValueError) as exc:
                raise _refused(name, exc, values, Config) from exc
        except InvalidSettingError as exc:
            _name_kind(exc, self.kind)
            raise
        given_values = {k: v for k, v in values.items() if k in given}
        return PlannerSetup(name, cls, config, values, given_values, kind=self.kind)

    def make(self, planner: str | type, /, **settings: Any) -> Any:
        """An instance of ``planner`` (see :meth:`resolve`) with its ``Config`` built from ``settings``
        (see :meth:`configure`)."""
        return self.configure(planner, settings).build()


@dataclass(frozen=True)
class PlannerSetup:
    """A plugin class (a planner, or the registry's ``kind``) with checked settings, ready to build
    (what :meth:`Registry.configure` gives).

    ``config`` is the class's ``Config`` instance (None for a class without a dataclass
    ``Config``: ``kwargs`` then go to the class as they are); ``settings`` are the settings given,
    parsed to their fields' types (what a benchmark stores and hands to its workers).
    """

    name: str
    cls: type
    config: Any
    kwargs: dict[str, Any]
    settings: dict[str, Any]
    kind: str = "planner"

    def build(self) -> Any:
        """The instance; a ``TypeError`` or ``ValueError`` of its ``__init__`` is an
        :class:`InvalidSettingError`."""
        try:
            return self.cls(self.config) if self.config is not None else self.cls(**self.kwargs)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, InvalidSettingError):
                _name_kind(exc, self.kind)
                raise
            refused = _refused(self.name, exc, self.kwargs, config_class(self.cls))
            raise _name_kind(refused, self.kind) from exc


PluginSetup = PlannerSetup
"""A plugin class with checked settings (the planner registry's historical name is kept)."""


def _name_kind(exc: InvalidSettingError, kind: str) -> InvalidSettingError:
    """``exc`` with its message naming ``kind`` instead of "planner" (``InvalidSettingError``
    words its message for planners; the fields are unchanged)."""
    if kind != "planner":
        text = str(exc)
        lead = f"planner {exc.planner!r}: "
        at = text.find(lead)
        if at >= 0:
            exc.args = (text[:at] + f"{kind} {exc.planner!r}: " + text[at + len(lead) :],)
    return exc


# -- settings parsed to the types of a Config's fields -----------------------------------------------

TRUE_WORDS = ("true", "1", "yes", "on")
FALSE_WORDS = ("false", "0", "no", "off")
NONE_WORDS = ("none", "null")


class _Refused(Exception):
    """One value that does not fit its type; ``expected`` says what would."""

    def __init__(self, expected: str) -> None:
        self.expected = expected
        super().__init__(expected)


def config_class(cls: type) -> Any:
    """The dataclass ``Config`` of planner class ``cls``, or None when it has none."""
    Config = getattr(cls, "Config", None)
    return Config if isinstance(Config, type) and dataclasses.is_dataclass(Config) else None


def config_types(Config: type) -> dict[str, Any]:
    """Each setting (an ``init`` field of the dataclass ``Config``) and its type; a type hint that
    cannot be resolved is ``Any`` (its values are then taken as given)."""
    try:
        hints = typing.get_type_hints(Config)
    except Exception:  # e.g. a name imported only under TYPE_CHECKING: check no type rather than fail
        hints = {}
    return {f.name: hints.get(f.name, Any) for f in dataclasses.fields(Config) if f.init}


def coerce_settings(
    planner: str,
    Config: type,
    settings: Mapping[str, Any],
    *,
    text: Mapping[str, str] | None = None,
    kind: str = "planner",
) -> dict[str, Any]:
    """``settings`` and command-line ``text`` (which wins) parsed to the types of ``Config``'s fields.

    Types: ``float``, ``int``, ``bool`` (``true/false``, ``1/0``, ``yes/no``, ``on/off``), ``str``,
    ``X | None`` (``none`` or ``null`` for None), ``Literal[...]``, ``tuple[X, ...]`` and
    ``list[X]`` (a list, ``[...]`` JSON or ``a,b,c`` text), ``dict`` / ``Mapping`` (JSON text),
    enums; a value of another type (``Any`` included) is taken as given, and command-line text for
    it is read as JSON when it is JSON. Raises :class:`InvalidSettingError` for an unknown setting
    or a value its type cannot take (``kind``: what ``planner`` is, for the message).
    """
    types = config_types(Config)
    out: dict[str, Any] = {}
    given = [(k, v, False) for k, v in settings.items()] + [(k, v, True) for k, v in (text or {}).items()]
    for key, value, is_text in given:
        shown = _json_or_text(value) if is_text else value  # errors show '0.3' typed as 0.3, like Python's 0.3
        if key not in types:
            raise InvalidSettingError(planner, key, shown, _no_such_setting(key, list(types), kind))
        try:
            out[key] = _coerce(types[key], value, is_text)
        except _Refused as refused:
            raise InvalidSettingError(planner, key, shown, refused.expected) from None
    return out


def _no_such_setting(key: str, known: list[str], kind: str = "planner") -> str:
    close = difflib.get_close_matches(key, known, n=3, cutoff=0.6)
    hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
    listing = ", ".join(sorted(known)) if known else "none"
    return f"the {kind} has no such setting{hint} (its settings: {listing})"


def _coerce(hint: Any, value: Any, is_text: bool) -> Any:
    """``value`` as type ``hint`` (``is_text``: as written on a command line); :class:`_Refused`."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is Any or hint is object:
        return _json_or_text(value) if is_text else value
    if origin in (typing.Union, types.UnionType):
        return _coerce_union(args, value, is_text)
    if origin is Literal:
        return _coerce_literal(args, value)
    try:
        if hint is bool:
            return _coerce_bool(value)
        if hint is int:
            return _coerce_int(value)
        if hint is float:
            return _coerce_float(value)
    except _Refused as refused:
        raise _Refused(f"{refused.expected}, got {_kind(_json_or_text(value) if is_text else value)}") from None
    if hint is str:
        if not isinstance(value, str):
            raise _Refused(f"expected text (str), got {_kind(value)}")
        return str(value)
    if hint in (tuple, list) or origin in (tuple, list, collections.abc.Sequence):
        return _coerce_sequence(origin or hint, args, value, is_text)
    if hint is dict or origin in (dict, collections.abc.Mapping):
        return _coerce_mapping(args, value, is_text)
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return _coerce_enum(hint, value)
    return _json_or_text(value) if is_text else value  # a type planbench does not know: as given


def _coerce_union(args: tuple[Any, ...], value: Any, is_text: bool) -> Any:
    if type(None) in args and (value is None or (isinstance(value, str) and value.strip().lower() in NONE_WORDS)):
        return None
    options = [a for a in args if a is not type(None)]
    expected = []
    for option in options:
        try:
            return _coerce(option, value, is_text)
        except _Refused as refused:
            expected.append(refused.expected.partition(", got")[0].removeprefix("expected "))
    if type(None) in args:
        expected.append("none")
    raise _Refused(f"expected {' or '.join(expected)}, got {_kind(value)}")


def _coerce_literal(args: tuple[Any, ...], value: Any) -> Any:
    for option in args:
        if type(option) is type(value) and option == value:
            return option
        if isinstance(value, str) and not isinstance(option, str) and value.strip() == _literal_text(option):
            return option
    raise _Refused(f"expected one of {', '.join(repr(a) for a in args)}")


def _literal_text(option: Any) -> str:
    return str(option).lower() if isinstance(option, bool) else str(option)


def _coerce_bool(value: Any) -> bool:
    if type(value) is bool:
        return value
    if isinstance(value, str) and value.strip().lower() in TRUE_WORDS + FALSE_WORDS:
        return value.strip().lower() in TRUE_WORDS
    if isinstance(value, numbers.Integral) and not isinstance(value, bool) and int(value) in (0, 1):
        return bool(value)
    raise _Refused("expected true or false (bool; also 1/0, yes/no)")


def _coerce_int(value: Any) -> int:
    expected = "expected a whole number (int)"
    if isinstance(value, bool):
        raise _Refused(expected)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, str):
        try:
            return int(value.strip())
        except ValueError:
            try:
                number = float(value.strip())
            except ValueError:
                number = math.nan
            if number.is_integer():
                return int(number)
    raise _Refused(expected)


def _coerce_float(value: Any) -> float:
    expected = "expected a number (float)"
    if isinstance(value, bool):
        raise _Refused(expected)
    if isinstance(value, numbers.Real):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value.strip())
        except ValueError:
            pass
    raise _Refused(expected)


def _coerce_sequence(kind: Any, args: tuple[Any, ...], value: Any, is_text: bool) -> Any:
    items_are_text = False
    if isinstance(value, str):
        stripped = value.strip()
        if stripped.startswith("["):
            try:
                value = json.loads(stripped)
            except ValueError:
                raise _Refused("expected a list: [a, b, ...] as JSON, or a,b,... (the text is not JSON)") from None
        else:
            value = [x.strip() for x in stripped.split(",")] if stripped else []
            items_are_text = True
    if not isinstance(value, (list, tuple)):
        raise _Refused(f"expected a list of values, got {_kind(value)}")
    if kind is not tuple or (args and args[-1] is Ellipsis):
        item = args[0] if args else Any
        out = [_coerce(item, x, items_are_text) for x in value]
    elif args:
        if len(args) != len(value):
            raise _Refused(f"expected {len(args)} values, got {len(value)}")
        out = [_coerce(a, x, items_are_text) for a, x in zip(args, value, strict=True)]
    else:
        out = list(value)
    return tuple(out) if kind is tuple else out


def _coerce_mapping(args: tuple[Any, ...], value: Any, is_text: bool) -> dict[Any, Any]:
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except ValueError:
            raise _Refused('expected a mapping: {"key": value, ...} as JSON') from None
    if not isinstance(value, Mapping):
        raise _Refused(f"expected a mapping (dict), got {_kind(value)}")
    key_type, item_type = args if len(args) == 2 else (Any, Any)
    return {_coerce(key_type, k, False): _coerce(item_type, v, False) for k, v in value.items()}


def _coerce_enum(hint: type[enum.Enum], value: Any) -> Any:
    if isinstance(value, hint):
        return value
    for member in hint:
        if value == member.value or (isinstance(value, str) and value.strip() in (member.name, str(member.value))):
            return member
    raise _Refused(f"expected one of {', '.join(repr(m.value) for m in hint)}")


def _json_or_text(value: Any) -> Any:
    """Command-line text as JSON when it is JSON (``{"a": 1}``, ``[1, 2]``, ``3``), else the text."""
    if not isinstance(value, str):
        return value
    try:
        return json.loads(value)
    except ValueError:
        return value


def _kind(value: Any) -> str:
    """What ``value`` is, for an error message: ``'abc' (str)``."""
    return f"{show_value(value, 40)} ({type(value).__name__})"


def _refused(planner: str, exc: BaseException, values: Mapping[str, Any], Config: Any) -> InvalidSettingError:
    """A ``Config``'s (or planner's) own refusal as an :class:`InvalidSettingError` naming the
    setting its message names (a given one first)."""
    names = [f.name for f in dataclasses.fields(Config)] if dataclasses.is_dataclass(Config) else list(values)
    message = str(exc) or type(exc).__name__
    hits = []
    for name in names:
        found = re.search(rf"(?<![\w]){re.escape(name)}(?![\w])", message)
        if found:
            hits.append((name not in values, found.start(), name))
    if not hits:
        return InvalidSettingError(planner, None, dict(values), message)
    _, _, setting = min(hits)
    value = values[setting] if setting in values else _default(Config, setting)
    return InvalidSettingError(planner, setting, value, message)


def _default(Config: Any, name: str) -> Any:
    for f in dataclasses.fields(Config):
        if f.name == name:
            if f.default is not dataclasses.MISSING:
                return f.default
            if f.default_factory is not dataclasses.MISSING:
                return f.default_factory()
    return None


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
