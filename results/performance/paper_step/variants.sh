#!/bin/bash
# One call of the device tool (issue 25): the paper-size train step (kosmos2, bfloat16, scan_layers,
# 256 tokens, the paper's dropouts unless a variant says otherwise) in several variants, one process
# and one JSON record each. All compile side by side, then each is timed alone (--lock, --barrier:
# benchmarks/step_mfu.py; at most SLOTS, 4, compile at once; while they wait each holds its float32 weights
# on the host, 6.6 GB at this size). The two batch-64 remat variants also trace one step (perfetto).
# Run from the repo root: bash results/performance/paper_step/variants.sh  (carry .whl; writes $OUT)
# .whl held only flax, optax, ml-collections, absl-py and etils of launch/device_env.sh's list (2026-12-04):
# the whole list and the repository were over the call's 64 MiB; the benchmark imports nothing else
# the machine lacks, and the machine's own orbax-checkpoint and tensorstore go together.
# A dry run here: LOCAL=1 SIZE=tiny PY=.venv/bin/python OUT=/tmp/out bash results/performance/paper_step/variants.sh
[[ -n "${LOCAL:-}" ]] || source launch/device_env.sh || exit 1
PY=${PY:-python3} SIZE=${SIZE:-kosmos2}
export PYTHONPATH="$PYTHONPATH:$PWD" TF_CPP_MIN_LOG_LEVEL=2 XLA_PYTHON_CLIENT_PREALLOCATE=false
R=$OUT/records B=/tmp/step_barrier LIMIT=${LIMIT:-420}
mkdir -p $R; rm -rf $B
nvidia-smi --query-gpu=name,memory.total,clocks.sm,clocks.max.sm --format=csv > $R/gpu.txt 2>&1
$PY -c "import jax, flax, optax; print(jax.__version__, flax.__version__, optax.__version__, jax.devices())" > $R/versions.txt 2>&1
VARIANTS=(
  "b64_full      --batch 64 --remat --profile /tmp/prof_b64_full"
  "b64_dots      --batch 64 --remat --remat-policy dots --profile /tmp/prof_b64_dots"
  "b64_dots_nodrop --batch 64 --remat --remat-policy dots --no-dropout"
  "b64_dots_unsafe_rbg --batch 64 --remat --remat-policy dots --prng unsafe_rbg"
  "b64_dots_bits16 --batch 64 --remat --remat-policy dots --dropout-mask-bits 16"
  "b32_noremat   --batch 32 --no-remat"
  "b128_dots     --batch 128 --remat --remat-policy dots"
)
N=${#VARIANTS[@]}
for line in "${VARIANTS[@]}"; do
  read -r name flags <<< "$line"
  ( timeout $LIMIT $PY benchmarks/step_mfu.py --size $SIZE --dtype bfloat16 --length 256 --scan --peer-size 8192 \
      --lock /tmp/step.lock --barrier $B:$N --slots /tmp/compile_slot:${SLOTS:-4} $flags --out $R/$name.json > $R/$name.log 2>&1
    echo "$(date +%T) $name rc $?" >> $R/progress.txt; mkdir -p $B; touch $B/$name ) &
done
wait
for dir in /tmp/prof_*; do  # the variants given --profile
  name=${dir#/tmp/prof_}
  find $dir -name 'perfetto_trace.json.gz' -exec cp {} $R/$name.perfetto_trace.json.gz \; 2>/dev/null
  [[ -f $R/$name.perfetto_trace.json.gz ]] && $PY benchmarks/trace_summary.py $R/$name.perfetto_trace.json.gz --top 12 \
    | tee $R/$name.trace_summary.txt
done
$PY - $R <<'PY'
import json, pathlib, sys
print(f"{'variant':22} {'step_s':>8} {'mfu':>6} {'peer TF/s':>9} {'GB':>6} {'compile':>7}")
for path in sorted(pathlib.Path(sys.argv[1]).glob("*.json")):
    r = json.loads(path.read_text())
    print(f"{path.stem:22} {r['step_s']:8.4f} {r['mfu']:6.3f} {r['peer_matmul_flops']/1e12:9.0f} {r['peak_memory_gb'] or 0:6.1f} {r['compile_s']:7.1f}"
          f" {r['profile_error'] or ''}")
PY
cat $R/progress.txt
tar czf $OUT/records.tgz -C $OUT records && rm -rf $R
