#!/bin/bash
# Device check: translator latency on CUDA, the trainers' CUDA paths (AMP, channels_last), torchrun + nccl.
# usage: bash scripts/cuda_check.sh DEVICE EPOCHS OUTDIR   (results/ablations/cuda_check.json: cuda 6)
# It reads a small data root and paired set in .gpu/ (git-ignored), made from the shared data beforehand:
#   .gpu/data/tactip331/real/surface_3d/shear/{csv_train,csv_val}: the first 1000 / 200 rows (images + targets.csv)
#   simshear collect --replay .gpu/data/tactip331/real/surface_3d/shear/csv_train \
#       .gpu/data/tactip331/real/surface_3d/shear/csv_val --contact surface --data .gpu/data --out .gpu/paired
# It needs torch (with CUDA) and the package's own pure-Python dependencies; no PyBullet, Gymnasium or SB3.
DEV=${1:-cuda}; EP=${2:-4}; O=${3:-$OUT}
export TQDM_DISABLE=1 PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:$PYTHONPATH SIMSHEAR_DATA=$PWD/.gpu/data
PY=${PY:-python3}; S="$PY -m simshear_gym.cli"
mkdir -p $O/res; rm -rf /tmp/g
T0=$(date +%s)
stamp() { echo "=== $1 at $(( $(date +%s) - T0 )) s"; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1 | head -3
$PY -c "import torch, sys; print(sys.version.split()[0], torch.__version__, torch.cuda.is_available())"
P=.gpu/paired/surface_3d_shear_csv_train
stamp speed
$S evaluate translator-speed --device $DEV --batch-sizes 1 8 32 128 --repeats 100 --out $O/res || echo FAIL speed
stamp translator
$S train translator --arch shpix2pix --paired $P --data .gpu/data --out /tmp/g/tr --lr 1e-3 --lr-schedule cosine --decoder-scale 0.5 --epochs $EP --threads 8 --device $DEV || echo FAIL translator
cp /tmp/g/tr/history.json $O/res/translator_history.json
stamp posenet_real
$S train posenet --source real --contact surface --paired $P --data .gpu/data --out /tmp/g/pr --epochs $EP --threads 8 --device $DEV || echo FAIL posenet real
cp /tmp/g/pr/history.json $O/res/posenet_real_history.json
stamp posenet_translated
$S train posenet --source shpix2pix --translators simshear_gym/models/weights/shpix2pix_surface.pt --contact surface --paired $P --data .gpu/data --out /tmp/g/pt --epochs $EP --threads 8 --device $DEV || echo FAIL posenet shpix2pix
cp /tmp/g/pt/history.json $O/res/posenet_shpix2pix_history.json
stamp translator_10k_rows
$S train translator --arch shpix2pix --paired $P $P $P $P $P $P $P $P $P $P --data .gpu/data --out /tmp/g/tr10 --lr 1e-3 --lr-schedule cosine --decoder-scale 0.5 --epochs 2 --threads 8 --device $DEV || echo FAIL translator10
cp /tmp/g/tr10/history.json $O/res/translator10k_history.json
stamp torchrun
$PY -m torch.distributed.run --standalone --nproc_per_node 1 -m simshear_gym.cli train translator --arch shpix2pix --paired $P --data .gpu/data --out /tmp/g/ddp --epochs 1 --threads 8 --device $DEV || echo FAIL torchrun
ls /tmp/g/ddp
stamp evaluate
$S evaluate posenet --set .gpu/data/tactip331/real/surface_3d/shear/csv_val --model real:surface=/tmp/g/pr/best.pt --device $DEV --out /tmp/g/ev 2>&1 | tail -n 8 || echo FAIL evaluate posenet
stamp done
cp /tmp/g/ev/*.json $O/res/ 2>/dev/null; ls $O/res
