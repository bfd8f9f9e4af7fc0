"""Frozen dataclasses from TOML tables, with errors that name the file, the key, the value and what was expected.

:func:`from_table` builds a (nested) frozen dataclass from a table read with :mod:`tomllib`: it refuses unknown
keys (listing the known ones), checks each value against the field's annotation (``int``, ``float``, ``str``,
``bool``, ``tuple[...]``, ``X | None``, a ``Literal``, a nested dataclass, ``dict[str, X]``) and re-raises the
dataclass's own ``__post_init__`` validation as a :class:`ConfigError` that says where the table came from.
"""

from __future__ import annotations

import collections.abc
import copy
import dataclasses
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin, get_type_hints

T = TypeVar("T")


class ConfigError(ValueError):
    """A config file, key or value is wrong; the message names the file, the key and what was expected."""


def read_toml(path: str | Path) -> dict[str, Any]:
    """A TOML file as a dict; a missing file or a syntax error becomes a :class:`ConfigError` naming the file."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML ({error})") from None


SET_HELP = ("override one setting of the config file, SECTION.KEY=VALUE (a TOML value), e.g. "
            "profiles.smoke.translator.epochs=2; repeatable; the file is not changed and the run records it")


def add_set_argument(parser) -> None:
    """``--set SECTION.KEY=VALUE`` (repeatable, into ``args.settings``) on a command that reads a config TOML
    (:func:`with_settings`)."""
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help=SET_HELP)


def parse_setting(text: str) -> tuple[tuple[str, ...], Any]:
    """One ``--set section.key=value``: (the dotted key's parts, the value read as a TOML value: ``2``, ``0.5``,
    ``true``, ``"cosine"``, ``[1, 2]``, ``{ surface = 26 }``; a bare word that is no TOML value is a string)."""
    key, sep, raw = str(text).partition("=")
    parts = tuple(part.strip() for part in key.split("."))
    if not sep or not all(parts) or not raw.strip():
        raise ConfigError(f"--set {text!r}: expected SECTION.KEY=VALUE, e.g. profiles.smoke.translator.epochs=2")
    try:
        value = tomllib.loads(f"value = {raw.strip()}")["value"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return parts, value


def with_settings(table: dict[str, Any], settings: tuple[str, ...] | list[str], source: str) -> dict[str, Any]:
    """``table`` (a config file's, read by :func:`read_toml`) with each ``--set section.key=value`` of ``settings``
    applied in order (tables on the way made where missing); the file itself is not touched. A key through a value
    that is no table is one error naming the file and the key."""
    result = copy.deepcopy(table)
    for text in settings:
        parts, value = parse_setting(text)
        node = result
        for depth, part in enumerate(parts[:-1]):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{source}: --set {text!r}: {'.'.join(parts[:depth + 1])} is {child!r}, not a "
                                  "table")
            node = child
        node[parts[-1]] = value
    return result


def from_table(cls: type[T], table: Any, source: str, key: str = "") -> T:
    """Build dataclass ``cls`` from a TOML table found at ``key`` (dotted) of the file ``source``."""
    where = f"{source}: [{key}]" if key else f"{source}:"
    if not isinstance(table, dict):
        raise ConfigError(f"{where} must be a table of {cls.__name__} settings, got {table!r}")
    known = {field.name: field for field in dataclasses.fields(cls) if field.init}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise ConfigError(f"{where} unknown key {_join(key, unknown[0])!r}; expected one of {sorted(known)}")
    missing = [name for name, field in known.items() if name not in table
               and field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING]
    if missing:
        raise ConfigError(f"{where} missing key {_join(key, missing[0])!r} ({cls.__name__} needs {missing})")
    values = field_values(cls, table, source, key)
    try:
        return cls(**values)
    except ConfigError:
        raise
    except (TypeError, ValueError) as error:
        raise ConfigError(f"{where} {error}") from None


def field_values(cls: type, table: dict, source: str, key: str = "") -> dict[str, Any]:
    """A TOML table's values checked and converted against the annotations of dataclass ``cls``'s fields of the
    same names (every key must name one), without building ``cls``: the override tables of a config."""
    hints = get_type_hints(cls)
    return {name: _convert(hints[name], value, source, _join(key, name)) for name, value in table.items()}


def _join(key: str, name: str) -> str:
    return f"{key}.{name}" if key else name


def _convert(annotation: Any, value: Any, source: str, key: str) -> Any:
    origin, args = get_origin(annotation), get_args(annotation)
    if origin in (Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for option in (arg for arg in args if arg is not type(None)):
            try:
                return _convert(option, value, source, key)
            except ConfigError as error:
                errors.append(error)
        raise errors[0] if len(errors) == 1 else ConfigError(
            f"{source}: {key} = {value!r} is none of {[_name(arg) for arg in args]}")
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"{source}: {key} = {value!r}; expected one of {list(args)}")
        return value
    if dataclasses.is_dataclass(annotation):
        return from_table(annotation, value, source, key)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{source}: {key} = {value!r}; expected a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], item, source, f"{key}[{i}]") for i, item in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{source}: {key} = {value!r}; expected a list of {len(args)} values")
        return tuple(_convert(arg, item, source, f"{key}[{i}]") for i, (arg, item) in enumerate(zip(args, value)))
    if origin in (dict, collections.abc.Mapping):
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: [{key}] must be a table, got {value!r}")
        return {name: _convert(args[1], item, source, _join(key, name)) for name, item in value.items()}
    if annotation is typing.Any:
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: {key} = {value!r}; expected true or false")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{source}: {key} = {value!r}; expected an integer")
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{source}: {key} = {value!r}; expected a number")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{source}: {key} = {value!r}; expected a string")
        return value
    raise TypeError(f"from_table cannot read a field annotated {annotation!r} ({key})")


def _name(annotation: Any) -> str:
    return getattr(annotation, "__name__", repr(annotation))
