"""Model specifications of the evaluate commands: ``NAME[:CONTACT]=PATH`` (one model for every contact type, or one
per type) and ``CONTACT=PATH``."""

from __future__ import annotations

from pathlib import Path

from simshear_gym.data.labels import CONTACT_TYPES


def parse_models(specs: list[str]) -> dict[str, dict[str, Path]]:
    """``NAME=PATH`` (one model for all contacts) or ``NAME:CONTACT=PATH`` -> {name: {contact: path}}."""
    models: dict[str, dict[str, Path]] = {}
    for spec in specs:
        if "=" not in spec:
            raise ValueError(f"--model {spec!r}: expected NAME=PATH or NAME:CONTACT=PATH")
        key, path = spec.split("=", 1)
        name, _, contact = key.partition(":")
        if contact and contact not in CONTACT_TYPES:
            raise ValueError(f"--model {spec!r}: contact must be one of {CONTACT_TYPES}")
        for each in ([contact] if contact else CONTACT_TYPES):
            models.setdefault(name, {})[each] = Path(path)
    return models


def parse_contact_paths(specs: list[str], flag: str) -> dict[str, Path]:
    """``CONTACT=PATH`` -> {contact: path}; ``flag`` names the option in errors."""
    paths: dict[str, Path] = {}
    for spec in specs:
        contact, _, path = spec.partition("=")
        if contact not in CONTACT_TYPES or not path:
            raise ValueError(f"{flag} {spec!r}: expected CONTACT=PATH with CONTACT one of {CONTACT_TYPES}")
        paths[contact] = Path(path)
    return paths
