#!/bin/bash
# fine-tunes of make demo's recipe, seeds 0-2, checkpoints every 50 steps kept, then scored on validation
set -x
cd /work/main
export JAX_PLATFORMS=cpu
while pgrep -f "make demo" >/dev/null || pgrep -f "kosmos_jax.demo" >/dev/null; do sleep 20; done
PY=.venv/bin/python
VAL="--cornell=datasets/synthetic-300-seed7 --kinds=non,multi --nounconstrained --mosaic_zoom --json"
for S in 0 1 2; do
  W=runs/ft/ck50_s$S
  $PY -m kosmos_jax.train --config=configs/kosmos_e.py:demo_grounded224_consensus --workdir=$W \
    --config.init_from=results/pretrain/grounding23600_lr2e-4 --config.data.root=demo_out/datasets \
    --config.train.grasp_eval_at_end=False --config.train.seed=$S \
    --config.train.checkpoint_every=50 --config.train.keep_checkpoints=8 > $W.train.log 2>&1 || exit 1
done
for S in 0 1 2; do
  W=runs/ft/ck50_s$S
  $PY -m kosmos_jax.workdir.average --workdirs=$W --steps=250,300,350,400 --out=runs/soup/tail_s$S || exit 1
done
$PY -m kosmos_jax.workdir.average --workdirs=runs/ft/ck50_s0,runs/ft/ck50_s1,runs/ft/ck50_s2 --out=runs/soup/soup012 || exit 1
for S in 0 1 2; do
  $PY -m kosmos_jax.evaluate --pretrained=runs/soup/tail_s$S --out=runs/soup/eval_tail_s$S $VAL > runs/soup/tail_s$S.validation.json || exit 1
done
$PY -m kosmos_jax.evaluate --pretrained=runs/soup/soup012 --out=runs/soup/eval_soup012 $VAL > runs/soup/soup012.validation.json || exit 1
for S in 0 1 2; do
  $PY -m kosmos_jax.evaluate --workdir=runs/ft/ck50_s$S $VAL > runs/soup/final_s$S.validation.json || exit 1
done
echo DONE
