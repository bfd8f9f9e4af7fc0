"""The command line a record holds: the command's words and the options that differ from their defaults.

Every command that writes a result, a card or a manifest records the command that reproduces it, rebuilt here from
the command's parser and its parsed arguments, so a new option is recorded without touching the writer. The
canonical form: the words (``simshear evaluate servo``), then each argument in the parser's order - positionals as
given, an option only where its value differs from its default (``store_true`` flags bare, a list one word per
item, an ``append`` option once per item, an ``nargs="?"`` option bare at its ``const``, floats as ``%g`` where
that loses nothing) - every word quoted for the shell. Paths stay as the user gave them. Parsing the line again
with the same parser gives the same arguments.
"""

from __future__ import annotations

import argparse
import os
import shlex
from collections.abc import Callable


def recorded_command(words: str, add_arguments: Callable[[argparse.ArgumentParser], None],
                     args: argparse.Namespace) -> str:
    """:func:`command_line` of a command module's options: ``add_arguments`` fills a fresh parser."""
    parser = argparse.ArgumentParser(prog=words)
    add_arguments(parser)
    return command_line(words, parser, args)


def command_line(words: str, parser: argparse.ArgumentParser, args: argparse.Namespace) -> str:
    """The canonical command line (see the module docstring) of ``args`` parsed by ``parser``, after ``words``.
    Arguments absent from ``args`` count as their defaults."""
    line = words.split()
    for action in parser._actions:
        if action.default is argparse.SUPPRESS or not hasattr(args, action.dest):
            continue  # --help, --version, sub-commands; a hand-made Namespace without the option
        value = getattr(args, action.dest)
        if not action.option_strings:  # a positional: always, but an optional one (nargs ? or *) at its default
            if not (action.nargs in ("?", "*") and _same(value, _default(action))):
                line += _values(value)
        elif not _same(value, _default(action)):
            line += _option(action, value)
    return shlex.join(line)


def _option(action: argparse.Action, value) -> list[str]:
    flag = next((s for s in action.option_strings if s.startswith("--")), action.option_strings[0])
    if isinstance(action, argparse.BooleanOptionalAction):
        return [flag if value else next(s for s in action.option_strings if s.startswith("--no-"))]
    if action.nargs == 0:  # store_true, store_false, store_const
        if value != action.const:
            raise ValueError(f"cannot record {flag} with the value {value!r}: the flag stores {action.const!r}")
        return [flag]
    if action.nargs == "?" and action.const is not None and value == action.const:
        return [flag]  # an option whose value may be left out: left out where it is the one it stands for
    if isinstance(action, argparse._AppendAction):
        return [word for item in value for word in (flag, *_values(item))]
    return [flag, *_values(value)]


def _values(value) -> list[str]:
    return [_word(item) for item in value] if isinstance(value, (list, tuple)) else [_word(value)]


def _word(value) -> str:
    if isinstance(value, float):
        short = f"{value:g}"
        return short if float(short) == value else repr(value)
    return os.fspath(value) if isinstance(value, os.PathLike) else str(value)


def _default(action: argparse.Action):
    """The default as argparse stores it: a string default goes through the option's type."""
    default = action.default
    if isinstance(default, str) and callable(action.type):
        return action.type(default)
    return default


def _same(value, default) -> bool:
    """Equal, a tuple default and a parsed list alike."""
    def listed(item):
        return list(item) if isinstance(item, (list, tuple)) else item
    return listed(value) == listed(default)
