#!/usr/bin/env bash
# Launch a kosmos_jax entry point with an ml-collections config on this machine.
#
#   launch/local.sh demo configs/demo.py:tiny --config.seed=1
#   FAKE_DEVICES=8 launch/local.sh demo configs/demo.py    # pretend the CPU is 8 devices
#   PROCESSES=2 FAKE_DEVICES=2 launch/local.sh train configs/kosmos_e.py:tiny --workdir=runs/mp
#   PROCESSES=2 launch/local.sh train.distributed_check configs/demo.py   # does multi-process work?
#
# The first argument is the module under kosmos_jax (demo, train, ...); the second the config file
# with an optional ":arg"; the rest (--config.* overrides, --workdir=...) are passed through. It runs
# in the repository root, so relative paths in the flags are relative to it.
#
# Environment:
#   FAKE_DEVICES=N      XLA pretends the CPU is N devices (in each process)
#   PROCESSES=N         N processes of the same command on 127.0.0.1 (default 1), each told its part
#                       through KOSMOS_COORDINATOR=127.0.0.1:PORT, KOSMOS_NUM_PROCESSES=N and
#                       KOSMOS_PROCESS_ID=I (read by kosmos_jax.train.distributed); their output
#                       lines start with "[I] "; if one fails the others are stopped and its exit
#                       status is this script's
#   COORDINATOR_PORT=P  the coordinator's port (default: a free one)
#   DRY_RUN=1           print the commands (with the environment they get) and exit
#   SETUP=0             skip `make setup` (skipped under DRY_RUN too)
#   LAUNCH_PYTHON=PATH  the interpreter (default .venv/bin/python)
set -euo pipefail
usage() {
  echo "usage: $0 MODULE CONFIG[:ARG] [--config.key=value ...]" >&2
  echo "  environment: PROCESSES=N FAKE_DEVICES=N COORDINATOR_PORT=P DRY_RUN=1 SETUP=0 LAUNCH_PYTHON=PATH" >&2
  exit 2
}
if [ $# -lt 2 ]; then
  usage
fi
module=$1; config=$2; shift 2
repo=$(cd "$(dirname "$0")/.." && pwd)
# shellcheck source=launch/quote.sh
. "$repo/launch/quote.sh"
config_file=${config%%:*}
if [ ! -f "$repo/$config_file" ]; then
  if [ ! -f "$config_file" ]; then
    echo "$0: config file $config_file not found" >&2
    exit 2
  fi
  # relative to where we were called from: make it absolute, we run in the repository root
  config="$(cd "$(dirname "$config_file")" && pwd)/$(basename "$config")"
fi
positive() {  # NAME VALUE: VALUE must be a positive integer
  if ! [[ $2 =~ ^[1-9][0-9]*$ ]]; then
    echo "$0: $1=$2 is not a positive integer" >&2
    usage
  fi
}
processes=${PROCESSES:-1}
positive PROCESSES "$processes"
dry_run=${DRY_RUN:-0}
python=${LAUNCH_PYTHON:-.venv/bin/python}

# huge pages for large CPU buffers: see the Makefile
export GLIBC_TUNABLES="${GLIBC_TUNABLES:-glibc.malloc.hugetlb=1}"
launch_env=(GLIBC_TUNABLES)
if [ -n "${FAKE_DEVICES:-}" ]; then
  positive FAKE_DEVICES "$FAKE_DEVICES"
  export XLA_FLAGS="${XLA_FLAGS:+$XLA_FLAGS }--xla_force_host_platform_device_count=${FAKE_DEVICES}"
  launch_env+=(XLA_FLAGS)
fi
command=("$python" -m "kosmos_jax.${module}" --config="$config" "$@")

show() {  # the command line of process $1 ("" for the only one), with the environment it gets
  local name line=""
  for name in "${launch_env[@]}"; do
    line+="$name=$(quote "${!name}") "
  done
  if [ -n "$1" ]; then
    line+="KOSMOS_COORDINATOR=$coordinator KOSMOS_NUM_PROCESSES=$processes KOSMOS_PROCESS_ID=$1 "
  fi
  echo "$line$(quote "${command[@]}")"
}
pick_coordinator() {
  local port=${COORDINATOR_PORT:-}
  if [ -n "$port" ]; then
    positive COORDINATOR_PORT "$port"
  else  # a free port now (the coordinator binds it a moment later)
    port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  fi
  coordinator=127.0.0.1:$port
}

if [ "$dry_run" != 0 ] && [ -n "$dry_run" ]; then
  echo "cd $(quote "$repo")"
  if [ "$processes" = 1 ]; then
    show ""
  else
    pick_coordinator
    for ((i = 0; i < processes; i++)); do
      show "$i"
    done
  fi
  exit 0
fi
if [ "${SETUP:-1}" != 0 ]; then
  make -C "$repo" --no-print-directory setup >&2
fi
cd "$repo"
if [ "$processes" = 1 ]; then
  exec "${command[@]}"
fi

pick_coordinator
export KOSMOS_COORDINATOR=$coordinator KOSMOS_NUM_PROCESSES=$processes PYTHONUNBUFFERED=1
pids=()
stop_all() {  # TERM to the processes still running, KILL to those left after 10 s
  local pid tries=50  # "finished": already waited for
  for pid in "${pids[@]}"; do
    kill "$pid" 2>/dev/null || true
  done
  for pid in "${pids[@]}"; do
    while kill -0 "$pid" 2>/dev/null && [ "$tries" -gt 0 ]; do
      sleep 0.2
      tries=$((tries - 1))
    done
    kill -KILL "$pid" 2>/dev/null || true
  done
}
prefix() {  # copy stdin to stdout, each line after $1, as it comes
  local line
  while IFS= read -r line || [ -n "$line" ]; do
    printf '%s%s\n' "$1" "$line"
  done
}
trap stop_all EXIT
trap 'exit 130' INT
trap 'exit 143' TERM
echo "$0: $processes processes of ${command[*]} (coordinator $coordinator)" >&2
for ((i = 0; i < processes; i++)); do
  KOSMOS_PROCESS_ID=$i "${command[@]}" > >(prefix "[$i] ") 2>&1 &
  pids+=($!)
done
# Wait for all; the first failure stops the others and gives its status.
left=$processes
while [ "$left" -gt 0 ]; do
  for i in "${!pids[@]}"; do
    pid=${pids[$i]}
    if [ "$pid" != "finished" ] && ! kill -0 "$pid" 2>/dev/null; then
      status=0
      wait "$pid" || status=$?
      pids[i]="finished"
      left=$((left - 1))
      if [ "$status" != 0 ]; then
        echo "$0: process $i exited with status $status; stopping the others" >&2
        exit "$status"
      fi
    fi
  done
  sleep 0.2
done
