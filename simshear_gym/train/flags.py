"""Command-line flags from a frozen config dataclass, and the config back from the parsed flags.

One flag per field, named from the field (``image_size_px`` -> ``--image-size``: the unit suffix ``_px`` dropped,
``_`` -> ``-``), with the field's type and default:

- ``bool`` fields: ``--flag`` when the default is False, ``--no-flag`` when it is True (both set the field);
- ``tuple[T, ...]`` fields: one or more values of T (``nargs="+"``);
- ``T | None`` fields: a T, default None.

Every flag gets a help text (the default is appended where there is one to show), so ``simshear X --help``
documents every setting. Torch-free, like the command modules that use it.
"""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

Config = TypeVar("Config")


def flag_name(field_name: str) -> str:
    """The flag of a config field: ``image_size_px`` -> ``--image-size``, ``patience_epochs`` ->
    ``--patience-epochs``."""
    return "--" + field_name.replace("_px", "").replace("_", "-")


def config_flags(parser: argparse.ArgumentParser, config_class: type, help: Mapping[str, str], *,
                 flags: Mapping[str, str] | None = None, choices: Mapping[str, tuple] | None = None,
                 required: tuple[str, ...] = (), metavars: Mapping[str, str] | None = None) -> None:
    """Add a flag to ``parser`` for each field of ``config_class`` named in ``help`` (in its order).

    Args:
        help: field name -> help text; only these fields get a flag (the others keep their defaults).
        flags: field name -> flag, where it is not :func:`flag_name` of the field.
        choices: field name -> the values the flag accepts.
        required: fields whose flag must be given (the dataclass default is then not used).
        metavars: field name -> the value's name in the usage line (default: the flag's, ``--blur`` -> ``BLUR``).
    """
    flags, choices, metavars = dict(flags or {}), dict(choices or {}), dict(metavars or {})
    fields = {field.name: field for field in dataclasses.fields(config_class)}
    unknown = sorted(set(help) - set(fields)) + sorted((set(flags) | set(choices) | set(required) | set(metavars))
                                                       - set(help))
    if unknown:
        raise ValueError(f"{config_class.__name__}: flags for {unknown}, which are not fields with a help text; "
                         f"fields: {sorted(fields)}")
    hints = typing.get_type_hints(config_class)
    for name, text in help.items():
        default = _default(fields[name])
        kind, element = _flag_type(hints[name], name)
        flag = flags.get(name, flag_name(name))
        options: dict[str, Any] = {"dest": name}
        if kind is bool:
            if name in required or name in choices:
                raise ValueError(f"{name}: a bool flag is a switch; it takes no choices and cannot be required")
            if default:
                flag = "--no-" + flag.removeprefix("--")
            parser.add_argument(flag, action="store_false" if default else "store_true", help=text, **options)
            continue
        if kind is tuple:
            options["nargs"] = "+"
        options["type"] = element
        if name in choices:
            options["choices"] = choices[name]
        options["metavar"] = metavars.get(name, flag.removeprefix("--").replace("-", "_").upper())
        if name in required:
            options["required"] = True
        else:
            options["default"] = default
            if default not in (None, (), ""):
                shown = " ".join(map(str, default)) if isinstance(default, tuple) else default
                text = f"{text} (default: {shown})"
        parser.add_argument(flag, help=text, **options)


def config_from_args(config_class: type[Config], args: argparse.Namespace, **overrides: Any) -> Config:
    """``config_class`` from the parsed flags: every field that ``args`` holds (lists become tuples), then
    ``overrides``; the fields without a flag keep their defaults."""
    values = {field.name: getattr(args, field.name) for field in dataclasses.fields(config_class)
              if hasattr(args, field.name)}
    values = {name: tuple(value) if isinstance(value, list) else value for name, value in values.items()}
    return config_class(**{**values, **overrides})


def _default(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return None


def _flag_type(hint: Any, name: str) -> tuple[type, type]:
    """(kind, value type) of a field's type hint: (bool, bool), (tuple, T) for tuple[T, ...], else (T, T) for T or
    T | None."""
    origin, parts = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        others = [part for part in parts if part is not type(None)]
        if len(others) != 1:
            raise ValueError(f"{name}: a flag takes one type or that type | None, not {hint}")
        return _flag_type(others[0], name)
    if origin is tuple:
        if len(parts) != 2 or parts[1] is not Ellipsis:
            raise ValueError(f"{name}: a tuple flag needs tuple[T, ...], not {hint}")
        return tuple, parts[0]
    if hint in (bool, int, float, str):
        return hint, hint
    raise ValueError(f"{name}: no flag for a field of type {hint}")
