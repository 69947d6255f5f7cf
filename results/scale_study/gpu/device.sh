#!/bin/bash
# One call of the device tool (results/scale_study/README.md; results/performance/paper_step/README.md):
#   1. issue 25: the paper-size train step with attention "einsum" and "fused" (cuDNN), same batch,
#      same run, decoder attention dropout 0 in both (the fused kernel takes none);
#   2. issue 21: the demo recipe (seed 0, value tokens read as their local mean) for STEPS steps on
#      300 and on 1200 synthetic photos, trained side by side once the benchmark has the GPU no more,
#      each scored on the 300 validation scenes of seed 7.
# Datasets are built on the CPU (JAX_PLATFORMS=cpu) while the benchmark runs. Training is stopped
# by SIGTERM (a checkpoint is saved) after TRAIN_LIMIT seconds, so the call ends in time.
# Run from the repo root: bash results/scale_study/gpu/device.sh  (carry .whl; writes under $OUT)
source launch/device_env.sh || exit 1
export PYTHONPATH="$PYTHONPATH:$PWD" TF_CPP_MIN_LOG_LEVEL=2 XLA_PYTHON_CLIENT_PREALLOCATE=false
STEPS=${STEPS:-2400} TRAIN_LIMIT=${TRAIN_LIMIT:-230} SIZE=${SIZE:-kosmos2} BATCH=${BATCH:-64}
SMALL=${SMALL:-300} LARGE=${LARGE:-1200} VAL=${VAL:-300} EXTRA=${EXTRA:-}
L=$OUT/scale P=$OUT/paper_step; mkdir -p $L $P
nvidia-smi --query-gpu=name,memory.total --format=csv > $OUT/gpu.txt 2>&1
python3 -c "import jax, flax, optax; print(jax.__version__, flax.__version__, optax.__version__, jax.devices())" > $OUT/versions.txt 2>&1
stamp() { echo "$(date +%T) $*" >> $OUT/progress.txt; }
prepare() {  # root photos: the arm's dataset, built as its trainer would, on the CPU
  JAX_PLATFORMS=cpu python3 - "$@" <<'PY'
import importlib.util, sys
spec = importlib.util.spec_from_file_location("kosmos_e", "configs/kosmos_e.py")
module = importlib.util.module_from_spec(spec); spec.loader.exec_module(module)
config = module.get_config("demo"); config.data.root = sys.argv[1]; config.data.synthetic_photos = int(sys.argv[2])
from kosmos_jax.train import batches
batches.prepare(config.data)
PY
}
stamp start
( JAX_PLATFORMS=cpu python3 -m kosmos_jax.sources.synthetic --out /tmp/synthetic-$VAL-seed7 --photos $VAL --seed 7 --quiet > $L/val.log 2>&1; stamp val written ) &
val_pid=$!
( prepare /tmp/p$SMALL $SMALL > $L/p$SMALL.build.log 2>&1; stamp p$SMALL built ) &
small_pid=$!
( prepare /tmp/p$LARGE $LARGE > $L/p$LARGE.build.log 2>&1; stamp p$LARGE built ) &
large_pid=$!
for kernel in einsum fused; do
  XLA_PYTHON_CLIENT_MEM_FRACTION=0.6 python3 benchmarks/step_mfu.py --size $SIZE --dtype bfloat16 --length 256 --scan \
    --batch $BATCH --remat --attention $kernel --text-attention-dropout 0 --out $P/${kernel}_b${BATCH}_remat.json \
    > $P/${kernel}.log 2>&1
  stamp step_mfu $kernel rc $?
done
arm() {  # photos
  local w=/tmp/w_p$1
  { time timeout $TRAIN_LIMIT python3 -m kosmos_jax.train --config=configs/kosmos_e.py:demo --workdir=$w \
      --config.data.root=/tmp/p$1 --config.data.synthetic_photos=$1 --config.train.steps=$STEPS \
      --config.train.eval_every=0 --config.train.checkpoint_every=$STEPS $EXTRA ; } > $L/p$1.train.log 2>&1
  stamp p$1 trained
  cp $w/metrics.jsonl $L/p$1.metrics.jsonl; cp $w/run.json $L/p$1.run.json
  python3 -m kosmos_jax.evaluate --workdir=$w --cornell=/tmp/synthetic-$VAL-seed7 --json \
      > $L/p$1.validation_seed7.json 2> $L/p$1.val.err
  python3 -m kosmos_jax.diagnostics.answer_errors --workdir=$w --scored=cornell-synthetic-$VAL-seed7 --json \
      > $L/p$1.answer_errors_seed7.json 2>> $L/p$1.val.err
  stamp p$1 scored
}
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.3
wait $val_pid $small_pid; arm $SMALL &
wait $large_pid; arm $LARGE &
wait
stamp end
# the device tool returns only a few files of a call (2026-11-27: 8 of 27): everything else as one archive
tar czf $OUT/records.tgz -C $OUT scale paper_step && rm -rf $OUT/scale $OUT/paper_step
