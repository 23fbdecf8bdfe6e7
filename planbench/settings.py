"""A plugin's settings from text and values: ``--set key=value`` text read, every value parsed to the
type its ``Config`` field declares, the ``Config`` built, and every refusal an
:class:`~planbench.errors.InvalidSettingError` that names the plugin, the setting, the value and what is
accepted.

The registries (:mod:`planbench.registry`) find a plugin's class by name; this module is what turns
user values into that class's settings, for every kind of plugin alike (messages name the kind). It
imports no registry (the registries import it), and the benchmark's commands read ``--set`` here
rather than through :mod:`planbench.cli`.
"""

from __future__ import annotations

import argparse
import collections.abc
import dataclasses
import difflib
import enum
import json
import math
import numbers
import re
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from planbench.errors import InvalidSettingError, PlanbenchError, show_value

__all__ = [
    "PlannerSetup",
    "PluginSetup",
    "coerce_settings",
    "config_class",
    "config_types",
    "configure_class",
    "parse_setting",
    "settings_text",
]


# -- settings as written on a command line ------------------------------------------------------------


def parse_setting(text: str) -> tuple[str, str]:
    """``key=value`` as the key and the value's text: the plugin's ``Config`` says what the text
    means (``gain=2.5`` a float, ``timed=false`` a bool, ``params={"range": 0.3}`` JSON), see
    :func:`configure_class`. An argparse ``type``: a malformed pair is a usage error."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"settings are key=value, got {text!r}")
    return key.strip(), value


def settings_text(pairs: Sequence[tuple[str, str]] | None) -> dict[str, str]:
    """``--set`` pairs as a dict; a key given twice is an error (which one was meant?)."""
    out: dict[str, str] = {}
    for key, value in pairs or ():
        if key in out and out[key] != value:
            raise PlanbenchError(f"--set {key} is given twice ({out[key]!r} and {value!r}); give it once")
        out[key] = value
    return out


# -- a plugin class with its settings checked ---------------------------------------------------------


def configure_class(
    name: str,
    cls: type,
    settings: Mapping[str, Any] | None = None,
    *,
    implied: Mapping[str, Any] | None = None,
    text: Mapping[str, str] | None = None,
    kind: str = "planner",
) -> PlannerSetup:
    """Plugin class ``cls`` (called ``name`` in messages) with its settings checked and its ``Config``
    built (what :meth:`planbench.registry.Registry.configure` gives once it has found the class).

    ``implied`` are the settings its name implies (a ``family:variant`` preset), ``settings`` values
    (Python, a suite file) and ``text`` values as written on a command line (``--set key=value``),
    each winning over the one before. Each is parsed to the type its ``Config`` field declares
    (:func:`coerce_settings`), then ``Config(**settings)`` is built; every refusal is an
    :class:`InvalidSettingError` naming the plugin (as a ``kind``), the setting, the value and what
    is accepted. Building the ``Config`` runs no plugin code besides its own checks.
    """
    implied = implied or {}
    Config = config_class(cls)
    given = {**(settings or {}), **(text or {})}
    if Config is None:
        values = {k: _json_or_text(v) if k in (text or {}) else v for k, v in given.items()}
        return PlannerSetup(name, cls, None, {**implied, **values}, values, kind=kind)
    try:
        values = coerce_settings(name, Config, {**implied, **(settings or {})}, text=text, kind=kind)
        try:
            config = Config(**values)
        except (TypeError, ValueError) as exc:
            raise _refused(name, exc, values, Config) from exc
    except InvalidSettingError as exc:
        _name_kind(exc, kind)
        raise
    given_values = {k: v for k, v in values.items() if k in given}
    return PlannerSetup(name, cls, config, values, given_values, kind=kind)


@dataclass(frozen=True)
class PlannerSetup:
    """A plugin class (a planner, or the registry's ``kind``) with checked settings, ready to build
    (what :func:`configure_class` and
    :meth:`planbench.registry.Registry.configure` give).

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
