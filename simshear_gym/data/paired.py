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


def load_paired(directory: str | os.PathLike, root: str | os.PathLike | None = None
                ) -> tuple[TactileSet, TactileSet | None]:
    """A paired set and, for replayed sets, the real set it pairs with (None for random contacts).

    The real set's ``targets`` are reordered to the paired set's rows, so image ``i`` of both belong together.
    """
    paired = read_set(directory, required_columns=POSE_COLUMNS + MOVE_COLUMNS + SHEAR_COLUMNS)
    real_relative = paired.meta.get("real_set")
    if not real_relative:
        return paired, None
    real_dir = Path(real_relative)
    if paired.meta.get("real_set_relative_to_data_root"):
        real_dir = data_root(root) / real_dir
    real = read_set(real_dir)
    index = pd.Index(real.targets[IMAGE_COLUMN])
    positions = index.get_indexer(paired.targets[REAL_IMAGE_COLUMN])
    if (positions < 0).any():
        missing = paired.targets[REAL_IMAGE_COLUMN].iloc[int(np.flatnonzero(positions < 0)[0])]
        raise TactileDataError(f"{paired.root}/targets.csv: real_image {missing!r} is not in {real_dir}")
    real = TactileSet(real.root, real.targets.iloc[positions].reset_index(drop=True), real.meta)
    return paired, real
