"""The paired-set format: our sim renders of labelled contacts beside the real images of the same contacts.

A **paired set** is a tactile-data set (see :mod:`simshear_gym.data.tactile_set`) whose ``images/`` are our sim
renders and whose ``targets.csv`` carries, per row: ``sensor_image`` (our render), ``real_image`` (the real
image of the same contact, a file in the real set named by ``meta.json``'s ``real_set``; empty for random
contacts), the labels ``pose_*`` and ``move_*``, and the shear vector in the sensor frame ``shear_sensor_*``
(from the :class:`~simshear_gym.sim.shear.ShearTracker`). ``meta.json`` records the contact type, the sensor
and geometry settings and where the real set lies (relative to the data root when it is under it).

``simshear collect --replay DIR [DIR ...] --out OUT`` and ``simshear collect --replay-all --out OUT`` (the eight
tactip331 sets) replay real sets; ``simshear collect --task surface|edge --n N --seed S --out OUT`` draws
random contacts over the real sets' ranges.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from simshear_gym.data.labels import (
    IMAGE_COLUMN,
    MOVE_COLUMNS,
    POSE_COLUMNS,
    SHEAR_COLUMNS,
)
from simshear_gym.data.paths import data_root
from simshear_gym.data.tactile_set import TactileDataError, TactileSet, read_set

REAL_IMAGE_COLUMN = "real_image"


def load_paired(directory: str | os.PathLike, root: str | os.PathLike | None = None, load_real: bool = True
                ) -> tuple[TactileSet, TactileSet | None]:
    """A paired set and, for replayed sets, the real set it pairs with (None for random contacts, and when
    ``load_real`` is False: a caller that uses only the sim renders and labels does not need the real set).

    The real set's ``targets`` are reordered to the paired set's rows, so image ``i`` of both belong together.

    Raises:
        TactileDataError: the set, its ``meta.json`` (missing, not an object, ``real_set`` not a path), its
            ``real_image`` column (missing, empty, naming an image the real set lacks) or the real set is
            malformed; the message names the file, row or column.
    """
    meta_file = Path(directory) / "meta.json"
    paired = read_set(directory, required_columns=POSE_COLUMNS + MOVE_COLUMNS + SHEAR_COLUMNS)
    if not meta_file.is_file():
        raise TactileDataError(f"{meta_file}: missing; a paired set records its contact type and the real set it "
                               "pairs with there (simshear collect writes it)")
    real_relative = paired.meta.get("real_set")
    if not real_relative:
        return paired, None
    if not isinstance(real_relative, str):
        raise TactileDataError(f"{meta_file}: 'real_set' must be the real set's directory (a string), got "
                               f"{real_relative!r}")
    targets_file = paired.root / "targets.csv"
    if REAL_IMAGE_COLUMN not in paired.targets.columns:
        raise TactileDataError(f"{targets_file}: column {REAL_IMAGE_COLUMN!r} is missing; a replayed paired set "
                               f"(meta.json real_set {real_relative!r}) names each row's real image there; found "
                               f"columns {list(paired.targets.columns)}")
    names = paired.targets[REAL_IMAGE_COLUMN]
    empty = names.isna() | (names.astype(str).str.strip() == "")
    if empty.any():
        row = int(np.flatnonzero(empty.to_numpy())[0])
        raise TactileDataError(f"{targets_file}: row {row + 1}, column {REAL_IMAGE_COLUMN!r}: empty; expected the "
                               f"name of the real image in {real_relative}")
    if not load_real:
        return paired, None
    real_dir = Path(real_relative)
    if paired.meta.get("real_set_relative_to_data_root"):
        real_dir = data_root(root) / real_dir
    real = read_set(real_dir)
    index = pd.Index(real.targets[IMAGE_COLUMN])
    positions = index.get_indexer(names.astype(str))
    if (positions < 0).any():
        row = int(np.flatnonzero(positions < 0)[0])
        raise TactileDataError(f"{targets_file}: row {row + 1}, real_image {names.iloc[row]!r} is not in "
                               f"{real_dir}")
    real = TactileSet(real.root, real.targets.iloc[positions].reset_index(drop=True), real.meta)
    return paired, real
