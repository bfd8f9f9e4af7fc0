#!/bin/bash
# Device check of the GPU path (docs: configs/README.md, profile `gpu`), in one go on a lent GPU (about 9 minutes of
# its 15): 1. `pipeline estimate` of the gpu profile on the GPU (its batch sizes, rows on the device); 2. the
# batches' quality on real rows (the first 3000 surface shear rows; on a CPU the profile's batches at the recipe's
# epochs lost quality: docs/experiments.md, gpu_rule): the shPix2pix (14 epochs, as the edge recipe's; decoder 0.5,
# cosine) at batch 16 and lr 1e-3 (the reference) against batch 64 and against batch 256 with 4x the epochs (rate x
# sqrt of the batch ratio), and 256 under torch.compile; the real-image GDNN (60 epochs, as the surface recipe's) at
# batch 64 against 256 and against 1024 with 4x the epochs; 3. where PyBullet and the whole data set are there (not on the machines lent so
# far: no PyBullet, 64 MiB of working tree), `pipeline run --profile gpu --device cuda` under a timeout.
# Before, on a CPU machine: bash scripts/device_check_prepare.sh (writes .gpu/gpu_path, git-ignored); then the run
# tool with carry [".gpu/gpu_path"] and command `bash scripts/device_check.sh`, timeout_s 600.
# The timeouts add up to 530 s (a run they cut keeps its finished epochs in its history). Results under $OUT: log.txt, estimate_gpu.json, device_check.json (each run's settings, epochs, seconds and holdout
# metric per epoch).
set -uo pipefail
O=${OUT:-/tmp/device_check}
G=.gpu/gpu_path
mkdir -p "$O"
exec > >(tee "$O/log.txt") 2>&1
export TQDM_DISABLE=1 PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
PY=${PY:-python3}
S="$PY -m simshear_gym.cli"
T0=$(date +%s)
stamp() { echo "=== $1 at $(( $(date +%s) - T0 )) s"; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1 | head -3
if ! $PY -c "import gymnasium" 2>/dev/null; then  # the package's config imports it; carried as wheels
    $PY -m pip install -q --no-index --no-deps --no-compile --target /tmp/site $G/whl/*.whl && export PYTHONPATH=/tmp/site:$PYTHONPATH
fi
SIMULATES=1
if ! $PY -c "import pybullet" 2>/dev/null; then  # no PyBullet: a stand-in lets the config load; nothing simulates
    SIMULATES=0
    mkdir -p /tmp/stub/pybullet /tmp/stub/pybullet_data
    printf 'def __getattr__(name):\n    if name.isupper():\n        return 0\n    raise ImportError("PyBullet is not installed here")\n' > /tmp/stub/pybullet/__init__.py
    printf 'def getDataPath():\n    return ""\n' > /tmp/stub/pybullet_data/__init__.py
    export PYTHONPATH=/tmp/stub:$PYTHONPATH
fi
$PY -c "import sys, torch; print(sys.version.split()[0], torch.__version__, torch.cuda.is_available())"

stamp estimate
timeout 150 $S pipeline estimate configs/tactip331.toml --profile gpu --device cuda --data $G/labels --probe-steps 20 \
    --json "$O/estimate_gpu.json" || echo "FAIL estimate"

P=$G/paired
D=$G/data
R=/tmp/device_check_runs
rm -rf $R
TRANSLATOR="train translator --arch shpix2pix --paired $P --data $D --decoder-scale 0.5 --lr-schedule cosine \
    --patience-epochs 1000 --epochs 14 --threads 8 --device cuda"
POSENET="train posenet --source real --contact surface --paired $P --data $D --lr-schedule cosine \
    --patience-epochs 1000 --epochs 60 --threads 8 --device cuda"
# at the recipe's epochs the large batches lose quality (measured on a CPU: docs/experiments.md, gpu_rule; the
# linear rule does not train): the batch 256 rule, and batch 1024 with four times the epochs
stamp "posenet batch 256 sqrt"
timeout 35 $S $POSENET --batch-size 256 --lr-scaling sqrt --warmup-epochs 1 --out $R/posenet_b256_sqrt \
    > /dev/null || echo "FAIL posenet b256"
stamp "posenet batch 1024 sqrt, 4x epochs"
timeout 35 $S $POSENET --batch-size 1024 --lr-scaling sqrt --warmup-epochs 1 --epochs 240 \
    --out $R/posenet_b1024_sqrt_x4 > /dev/null || echo "FAIL posenet b1024 x4"
stamp "posenet batch 64 (reference)"
timeout 70 $S $POSENET --out $R/posenet_b64 > /dev/null || echo "FAIL posenet reference (cut: its epochs so far count)"
# batch 256 at the recipe's epochs reads MAPE 1.6-2.3x the shipped (CPU, gpu_rule): batch 64, and 256 with 4x epochs
stamp "translator batch 64 sqrt"
timeout 30 $S $TRANSLATOR --batch-size 64 --lr-scaling sqrt --warmup-epochs 1 --no-amp \
    --out $R/translator_b64_sqrt > /dev/null || echo "FAIL translator b64"
stamp "translator batch 256 sqrt, 4x epochs"
timeout 40 $S $TRANSLATOR --batch-size 256 --lr-scaling sqrt --warmup-epochs 1 --no-amp --epochs 56 \
    --out $R/translator_b256_sqrt_x4 > /dev/null || echo "FAIL translator b256 x4"
stamp "translator batch 256 sqrt compiled"
timeout 50 $S $TRANSLATOR --batch-size 256 --lr-scaling sqrt --warmup-epochs 1 --no-amp --compile \
    --out $R/translator_b256_sqrt_compiled > /dev/null || echo "FAIL translator compiled"
stamp "translator batch 16 (reference)"
timeout 120 $S $TRANSLATOR --out $R/translator_b16 > /dev/null || echo "FAIL translator reference (cut: its epochs so far count)"

stamp summary
$PY - $R "$O/device_check.json" <<'EOF'
import json
import sys
from pathlib import Path

runs, out = Path(sys.argv[1]), Path(sys.argv[2])
found = {}
for history in sorted(runs.glob("*/history.json")):
    record = json.loads(history.read_text())
    config, epochs = record["config"], record["epochs"]
    metric = next(key for key in epochs[0] if key.startswith("holdout_")) if epochs else None
    found[history.parent.name] = {
        "settings": {k: config.get(k) for k in ("batch_size", "lr", "lr_scaling", "warmup_epochs", "epochs", "amp",
                                                "compile", "data_on_device")},
        "epochs_done": len(epochs), "elapsed_s": epochs[-1]["elapsed_s"] if epochs else None,
        "metric": metric, "best": min(e[metric] for e in epochs) if epochs else None,
        "last": epochs[-1][metric] if epochs else None,
        "per_epoch": [[e["epoch"], e["elapsed_s"], round(e[metric], 5)] for e in epochs]}
out.write_text(json.dumps(found, indent=1))
for name, run in found.items():
    print(f"{name:34s} epochs {run['epochs_done']:3d} {run['elapsed_s']} s  best {run['metric']} {run['best']}")
EOF

if [ "$SIMULATES" = 1 ] && [ -n "${SIMSHEAR_DATA:-}" ]; then
    stamp "pipeline run --profile gpu"
    timeout "${RUN_TIMEOUT_S:-300}" $S pipeline run configs/tactip331.toml --profile gpu --device cuda \
        --out /tmp/device_check_pipeline || echo "STOPPED pipeline run (timeout or failure)"
    cp /tmp/device_check_pipeline/manifest.json "$O/pipeline_manifest.json" 2>/dev/null
else
    echo "=== pipeline run skipped: it needs PyBullet (the data stages render in simulation) and the whole data set" \
         "(SIMSHEAR_DATA, 232 MB: more than the 64 MiB a lent machine takes)"
fi
stamp done
