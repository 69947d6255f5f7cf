#!/bin/bash
# Issue 21's gpu variants: the demo recipe (seed 0) for 800 steps (the CPU runs' length), 2400 steps,
# and 2400 steps on 1200 synthetic photos instead of 300; each scored on the 60 seed-7 validation scenes.
# Training is stopped (SIGTERM: checkpoint saved) after TRAIN_LIMIT seconds, so the call ends in time.
source launch/device_env.sh || exit 1
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.25 TF_CPP_MIN_LOG_LEVEL=2
L=$OUT/learn; mkdir -p $L; VAL=/tmp/synthetic-60-seed7
TRAIN_LIMIT=${TRAIN_LIMIT:-250}
nvidia-smi --query-gpu=name,memory.total --format=csv > $L/gpu.txt
python3 -c "import jax, flax, optax; print(jax.__version__, flax.__version__, optax.__version__, jax.devices())" > $L/versions.txt 2>&1
arm() {  # name steps photos
  local w=/tmp/w_$1
  { time timeout $TRAIN_LIMIT python3 -m kosmos_jax.train --config=configs/kosmos_e.py:demo --workdir=$w \
      --config.data.root=/tmp/data_$1 --config.train.steps=$2 --config.data.synthetic_photos=$3 \
      --config.train.eval_every=0 --config.train.checkpoint_every=$2 ; } > $L/$1.train.log 2>&1
  cp $w/metrics.jsonl $L/$1.metrics.jsonl
  while [ ! -f /tmp/val.ready ]; do sleep 1; done
  { time python3 -m kosmos_jax.evaluate --workdir=$w --cornell=$VAL --json ; } > $L/$1.validation_seed7.json 2> $L/$1.val.err
  python3 -m kosmos_jax.diagnostics.answer_errors --workdir=$w --scored=cornell-synthetic-60-seed7 --json \
      > $L/$1.answer_errors_seed7.json 2>> $L/$1.val.err
  echo "$1 done $(date +%T)" >> $L/progress.txt
}
arm s800 800 300 & arm s2400 2400 300 & arm s2400_p1200 2400 1200 &
{ time python3 -m kosmos_jax.sources.synthetic --out $VAL --photos 60 --seed 7 --quiet ; } > $L/val7.log 2>&1 && touch /tmp/val.ready
wait
