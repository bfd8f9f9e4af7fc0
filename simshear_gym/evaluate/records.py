"""The benchmarks' records: one way to write them, the command that reproduces each first."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from simshear_gym.command_line import recorded_command
from simshear_gym.io import write_json


def write_record(words: str, add_arguments: Callable[[argparse.ArgumentParser], None], args: argparse.Namespace,
                 path: Path, record: dict) -> Path:
    """Write ``record`` to ``path`` (indented JSON, atomically) after its ``"command"``: ``words`` and the options
    ``add_arguments`` defines, as ``args`` holds them (:func:`~simshear_gym.command_line.recorded_command`)."""
    return write_json(path, {"command": recorded_command(words, add_arguments, args), **record})
