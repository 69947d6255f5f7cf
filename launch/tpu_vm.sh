#!/usr/bin/env bash
# Run a kosmos_jax entry point on every worker of a TPU VM slice, through
# `gcloud compute tpus tpu-vm ssh NAME --worker=all`. Each worker runs it with KOSMOS_DISTRIBUTED=auto:
# kosmos_jax.train.distributed.initialize_from_env then calls jax.distributed.initialize(), which
# finds the slice's workers from the TPU metadata.
#
#   launch/tpu_vm.sh --name=my-v5e --zone=us-west4-a --setup train configs/kosmos_e.py:paper --workdir=gs://bucket/runs/paper
#   TPU_NAME=my-v5e ZONE=us-west4-a launch/tpu_vm.sh train.distributed_check configs/demo.py
#   DRY_RUN=1 TPU_NAME=t ZONE=z launch/tpu_vm.sh train configs/kosmos_e.py:tiny   # print the gcloud commands
#
# Options (before MODULE; each also from the environment): --name=TPU_NAME, --zone=ZONE,
# --project=PROJECT (default: gcloud's), --remote-dir=REMOTE_DIR (the repository on the workers,
# default kosmos_jax, relative to the home folder), --setup: first copy this repository's
# committed HEAD (git archive) to every worker and install it there with `pip install -e .[tpu]`
# in REMOTE_DIR/.venv. Then MODULE (under kosmos_jax), CONFIG[:ARG] (relative to the repository)
# and flags passed through. WORKDIR should be one every worker sees (a gs:// bucket).
set -euo pipefail
usage() {
  echo "usage: $0 [--name=TPU_NAME] [--zone=ZONE] [--project=PROJECT] [--remote-dir=DIR] [--setup] MODULE CONFIG[:ARG] [--flags ...]" >&2
  echo "  environment: TPU_NAME ZONE PROJECT REMOTE_DIR DRY_RUN=1" >&2
  exit 2
}
name=${TPU_NAME:-}
zone=${ZONE:-}
project=${PROJECT:-}
remote_dir=${REMOTE_DIR:-kosmos_jax}
setup=0
while [ $# -gt 0 ]; do
  case $1 in
    --name=*) name=${1#*=} ;;
    --zone=*) zone=${1#*=} ;;
    --project=*) project=${1#*=} ;;
    --remote-dir=*) remote_dir=${1#*=} ;;
    --setup) setup=1 ;;
    -h | --help) usage ;;
    -*) echo "$0: unknown option $1" >&2; usage ;;
    *) break ;;
  esac
  shift
done
if [ $# -lt 2 ] || [ -z "$name" ] || [ -z "$zone" ]; then
  [ -n "$name" ] || echo "$0: no TPU name (--name or TPU_NAME)" >&2
  [ -n "$zone" ] || echo "$0: no zone (--zone or ZONE)" >&2
  usage
fi
module=$1; config=$2; shift 2
repo=$(cd "$(dirname "$0")/.." && pwd)
# shellcheck source=launch/quote.sh
. "$repo/launch/quote.sh"
dry_run=${DRY_RUN:-0}

target=("$name" "--zone=$zone")
if [ -n "$project" ]; then
  target+=("--project=$project")
fi
run() {  # run (or under DRY_RUN print) a command
  if [ "$dry_run" != 0 ] && [ -n "$dry_run" ]; then
    quote "$@"
  else
    "$@"
  fi
}
on_workers() {  # a shell command line, run on every worker
  run gcloud compute tpus tpu-vm ssh "${target[@]}" --worker=all --command="$1"
}

dir=$(quote "$remote_dir")
if [ "$setup" = 1 ]; then
  archive=${TMPDIR:-/tmp}/kosmos_jax-$$.tar.gz
  run git -C "$repo" archive --format=tar.gz --output="$archive" HEAD
  run gcloud compute tpus tpu-vm scp "$archive" "$name:kosmos_jax.tar.gz" "${target[@]:1}" --worker=all
  on_workers "mkdir -p $dir && tar -xzf kosmos_jax.tar.gz -C $dir && rm kosmos_jax.tar.gz && cd $dir && python3 -m venv .venv && .venv/bin/pip install --quiet -e '.[tpu]'"
  if [ "$dry_run" = 0 ] || [ -z "$dry_run" ]; then
    rm -f "$archive"
  fi
fi
on_workers "cd $dir && KOSMOS_DISTRIBUTED=auto $(quote .venv/bin/python -m "kosmos_jax.$module" --config="$config" "$@")"
