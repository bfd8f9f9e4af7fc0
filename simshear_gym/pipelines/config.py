"""The experiment config: one TOML file per sensor, read with :mod:`tomllib` into frozen dataclasses.

Tables (``configs/tactip331.toml`` describes the shipped sensor; ``configs/README.md`` documents every key):

- ``name``, ``description``: the sensor's name (names caches and run folders) and a line about it.
- ``[sensor]``: the simulated TacTip (:class:`~simshear_gym.sim.tactip.TacTipConfig`: dome radius, camera
  distance, field of view, full scale, image size), so that the simulation renders this lab's sensor.
- ``[replay]``: where the stimuli lie in the simulation's work frame
  (:class:`~simshear_gym.sim.replay.ReplayGeometry`: the surface's depth, the edge's offset).
- ``[frame]``: the lab's work frame -> the simulation's (:class:`~simshear_gym.data.adapter.FrameConfig`).
- ``[datasets.<name>]``: one per task: files, label columns, units, splits and the image adapter
  (:class:`~simshear_gym.data.adapter.DatasetConfig`).
- ``[check]``: how many rows per dataset ``simshear pipeline check`` replays in simulation, and the least share of
  them that must make contact.

Every error is a :class:`~simshear_gym.tables.ConfigError` naming the file, the key, the value and what was
expected, raised before anything reads data.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from simshear_gym.data.adapter import DatasetConfig, FrameConfig
from simshear_gym.sim.replay import ReplayGeometry
from simshear_gym.sim.tactip import TacTipConfig
from simshear_gym.tables import ConfigError, from_table, read_toml


@dataclass(frozen=True)
class CheckConfig:
    """``simshear pipeline check``'s replay test: ``replay_rows`` rows per dataset (spread over its train split)
    are rendered in simulation; fewer than ``min_contact_share`` of them with any contact means the frame or
    depth mapping is wrong (blank renders)."""

    replay_rows: int = 64
    min_contact_share: float = 0.5

    def __post_init__(self) -> None:
        if self.replay_rows < 1:
            raise ValueError(f"replay_rows must be >= 1, got {self.replay_rows!r}")
        if not 0.0 < self.min_contact_share <= 1.0:
            raise ValueError(f"min_contact_share must be in (0, 1], got {self.min_contact_share!r}")


@dataclass(frozen=True)
class ExperimentConfig:
    """A sensor's experiment config (see the module docstring); ``path`` is the file it was read from."""

    name: str
    datasets: Mapping[str, DatasetConfig]
    description: str = ""
    sensor: TacTipConfig = TacTipConfig()
    replay: ReplayGeometry = ReplayGeometry()
    frame: FrameConfig = FrameConfig()
    check: CheckConfig = CheckConfig()
    path: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "").replace("-", "").isalnum():
            raise ValueError(f"name must be letters, digits, '-' or '_' (it names folders), got {self.name!r}")
        if not self.datasets:
            raise ValueError("datasets must name at least one [datasets.<name>] table")


_TOP_LEVEL = ("name", "description", "sensor", "replay", "frame", "datasets", "check")


def load_config(path: str | Path) -> ExperimentConfig:
    """Read and validate an experiment config; raises :class:`ConfigError` on the first problem."""
    path = Path(path)
    table = read_toml(path)
    source = str(path)
    unknown = sorted(set(table) - set(_TOP_LEVEL))
    if unknown:
        raise ConfigError(f"{source}: unknown key {unknown[0]!r}; expected one of {list(_TOP_LEVEL)}")
    if "name" not in table:
        raise ConfigError(f"{source}: missing key 'name' (the sensor's name)")
    datasets_table = table.get("datasets")
    if not isinstance(datasets_table, dict) or not datasets_table:
        raise ConfigError(f"{source}: missing [datasets.<name>] tables (one per task)")
    datasets = {name: from_table(DatasetConfig, value, source, f"datasets.{name}")
                for name, value in datasets_table.items()}
    parts = {key: from_table(cls, table.get(key, {}), source, key)
             for key, cls in (("sensor", TacTipConfig), ("replay", ReplayGeometry), ("frame", FrameConfig),
                              ("check", CheckConfig))}
    for key in ("name", "description"):
        if key in table and not isinstance(table[key], str):
            raise ConfigError(f"{source}: {key} = {table[key]!r}; expected a string")
    try:
        return ExperimentConfig(name=table["name"], description=table.get("description", ""),
                                datasets=datasets, path=path, **parts)
    except ValueError as error:
        raise ConfigError(f"{source}: {error}") from None
