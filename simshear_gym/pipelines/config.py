"""The experiment config: one TOML file per sensor, read with :mod:`tomllib` into frozen dataclasses.

Tables (``configs/tactip331.toml`` describes the shipped sensor; ``configs/README.md`` documents every key):

- ``name``, ``description``: the sensor's name (names caches and run folders) and a line about it.
- ``[sensor]``: the simulated TacTip (:class:`~simshear_gym.sim.tactip.TacTipConfig`: dome radius, camera
  distance, field of view, full scale, image size), so that the simulation renders this lab's sensor.
- ``[replay]``: where the stimuli lie in the simulation's work frame
  (:class:`~simshear_gym.sim.replay.ReplayGeometry`: the surface's depth, the edge's offset).
- ``[frame]``: the lab's work frame -> the simulation's (:class:`~simshear_gym.data.adapter.FrameConfig`).
- ``[datasets.<name>]``: one per task: files, label columns, units, splits and the image adapter
  (:class:`~simshear_gym.data.adapter.DatasetConfig`); ``[datasets.<name>.frame]``: that dataset's own frame
  (a set recorded with another mount), in place of ``[frame]``.
- ``[collect]``: the data-collection protocol of ``simshear collect-real`` and ``simshear collect --protocol``
  (:class:`~simshear_gym.lab.collect_protocol.CollectProtocol`: stimulus and where it lies, ranges, rows, seed,
  tap share, hover, speeds, settle, frames per capture).
- ``[check]``: how many rows per dataset ``simshear pipeline check`` replays in simulation, the least share of
  them that must make contact, and how many rows check each label's sign, axis and the mount angle against the
  real images.
- ``[env_models.<name>]``: the recipe of a GDNN trained on an env's own translated images (the co-lift estimator;
  :class:`EnvModelRecipe`), run by ``simshear pipeline env-model CONFIG --model <name>``.
- ``[profiles.<name>]``: the training stages' settings, budgets counted in epochs (:class:`Profile`,
  :class:`TranslatorStage`, :class:`PosenetStage`); ``smoke`` (the test suite, seconds), ``quick`` (a laptop,
  under 30 minutes) and ``full`` have built-in defaults (:data:`DEFAULT_PROFILES`) that a config's table overrides
  key by key.

Every error is a :class:`~simshear_gym.tables.ConfigError` naming the file, the key, the value and what was
expected, raised before anything reads data or writes a file.

Names (the sensor's ``name``, each ``[datasets.<name>]``, ``[env_models.<name>]`` and pool generator ``name``) name
folders and files of a run, so a name is a name: it matches :data:`NAME_PATTERN` (letters, digits, ``_`` and ``-``,
starting with a letter or digit, at most 64 characters): no path separator, no ``..``, no space.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from simshear_gym.data.adapter import CONTACTS, DatasetConfig, FrameConfig
from simshear_gym.lab.collect_protocol import CollectProtocol
from simshear_gym.models.device import check_device_name
from simshear_gym.pipelines.env_collect import TASKS as ENV_TASKS
from simshear_gym.sim.objects import PAYLOADS
from simshear_gym.sim.replay import ReplayGeometry
from simshear_gym.sim.tactip import TacTipConfig
from simshear_gym.tables import ConfigError, field_values, from_table, read_toml, with_settings
from simshear_gym.train.posenet_config import PosenetTrainConfig
from simshear_gym.train.translator_config import TranslatorTrainConfig

NAME_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}"
"""What a name of the config may be (it names a folder of the run): letters, digits, '_' and '-', starting with a
letter or digit, at most 64 characters."""


def check_name(kind: str, name) -> str:
    """``name`` if it matches :data:`NAME_PATTERN`, else a ValueError naming ``kind`` and the value."""
    if not isinstance(name, str) or not re.fullmatch(NAME_PATTERN, name):
        raise ValueError(f"{kind} {name!r} is not a name: it names a folder of the run, so it must match "
                         f"{NAME_PATTERN} (letters, digits, '_' and '-'; no path separators, no '..', no spaces)")
    return name


def _check_per_contact(name: str, mapping: Mapping, valid, expected: str) -> None:
    """Raise unless every key of a {contact type: value} setting is a contact type and ``valid(value)``."""
    bad = {contact: value for contact, value in mapping.items() if contact not in CONTACTS or not valid(value)}
    if bad:
        raise ValueError(f"{name} must give contact types of {list(CONTACTS)} {expected}, got {bad}")


@dataclass(frozen=True)
class CheckConfig:
    """``simshear pipeline check``'s replay tests: ``replay_rows`` rows per dataset (spread over its train split)
    are rendered in simulation; fewer than ``min_contact_share`` of them with any contact means the frame or
    depth mapping is wrong (blank renders). Then ``frame_rows`` rows (0: none) check that the real images change
    with each label as the renders do (:mod:`simshear_gym.pipelines.check`'s frame check: signs, axes, mount angle)."""

    replay_rows: int = 64
    min_contact_share: float = 0.5
    frame_rows: int = 480

    def __post_init__(self) -> None:
        if self.replay_rows < 1:
            raise ValueError(f"replay_rows must be >= 1, got {self.replay_rows!r}")
        if self.frame_rows < 0 or 0 < self.frame_rows < 128:  # check.MIN_FRAME_ROWS
            raise ValueError(f"frame_rows must be 0 (no frame check) or >= 128, got {self.frame_rows!r}")
        if not 0.0 < self.min_contact_share <= 1.0:
            raise ValueError(f"min_contact_share must be in (0, 1], got {self.min_contact_share!r}")


TRANSLATOR_SET_BY_PIPELINE = ("arch", "paired_dirs", "image_size_px", "device", "pose_net", "teacher", "init_weights",
                              "max_minutes")
""":class:`~simshear_gym.train.translator_config.TranslatorTrainConfig` fields the pipeline sets itself (the
architecture of each step, its paired sets, the sensor's image size, the profile's device, a pool generator's pose
reader and the weights it starts from); it distils nothing, and its budgets are epochs, not minutes."""
GENERATOR_ARCH_KNOBS = ("base_channels", "max_channels", "template", "shear_decoder", "decoder_scale", "flow_px")
"""Translator knobs that shape the generator: a fine-tuned pool generator (``start_from``) shares them."""
POSE_KNOBS = ("pose_weight", "pose_variables")
"""Translator knobs only a pool generator sets (its pose-consistency loss needs a reader the pipeline trains)."""
POSENET_SET_BY_PIPELINE = ("source", "contact", "paired_dirs", "translators", "variables", "device", "max_minutes")
""":class:`~simshear_gym.train.posenet_config.PosenetTrainConfig` fields the pipeline sets itself."""
EPOCH_BUDGET: Mapping[str, object] = {"lr_schedule": "cosine", "patience_epochs": 1000}
"""What a pipeline profile changes in the trainers' defaults before its own overrides: a budget of epochs, the
rate annealed over the steps (so a slower machine trains the same model) and no early stop."""
TRANSLATOR_KEY_KNOBS = ("epochs", "batch_size", "lr", "lr_schedule", "base_channels", "max_channels",
                        "decoder_scale", "density_weight", "holdout", "patience_epochs", "seed", "threads",
                        "cap_minutes")
"""The knobs a translator step's cache key always names, overridden or not (so that the keys of earlier runs
hold); any other knob a profile overrides joins the key."""
POSENET_KEY_KNOBS = ("epochs", "batch_size", "image_size_px", "lr", "lr_schedule", "holdout", "patience_epochs",
                     "blur_px", "erase", "seed", "threads", "cap_minutes")
"""The knobs a GDNN step's cache key always names (as :data:`TRANSLATOR_KEY_KNOBS`)."""


def trainer_defaults(trainer: type) -> dict:
    """{field: default} of a trainer config (each of its fields has a plain default)."""
    return {item.name: item.default for item in fields(trainer)}


def knob_names(trainer: type, set_by_pipeline: tuple[str, ...]) -> tuple[str, ...]:
    """The fields of a trainer config a config file may override."""
    return tuple(name for name in trainer_defaults(trainer) if name not in set_by_pipeline)


def _check_overrides(owner, trainer: type, set_by_pipeline: tuple[str, ...]) -> None:
    """Raise unless every key of ``owner.overrides`` is a knob of ``trainer`` the config may set; the error lists
    the owner's own keys and the knobs."""
    own = sorted(item.name for item in fields(owner) if item.name != "overrides")
    knobs = knob_names(trainer, set_by_pipeline)
    for name in owner.overrides:
        if name in set_by_pipeline:
            raise ValueError(f"{name!r} is set by the pipeline, not by a config ({trainer.__name__} fields it sets: "
                             f"{list(set_by_pipeline)})")
        if name not in knobs:
            raise ValueError(f"unknown key {name!r}; expected one of {own} or a {trainer.__name__} knob of "
                             f"{sorted(knobs)}")


def _check_cap(cap_minutes) -> None:
    if cap_minutes is not None and cap_minutes <= 0:
        raise ValueError(f"cap_minutes must be > 0 (a wall-clock safety cap) or absent, got {cap_minutes!r}")


def _keyed(trainer: type, base: Mapping, overrides: Mapping, key_knobs: tuple[str, ...]) -> dict:
    """The trainer settings a step passes (and keys its cache by): ``key_knobs`` at the trainer's defaults under
    ``base`` and ``overrides``, and every other knob ``overrides`` gives."""
    values = {**trainer_defaults(trainer), **base, **overrides}
    return {name: values[name] for name in key_knobs} | {k: v for k, v in overrides.items() if k not in key_knobs}


@dataclass(frozen=True)
class TranslatorStage:
    """The translators' training: one per contact type and architecture in ``archs``, each a
    :class:`~simshear_gym.train.translator_config.TranslatorTrainConfig` at its defaults under
    :data:`EPOCH_BUDGET` and ``overrides`` (knob: value; any field but :data:`TRANSLATOR_SET_BY_PIPELINE` and
    :data:`POSE_KNOBS`). ``contact_epochs[contact]`` replaces ``epochs`` for a contact type it names (a harder
    contact type's translators train longer; the pool generators of that type take it too unless they give their
    own); a cosine schedule runs over the steps, so a slower machine trains the same model."""

    archs: tuple[str, ...] = ("shpix2pix", "pix2pix")
    contact_epochs: Mapping[str, int] = field(default_factory=dict)
    overrides: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check_overrides(self, TranslatorTrainConfig, TRANSLATOR_SET_BY_PIPELINE + POSE_KNOBS)
        _check_cap(self.setting("cap_minutes"))
        _check_per_contact("contact_epochs", self.contact_epochs, lambda n: isinstance(n, int) and n >= 1,
                           "a number of epochs >= 1")
        if not self.archs or set(self.archs) - {"shpix2pix", "pix2pix"}:
            raise ValueError(f"archs must name shpix2pix and/or pix2pix, got {list(self.archs)}")
        if "shpix2pix" not in self.archs:
            raise ValueError("archs must include shpix2pix: the GDNN trains on its images")
        if self.setting("epochs") < 1:
            raise ValueError(f"epochs must be >= 1, got {self.setting('epochs')!r}")
        TranslatorTrainConfig(paired_dirs=("set",), **self.settings_for(""))  # the trainer checks the values

    def setting(self, name: str):
        """A knob's value for the stage (before ``contact_epochs``)."""
        return {**trainer_defaults(TranslatorTrainConfig), **EPOCH_BUDGET, **self.overrides}[name]

    def with_epochs(self, epochs: int) -> TranslatorStage:
        """The stage with every contact type's translators trained ``epochs`` epochs."""
        return replace(self, overrides={**self.overrides, "epochs": epochs}, contact_epochs={})

    def epochs_for(self, contact: str) -> int:
        """The epochs of a contact type's translators."""
        return self.contact_epochs.get(contact, self.setting("epochs"))

    def settings_for(self, contact: str) -> dict:
        """The :class:`~simshear_gym.train.translator_config.TranslatorTrainConfig` settings of a contact type's
        translators (:data:`TRANSLATOR_KEY_KNOBS` and the other overrides, ``contact_epochs`` resolved into
        ``epochs``)."""
        settings = _keyed(TranslatorTrainConfig, EPOCH_BUDGET, self.overrides, TRANSLATOR_KEY_KNOBS)
        return settings | {"epochs": self.epochs_for(contact)}


BASELINES = ("pix2pix", "sim")
"""Comparison GDNNs a profile may add (:attr:`PosenetStage.baselines`): on pix2pix translations, on raw sim renders."""


@dataclass(frozen=True)
class PosenetStage:
    """The GDNNs' training: per contact type one on the real images (the reference) and one on the shPix2pix
    translations of the sim renders (the one that ships), each a
    :class:`~simshear_gym.train.posenet_config.PosenetTrainConfig` at its defaults under :data:`EPOCH_BUDGET` and
    ``overrides`` (any field but :data:`POSENET_SET_BY_PIPELINE`). Budget in epochs, as for
    :class:`TranslatorStage`: ``epochs``, or ``contact_epochs[contact]`` for every GDNN of a contact type it names
    (the reference, the one that ships and the baselines alike, so that they compare at one budget). The
    translated-image GDNN draws each row's generator from the contact's shPix2pix (listed ``translator_draws``
    times, or ``contact_translator_draws[contact]`` times for a contact type it names) and the profile's pool;
    ``random_contacts`` ({contact: n}) adds n sim contacts drawn uniformly over the contact's label ranges in the
    training data (no real image needed: they are translated like the replays), and ``random_tap_share``
    ({contact: share}) draws that share of them without shear (taps: the move columns 0), so that the rows without
    shear keep about the share they have in the real sets. ``baselines`` adds the paper's comparison GDNNs, scored
    beside the others on the real validation images: ``pix2pix`` (on the contact's pix2pix translations, which
    cannot know the shear) and ``sim`` (on the raw sim renders); ``baseline_epochs`` (not None) trains them that
    many epochs instead of their contact type's."""

    translator_draws: int = 1
    contact_translator_draws: Mapping[str, int] = field(default_factory=dict)
    random_contacts: Mapping[str, int] = field(default_factory=dict)
    random_tap_share: Mapping[str, float] = field(default_factory=dict)
    baselines: tuple[str, ...] = ()
    contact_epochs: Mapping[str, int] = field(default_factory=dict)
    baseline_epochs: int | None = None
    overrides: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check_overrides(self, PosenetTrainConfig, POSENET_SET_BY_PIPELINE)
        if self.setting("epochs") < 1:
            raise ValueError(f"epochs must be >= 1, got {self.setting('epochs')!r}")
        if self.baseline_epochs is not None and (not isinstance(self.baseline_epochs, int)
                                                 or self.baseline_epochs < 1):
            raise ValueError(f"baseline_epochs must be a number of epochs >= 1 or absent, got "
                             f"{self.baseline_epochs!r}")
        _check_per_contact("contact_epochs", self.contact_epochs, lambda n: isinstance(n, int) and n >= 1,
                           "a number of epochs >= 1")
        if set(self.baselines) - set(BASELINES) or len(set(self.baselines)) != len(self.baselines):
            raise ValueError(f"baselines must name distinct ones of {list(BASELINES)}, got {list(self.baselines)}")
        _check_cap(self.setting("cap_minutes"))
        if self.translator_draws < 1:
            raise ValueError(f"translator_draws must be >= 1, got {self.translator_draws!r}")
        _check_per_contact("contact_translator_draws", self.contact_translator_draws,
                           lambda n: isinstance(n, int) and not isinstance(n, bool) and n >= 1,
                           "a number of draws >= 1")
        _check_per_contact("random_contacts", self.random_contacts, lambda n: isinstance(n, int) and n >= 0,
                           "a count >= 0")
        _check_per_contact("random_tap_share", self.random_tap_share,
                           lambda share: isinstance(share, (int, float)) and not isinstance(share, bool)
                           and 0.0 <= share <= 1.0, "a share in [0, 1]")
        PosenetTrainConfig(paired_dirs=("set",), **self.train_settings("surface"))  # the trainer checks the values

    def setting(self, name: str):
        """A knob's value for the stage (before ``contact_epochs`` and ``baseline_epochs``)."""
        return {**trainer_defaults(PosenetTrainConfig), **EPOCH_BUDGET, **self.overrides}[name]

    def with_epochs(self, epochs: int) -> PosenetStage:
        """The stage with every contact type's GDNNs trained ``epochs`` epochs."""
        return replace(self, overrides={**self.overrides, "epochs": epochs}, contact_epochs={})

    def translator_draws_for(self, contact: str) -> int:
        """How often a contact type's shPix2pix is listed among the generators its GDNN draws from."""
        return self.contact_translator_draws.get(contact, self.translator_draws)

    def epochs_for(self, contact: str, baseline: bool = False) -> int:
        """The epochs of a contact type's GDNNs (``baseline``: of its baseline GDNNs)."""
        if baseline and self.baseline_epochs is not None:
            return self.baseline_epochs
        return self.contact_epochs.get(contact, self.setting("epochs"))

    def train_settings(self, contact: str, baseline: bool = False) -> dict:
        """The :class:`~simshear_gym.train.posenet_config.PosenetTrainConfig` settings of a contact type's GDNNs
        (``baseline``: of its baseline GDNNs): :data:`POSENET_KEY_KNOBS` and the other overrides, with
        ``contact_epochs`` and ``baseline_epochs`` resolved into ``epochs``."""
        settings = _keyed(PosenetTrainConfig, EPOCH_BUDGET, self.overrides, POSENET_KEY_KNOBS)
        return settings | {"epochs": self.epochs_for(contact, baseline)}


@dataclass(frozen=True)
class PoolGenerator:
    """One more shPix2pix generator of a contact type (``contact``; "" for every one) for the GDNN to train on:
    the translator stage's settings with ``overrides`` (translator knobs) replaced; its ``seed`` and
    ``density_weight`` are its own (the trainer's defaults where it gives none), not the stage's. With
    ``pose_weight`` > 0 it trains with the pose-consistency loss (:mod:`simshear_gym.train.pose_consistency`) read
    by the contact's real-image GDNN on ``pose_variables`` (all of its variables when empty), so it runs after that
    GDNN. The GDNN on translated images draws each row's generator at random, this one ``draws`` times as often as
    a generator listed once. Architecture and schedule knobs (``decoder_scale``, ``shear_decoder``, ``flow_px``,
    ``lr_schedule``...) may differ too, so that the pool's generators differ in more than their seed.
    ``reader_seed`` > 0 reads the pose consistency with a second real-image GDNN trained with that seed (the
    reference's settings otherwise), so that the generators do not all learn one network's quirks.
    ``start_from`` fine-tunes: the generator starts from the weights of the contact type's ``shpix2pix`` or of
    another pool generator (by name; the same architecture), so it runs after that one and needs fewer epochs
    than one trained from random weights."""

    name: str
    contact: str = ""
    draws: int = 1
    reader_seed: int = 0
    start_from: str = ""
    overrides: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_name("pool generator name", self.name)
        _check_overrides(self, TranslatorTrainConfig, TRANSLATOR_SET_BY_PIPELINE)
        if self.contact not in ("", *CONTACTS):
            raise ValueError(f"contact must be one of {list(CONTACTS)} or '' (every one), got {self.contact!r}")
        epochs = self.overrides.get("epochs")
        if self.draws < 1 or (epochs is not None and epochs < 1):
            raise ValueError(f"draws and epochs must be >= 1, got {self.draws!r}, {epochs!r}")
        if self.pose_weight < 0:
            raise ValueError(f"pose_weight must be >= 0, got {self.pose_weight!r}")
        if self.pose_variables and self.pose_weight == 0:
            raise ValueError(f"pose_variables {list(self.pose_variables)} need pose_weight > 0")
        if not isinstance(self.reader_seed, int) or self.reader_seed < 0:
            raise ValueError(f"reader_seed must be an integer >= 0 (0: the reference GDNN), got {self.reader_seed!r}")
        if self.reader_seed and self.pose_weight == 0:
            raise ValueError(f"reader_seed {self.reader_seed} needs pose_weight > 0 (it names the pose reader)")
        if self.start_from:
            check_name("pool generator start_from", self.start_from)
            if self.start_from == self.name:
                raise ValueError(f"pool generator {self.name!r}: start_from names the generator itself")
        TranslatorTrainConfig(paired_dirs=("set",), pose_net="reader" if self.pose_weight > 0 else "",
                              **{**EPOCH_BUDGET, **self.overrides})  # the trainer checks the values

    @property
    def pose_weight(self) -> float:
        return self.overrides.get("pose_weight", trainer_defaults(TranslatorTrainConfig)["pose_weight"])

    @property
    def pose_variables(self) -> tuple[str, ...]:
        return tuple(self.overrides.get("pose_variables", ()))

    @property
    def reader_step(self) -> str:
        """The suffix of the real-image GDNN step that reads this generator's pose consistency ("real" or
        "real_s<seed>")."""
        return f"real_s{self.reader_seed}" if self.reader_seed else "real"

    def replaced(self) -> dict:
        """The :class:`TranslatorStage` settings this generator replaces (its pose-consistency knobs aside)."""
        defaults = trainer_defaults(TranslatorTrainConfig)
        own = {"seed": defaults["seed"], "density_weight": defaults["density_weight"]}
        return own | {name: value for name, value in self.overrides.items() if name not in POSE_KNOBS}


ENV_MODEL_SET_BY_RECIPE = ("source", "contact", "paired_dirs", "translators", "variables", "device", "max_minutes")
""":class:`~simshear_gym.train.posenet_config.PosenetTrainConfig` fields an env-model recipe sets itself."""
ENV_MODEL_KEY_KNOBS = ("epochs", "patience_epochs", "batch_size", "lr", "seed", "threads", "cap_minutes")
"""The knobs an env-model GDNN's cache key always names (as :data:`TRANSLATOR_KEY_KNOBS`)."""


@dataclass(frozen=True)
class EnvModelRecipe:
    """A GDNN that reads an env's own translated images (``simshear pipeline env-model``;
    :mod:`simshear_gym.pipelines.env_model`), in one round of DAgger:

    1. ``oracle_seeds``: one set of ``rows`` images per seed (``simshear collect-env``: the oracle law with a
       wandering gain drives the follower, ``episode_steps`` per episode);
    2. a first GDNN on the sets of ``first_round_seeds`` (None: all the oracle sets), ``first_epochs`` epochs;
    3. ``dagger_seeds``: one set per seed driven by the servo controller reading with that first GDNN (the states
       the controller itself visits);
    4. the GDNN on every set, ``epochs`` epochs: the one that ships.

    Each GDNN is a :class:`~simshear_gym.train.posenet_config.PosenetTrainConfig` at its defaults under
    ``overrides`` (any field but :data:`ENV_MODEL_SET_BY_RECIPE`; ``epochs`` is the final GDNN's). Budgets are
    epochs; ``cap_minutes`` is only a wall-clock safety cap per training. ``task`` and ``payload`` pick the env
    (``SimShearCoLift-v0`` light or heavy objects, or ``SimShearTracking-v0``)."""

    task: str = "colift"
    payload: str = "light"
    rows: int = 12000
    episode_steps: int = 200
    oracle_seeds: tuple[int, ...] = (0, 1, 2)
    first_round_seeds: tuple[int, ...] | None = None
    dagger_seeds: tuple[int, ...] = ()
    first_epochs: int = 10
    overrides: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check_overrides(self, PosenetTrainConfig, ENV_MODEL_SET_BY_RECIPE)
        if self.task not in ENV_TASKS:
            raise ValueError(f"task must be one of {list(ENV_TASKS)}, got {self.task!r}")
        if self.payload not in PAYLOADS or (self.payload == "heavy" and self.task != "colift"):
            raise ValueError(f"payload must be one of {list(PAYLOADS)} (heavy: task colift), got {self.payload!r}")
        if self.rows < 1 or self.episode_steps < 1:
            raise ValueError(f"rows and episode_steps must be >= 1, got {self.rows!r}, {self.episode_steps!r}")
        if not self.oracle_seeds:
            raise ValueError("oracle_seeds must name at least one seed")
        seeds = [*self.oracle_seeds, *self.dagger_seeds]
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"oracle_seeds and dagger_seeds must all differ (a seed names a set), got {seeds}")
        if self.first_round_seeds is not None and (not self.first_round_seeds
                                                   or set(self.first_round_seeds) - set(self.oracle_seeds)):
            raise ValueError(f"first_round_seeds must be some of oracle_seeds {list(self.oracle_seeds)}, got "
                             f"{list(self.first_round_seeds)}")
        settings = self.train_settings()
        if min(self.first_epochs, *(settings[k] for k in ("epochs", "patience_epochs", "batch_size", "threads"))) < 1:
            raise ValueError("first_epochs, epochs, patience_epochs, batch_size and threads must be >= 1")
        _check_cap(settings["cap_minutes"])
        PosenetTrainConfig(source="env", contact="env", paired_dirs=("set",), **settings)  # the trainer checks them

    def train_settings(self, epochs: int | None = None) -> dict:
        """The :class:`~simshear_gym.train.posenet_config.PosenetTrainConfig` settings of the recipe's GDNNs
        (:data:`ENV_MODEL_KEY_KNOBS` and the other overrides), trained ``epochs`` epochs (None: the final's)."""
        settings = _keyed(PosenetTrainConfig, {}, self.overrides, ENV_MODEL_KEY_KNOBS)
        return settings | ({"epochs": epochs} if epochs is not None else {})

    def record(self) -> dict:
        """The recipe as its card and manifest record it: its own fields and its GDNNs' settings, flat."""
        own = {item.name: getattr(self, item.name) for item in fields(self) if item.name != "overrides"}
        return json.loads(json.dumps(own | self.train_settings()))  # plain JSON types (lists, not tuples)

    @property
    def first_round(self) -> tuple[int, ...]:
        """The oracle seeds whose sets train the first GDNN."""
        return self.first_round_seeds if self.first_round_seeds is not None else self.oracle_seeds


@dataclass(frozen=True)
class Profile:
    """A profile: how many rows of each split the pipeline uses (None: all), how many validation rows per
    dataset the evaluation reads (None: all), how many training steps run side by side (``jobs`` worker
    processes; give the stages ``threads`` = cores / jobs), where they train (``device``: ``auto``, ``cpu`` or
    ``cuda``, as ``--device`` of the trainers; not part of a step's cache key, so a step trained on one device is
    reused on another), the training stages' settings and the pool of extra generators for the translated-image
    GDNN (``[[profiles.<name>.pool]]``, :class:`PoolGenerator`). ``base`` names the profile it starts from (read
    by :func:`load_config`: that profile's tables key by key under this one's, its pool unless this one gives its
    own), so a variant of a recipe names only what differs."""

    base: str = ""
    rows_per_split: int | None = None
    eval_rows: int | None = None
    jobs: int = 1
    device: str = "auto"
    translator: TranslatorStage = TranslatorStage()
    posenet: PosenetStage = PosenetStage()
    pool: tuple[PoolGenerator, ...] = ()

    def __post_init__(self) -> None:
        if self.jobs < 1:
            raise ValueError(f"jobs must be >= 1, got {self.jobs!r}")
        check_device_name(self.device)
        names = [generator.name for generator in self.pool]
        if len(set(names)) != len(names):
            raise ValueError(f"pool: generator names must differ, got {names}")
        if "pix2pix" in self.posenet.baselines and "pix2pix" not in self.translator.archs:
            raise ValueError("posenet.baselines names pix2pix, but translator.archs trains no pix2pix")
        for generator in self.pool:
            self._check_start(generator)

    def _check_start(self, generator: PoolGenerator) -> None:
        """A pool generator's ``start_from`` names a translator the profile trains (the shPix2pix always) for every
        contact type the generator is trained for, of the generator's architecture, and no chain of starts loops."""
        by_name = {g.name: g for g in self.pool}
        seen, current = [generator.name], generator
        while current.start_from and current.start_from != "shpix2pix":
            found = by_name.get(current.start_from)
            if found is None or found.name in seen:
                raise ValueError(f"pool generator {generator.name!r}: start_from {generator.start_from!r} must be "
                                 f"'shpix2pix' or another pool generator's name, without a loop (pool: "
                                 f"{list(by_name)})")
            if found.contact not in ("", generator.contact):
                raise ValueError(f"pool generator {generator.name!r} ({generator.contact or 'every'} contact) "
                                 f"starts from {found.name!r}, trained for {found.contact} contacts only")
            seen.append(found.name)
            current = found
        if generator.start_from:
            start = by_name.get(generator.start_from)
            ours, theirs = (self.translator.settings_for("") | (g.replaced() if g else {}) for g in (generator, start))
            differ = {knob: (ours.get(knob), theirs.get(knob)) for knob in GENERATOR_ARCH_KNOBS
                      if ours.get(knob) != theirs.get(knob)}
            if differ:
                raise ValueError(f"pool generator {generator.name!r} starts from {generator.start_from!r}, another "
                                 f"architecture (its, the start's: {differ})")

    def pool_for(self, contact: str) -> tuple[PoolGenerator, ...]:
        """The pool's generators of a contact type."""
        return tuple(generator for generator in self.pool if generator.contact in ("", contact))


DEFAULT_PROFILES: Mapping[str, Mapping[str, Any]] = {
    "smoke": {"rows_per_split": 48, "eval_rows": 24,
              "translator": {"epochs": 1, "batch_size": 8, "base_channels": 4, "max_channels": 16},
              "posenet": {"epochs": 1, "batch_size": 16, "image_size_px": 32}},
    "quick": {"translator": {"epochs": 14}, "posenet": {"epochs": 20}},
    "full": {"translator": {"epochs": 30, "decoder_scale": 0.5}, "posenet": {"epochs": 40}},
}
"""Built-in profiles as ``[profiles.<name>]`` tables (trainer knobs over the trainers' defaults and
:data:`EPOCH_BUDGET`); a config's table overrides them key by key. ``full``'s translators have the shipped ones'
decoder, half the encoder's width, so that an env made with ``sensor=`` on its run steps at the shipped models' rate
(the trainer's full-width decoder: about 1.3x slower; ``quick`` keeps it, which learns more in few epochs)."""


def with_overrides(cls: type, trainer: type, table: Any, source: str, key: str):
    """A stage, pool generator or env-model recipe (``cls``) from its flat TOML table: its own fields, and the
    knobs of ``trainer`` (checked and converted against the trainer config's fields) as its ``overrides``."""
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [{key}] must be a table of {cls.__name__} settings, got {table!r}")
    own = {item.name for item in fields(cls)} - {"overrides"}
    knobs = set(trainer_defaults(trainer))
    given = {name: value for name, value in table.items() if name in knobs and name not in own}
    other = {name: value for name, value in table.items() if name not in knobs and name not in own}
    overrides = field_values(trainer, given, source, key) | other  # `other`: __post_init__ names the valid keys
    return from_table(cls, {**{name: table[name] for name in own if name in table}, "overrides": overrides},
                      source, key)


def profile_from_table(table: Any, source: str, key: str) -> Profile:
    """A :class:`Profile` from its ``[profiles.<name>]`` table (stage tables and pool entries flat, as
    :func:`with_overrides` reads them)."""
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [{key}] must be a table, got {table!r}")
    pool = table.get("pool", [])
    if not isinstance(pool, list):
        raise ConfigError(f"{source}: {key}.pool must be [[{key}.pool]] tables, got {pool!r}")
    parts = {"translator": with_overrides(TranslatorStage, TranslatorTrainConfig, table.get("translator", {}),
                                          source, f"{key}.translator"),
             "posenet": with_overrides(PosenetStage, PosenetTrainConfig, table.get("posenet", {}), source,
                                       f"{key}.posenet"),
             "pool": tuple(with_overrides(PoolGenerator, TranslatorTrainConfig, entry, source, f"{key}.pool[{i}]")
                           for i, entry in enumerate(pool))}
    profile = from_table(Profile, {k: v for k, v in table.items() if k not in parts}, source, key)
    try:
        return replace(profile, **parts)
    except ValueError as error:
        raise ConfigError(f"{source}: [{key}] {error}") from None


def default_profiles() -> dict[str, Profile]:
    """The built-in profiles (:data:`DEFAULT_PROFILES`)."""
    return {name: profile_from_table(dict(table), "built-in profiles", f"profiles.{name}")
            for name, table in DEFAULT_PROFILES.items()}


@dataclass(frozen=True)
class ExperimentConfig:
    """A sensor's experiment config (see the module docstring); ``path`` is the file it was read from, ``settings``
    the ``--set`` overrides read over it."""

    name: str
    datasets: Mapping[str, DatasetConfig]
    description: str = ""
    sensor: TacTipConfig = TacTipConfig()
    replay: ReplayGeometry = ReplayGeometry()
    frame: FrameConfig = FrameConfig()
    check: CheckConfig = CheckConfig()
    profiles: Mapping[str, Profile] = field(default_factory=default_profiles)
    env_models: Mapping[str, EnvModelRecipe] = field(default_factory=dict)
    dataset_frames: Mapping[str, FrameConfig] = field(default_factory=dict)
    collect: CollectProtocol | None = None
    path: Path | None = field(default=None, compare=False)
    settings: tuple[str, ...] = field(default=(), compare=False)  # the --set overrides read over the file

    def __post_init__(self) -> None:
        check_name("name", self.name)
        if not self.datasets:
            raise ValueError("datasets must name at least one [datasets.<name>] table")
        stray = sorted(set(self.dataset_frames) - set(self.datasets))
        if stray:
            raise ValueError(f"dataset_frames: {stray[0]!r} is no dataset; expected one of {sorted(self.datasets)}")
        for name in self.datasets:
            check_name("datasets: the dataset name", name)
        for name in self.env_models:
            check_name("env_models: the model name", name)
        contacts = {dataset.contact for dataset in self.datasets.values()}
        for name, profile in self.profiles.items():
            unused = sorted(({g.contact for g in profile.pool if g.contact}
                             | {c for c, n in profile.posenet.random_contacts.items() if n}
                             | {c for c, share in profile.posenet.random_tap_share.items() if share}) - contacts)
            if unused:
                raise ValueError(f"profiles.{name}: contact type {unused[0]!r} in pool, random_contacts or "
                                 f"random_tap_share, but the datasets have only {sorted(contacts)}")
            untapped = sorted(c for c, share in profile.posenet.random_tap_share.items()
                              if share and not profile.posenet.random_contacts.get(c))
            if untapped:
                raise ValueError(f"profiles.{name}: random_tap_share gives {untapped[0]!r} a share, but "
                                 f"random_contacts draws none for it")

    def frame_for(self, dataset: str) -> FrameConfig:
        """The frame of a dataset's labels: its own ``[datasets.<name>.frame]`` table, else the config's
        ``[frame]`` (data sets recorded with different mounts each give their own)."""
        return self.dataset_frames.get(dataset, self.frame)

    def profile(self, name: str) -> Profile:
        try:
            return self.profiles[name]
        except KeyError:
            raise ValueError(f"{self.path}: no profile {name!r}; it has {sorted(self.profiles)}") from None

    def env_model(self, name: str) -> EnvModelRecipe:
        try:
            return self.env_models[name]
        except KeyError:
            raise ValueError(f"{self.path}: no [env_models.{name}] table; it has {sorted(self.env_models)}") from None


_TOP_LEVEL = ("name", "description", "sensor", "replay", "frame", "datasets", "check", "profiles", "env_models",
              "collect")


def load_config(path: str | Path, settings: tuple[str, ...] | list[str] = ()) -> ExperimentConfig:
    """Read and validate an experiment config, with ``settings`` (``--set section.key=value``, see
    :func:`~simshear_gym.tables.with_settings`) applied over the file; raises :class:`ConfigError` on the first
    problem."""
    path = Path(path)
    source = str(path)
    table = with_settings(read_toml(path), settings, source)
    if settings:
        source = f"{path} with --set {' '.join(settings)}"
    unknown = sorted(set(table) - set(_TOP_LEVEL))
    if unknown:
        raise ConfigError(f"{source}: unknown key {unknown[0]!r}; expected one of {list(_TOP_LEVEL)}")
    if "name" not in table:
        raise ConfigError(f"{source}: missing key 'name' (the sensor's name)")
    datasets_table = table.get("datasets")
    if not isinstance(datasets_table, dict) or not datasets_table:
        raise ConfigError(f"{source}: missing [datasets.<name>] tables (one per task)")
    for name in list(datasets_table) + list(table.get("env_models") or {}):
        try:  # before the tables: a bad name is the first thing said
            check_name("the table name", name)
        except ValueError as error:
            raise ConfigError(f"{source}: {error}") from None
    dataset_frames = {name: from_table(FrameConfig, value["frame"], source, f"datasets.{name}.frame")
                      for name, value in datasets_table.items() if isinstance(value, dict) and "frame" in value}
    datasets = {name: from_table(DatasetConfig, {k: v for k, v in value.items() if k != "frame"}
                                 if isinstance(value, dict) else value, source, f"datasets.{name}")
                for name, value in datasets_table.items()}
    parts = {key: from_table(cls, table.get(key, {}), source, key)
             for key, cls in (("sensor", TacTipConfig), ("replay", ReplayGeometry), ("frame", FrameConfig),
                              ("check", CheckConfig))}
    tables = {name: dict(profile) for name, profile in DEFAULT_PROFILES.items()}
    for name, overrides in (table.get("profiles") or {}).items():
        if not isinstance(overrides, dict):
            raise ConfigError(f"{source}: [profiles.{name}] must be a table, got {overrides!r}")
        if "base" in overrides:  # a variant: the base profile's tables, as read so far, under this one's
            base = overrides["base"]
            if not isinstance(base, str) or base == name or base not in tables:
                raise ConfigError(f"{source}: [profiles.{name}] base = {base!r}; expected a profile built in or "
                                  f"defined above it: one of {sorted(set(tables) - {name})}")
            tables[name] = dict(tables[base])
        merged = tables.setdefault(name, {})
        for key, value in overrides.items():  # the stage tables key by key
            stage = merged.get(key)
            merged[key] = {**stage, **value} if isinstance(stage, dict) and isinstance(value, dict) else value
    profiles = {name: profile_from_table(profile, source, f"profiles.{name}") for name, profile in tables.items()}
    env_table = table.get("env_models") or {}
    if not isinstance(env_table, dict):
        raise ConfigError(f"{source}: env_models must be tables [env_models.<name>], got {env_table!r}")
    env_models = {name: with_overrides(EnvModelRecipe, PosenetTrainConfig, value, source, f"env_models.{name}")
                  for name, value in env_table.items()}
    collect = None
    if "collect" in table:
        collect_table = table["collect"]
        if isinstance(collect_table, dict) and "surface_depth_mm" in collect_table:
            raise ConfigError(f"{source}: [collect] surface_depth_mm: the stimulus's depth is [replay] "
                              "surface_depth_mm's (one place for it)")
        if isinstance(collect_table, dict):
            collect_table = {**collect_table, "surface_depth_mm": parts["replay"].surface_depth_mm}
        collect = from_table(CollectProtocol, collect_table, source, "collect")
    for key in ("name", "description"):
        if key in table and not isinstance(table[key], str):
            raise ConfigError(f"{source}: {key} = {table[key]!r}; expected a string")
    try:
        return ExperimentConfig(name=table["name"], description=table.get("description", ""),
                                datasets=datasets, profiles=profiles, env_models=env_models,
                                dataset_frames=dataset_frames, collect=collect, path=path,
                                settings=tuple(settings), **parts)
    except ValueError as error:
        raise ConfigError(f"{source}: {error}") from None
