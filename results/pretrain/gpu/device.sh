#!/bin/bash
# One call of the device tool (issue 21's gpu variant, issue 22's shipped start; results/pretrain/README.md):
# the shipped start's recipe (configs/kosmos_e.py:demo_gpu on photos of seed 1000) with four times the
# batch (128 rows, 2,400 steps: four times its examples), in three arms trained side by side:
#   b32         1,200 photos x 16 views (the shipped start's data), batch 32: the shipped start's recipe
#   b128        the same data, batch 128
#   b128_p2400  2,400 photos x 8 views (the same number of views), batch 128
# each scored on the 300 validation scenes of seed 7 (which chooses) and on make demo's unseen
# scenes (40 photos of seed 1: single photos and mosaics), and exported as a KOSMOS-2 folder.
# Datasets are built on the CPU (JAX_PLATFORMS=cpu). Training is stopped by SIGTERM (a checkpoint is
# saved) at DEADLINE seconds after the start, so the call ends in time; progress.txt says if it was.
# Run from the repo root: bash results/pretrain/gpu/device.sh  (carry .whl; writes under $OUT)
source launch/device_env.sh || exit 1
export PYTHONPATH="$PYTHONPATH:$PWD" TF_CPP_MIN_LOG_LEVEL=2 XLA_PYTHON_CLIENT_PREALLOCATE=false
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.3
STEPS=${STEPS:-2400} BATCH=${BATCH:-128} DEADLINE=${DEADLINE:-470} SEED=${SEED:-1000}
L=$OUT/records; mkdir -p $L $OUT/exports
START=$(date +%s)
nvidia-smi --query-gpu=name,memory.total --format=csv > $L/gpu.txt 2>&1
python3 -c "import jax, flax, optax; print(jax.__version__, flax.__version__, optax.__version__, jax.devices())" > $L/versions.txt 2>&1
stamp() { echo "$(date +%T) +$(( $(date +%s) - START ))s $*" >> $L/progress.txt; }
prepare() {  # root photos views: the arm's dataset, built as its trainer would, on the CPU
  JAX_PLATFORMS=cpu python3 - "$@" <<'PY'
import sys
from kosmos_jax.experiments.spec import config_module
config = config_module("configs/kosmos_e.py").get_config("demo_gpu")
config.data.root, config.data.synthetic_photos = sys.argv[1], int(sys.argv[2])
config.data.build.augmentations, config.data.synthetic_seed = int(sys.argv[3]), int(sys.argv[4])
from kosmos_jax.train import batches
batches.prepare(config.data)
PY
}
stamp start
for set in "300 7" "40 1"; do set -- $set
  ( JAX_PLATFORMS=cpu python3 -m kosmos_jax.sources.synthetic --out /tmp/synthetic-$1-seed$2 --photos $1 --seed $2 --quiet \
      > $L/synthetic-$1-seed$2.log 2>&1; stamp synthetic-$1-seed$2 written ) &
done
( prepare /tmp/d_b128 1200 16 $SEED > $L/b128.build.log 2>&1; stamp b128 data built ) &
first=$!
( prepare /tmp/d_b128_p2400 2400 8 $SEED > $L/b128_p2400.build.log 2>&1; stamp b128_p2400 data built ) &
second=$!
arm() {  # name photos views batch data [export]
  local w=/tmp/w_$1 left=$(( DEADLINE - ($(date +%s) - START) ))
  stamp $1 training, $left s left
  { time timeout $left python3 -m kosmos_jax.train --config=configs/kosmos_e.py:demo_gpu --workdir=$w \
      --config.data.root=/tmp/d_$5 --config.data.synthetic_photos=$2 --config.data.build.augmentations=$3 \
      --config.data.synthetic_seed=$SEED --config.train.batch_size=$4 --config.train.steps=$STEPS \
      --config.train.eval_every=0 --config.train.checkpoint_every=$STEPS ; } > $L/$1.train.log 2>&1
  stamp $1 trained rc $?
  cp $w/metrics.jsonl $L/$1.metrics.jsonl; cp $w/run.json $L/$1.run.json
  python3 -m kosmos_jax.evaluate --workdir=$w --cornell=/tmp/synthetic-300-seed7 --kinds=non --json \
      > $L/$1.validation300_seed7.json 2> $L/$1.score.err
  python3 -m kosmos_jax.diagnostics.answer_errors --workdir=$w --scored=cornell-synthetic-300-seed7 --json \
      > $L/$1.answer_errors300_seed7.json 2>> $L/$1.score.err
  python3 -m kosmos_jax.evaluate --workdir=$w --cornell=/tmp/synthetic-40-seed1 --kinds=non,multi --json \
      > $L/$1.unseen40_seed1.json 2>> $L/$1.score.err
  [ -z "$6" ] || { python3 -m kosmos_jax.workdir.export --workdir=$w --out=/tmp/export_$1 >> $L/$1.score.err 2>&1 \
      && tar czf $OUT/exports/$1.tgz -C /tmp export_$1; }
  stamp $1 scored
}
wait $first; arm b32 1200 16 32 b128 & arm b128 1200 16 $BATCH b128 export &
wait $second; arm b128_p2400 2400 8 $BATCH b128_p2400 export &
wait
stamp end
# the device tool returns only a few files of a call: the records as one archive
tar czf $OUT/records.tgz -C $OUT records && rm -rf $L
