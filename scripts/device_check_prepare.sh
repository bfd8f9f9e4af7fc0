#!/bin/bash
# Prepare, on a CPU machine with PyBullet and the shared data, what scripts/device_check.sh reads on a lent GPU
# (which has neither PyBullet nor the data, and takes at most 64 MiB of working tree): .gpu/gpu_path/ (git-ignored)
#   labels/  the tactip331 label files alone (targets.csv of the eight sets, values rounded to 1e-3: 2 MB): what
#            `pipeline estimate` counts the profile's rows from, without an image;
#   data/    the first ROWS rows of the surface shear training set (real images + targets.csv);
#   paired/  their sim renders (simshear collect --replay): the translator's and the GDNN's A/B rows;
#   whl/     Gymnasium's wheels (pure Python; the config imports it, the GPU machine lacks it).
# usage: bash scripts/device_check_prepare.sh [ROWS]  (default 3000: 11 MiB in all, beside the repository's 50 MiB
# of tracked files under the 64 MiB a lent machine takes; a minute)
# then on the GPU: the run tool with carry [".gpu/gpu_path"] and command `bash scripts/device_check.sh`.
set -euo pipefail
ROWS=${1:-3000}
PY=${PY:-python3}
SRC=${SIMSHEAR_DATA:-$(cd .. && pwd)/shared/data}
DST=.gpu/gpu_path
rm -rf "$DST"
mkdir -p "$DST"
"$PY" - "$SRC" "$DST" "$ROWS" <<'EOF'
import shutil
import sys
from pathlib import Path

import pandas as pd

src, dst, rows = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
for csv in sorted((src / "tactip331" / "real").glob("*/*/csv_*/targets.csv")):
    out = dst / "labels" / csv.relative_to(src)
    out.parent.mkdir(parents=True, exist_ok=True)
    pd.read_csv(csv).round(3).to_csv(out, index=False)  # the estimate counts rows: 1e-3 keeps every split
train = src / "tactip331/real/surface_3d/shear/csv_train"
out = dst / "data" / train.relative_to(src)
(out / "images").mkdir(parents=True)
targets = pd.read_csv(train / "targets.csv").head(rows)
targets.to_csv(out / "targets.csv", index=False)
for name in targets["sensor_image"]:
    shutil.copy(train / "images" / name, out / "images" / name)
print(f"{dst}: labels of {len(list((dst / 'labels').rglob('targets.csv')))} sets, {len(targets)} surface rows")
EOF
"$PY" -m simshear_gym.cli collect --replay "$DST/data/tactip331/real/surface_3d/shear/csv_train" --contact surface \
    --data "$DST/data" --out "$DST/paired" --workers "${WORKERS:-2}"
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux2014_x86_64 -d "$DST/whl" gymnasium==1.4.0 farama-notifications==0.0.6
du -sh "$DST"
