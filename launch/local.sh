#!/usr/bin/env bash
# Launch a kosmos_jax entry point with an ml-collections config on this machine.
#
#   launch/local.sh demo configs/demo.py:tiny --config.seed=1
#   FAKE_DEVICES=8 launch/local.sh demo configs/demo.py    # pretend the CPU is 8 devices
#
# The first argument is the module under kosmos_jax (demo, ...); the second the config file with an
# optional ":arg"; the rest are --config.* overrides passed through.
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 MODULE CONFIG[:ARG] [--config.key=value ...]" >&2
  exit 2
fi
module=$1; config=$2; shift 2
repo=$(cd "$(dirname "$0")/.." && pwd)
if [ ! -f "$repo/${config%%:*}" ] && [ ! -f "${config%%:*}" ]; then
  echo "$0: config file ${config%%:*} not found" >&2
  exit 2
fi
# huge pages for large CPU buffers: see the Makefile
export GLIBC_TUNABLES="${GLIBC_TUNABLES:-glibc.malloc.hugetlb=1}"
if [ -n "${FAKE_DEVICES:-}" ]; then
  export XLA_FLAGS="${XLA_FLAGS:-} --xla_force_host_platform_device_count=${FAKE_DEVICES}"
fi
make -C "$repo" --no-print-directory setup >&2
cd "$repo"
exec .venv/bin/python -m "kosmos_jax.${module}" --config="$config" "$@"
