"""``--model`` specifications of the evaluate commands: one model for every contact type, or one per type."""

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
