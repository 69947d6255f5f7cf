# shellcheck shell=bash
# Source at the start of a command on the lent GPU machine (the `run` tool, carry [".whl"]), from
# the repo root:
#
#     source launch/device_env.sh || exit 1
#     python3 -m kosmos_jax.train --config=configs/kosmos_e.py:demo --workdir=/tmp/w --config.train.steps=300
#     python3 -m kosmos_jax.evaluate --workdir=/tmp/w --json
#
# (2026-11-24 on the H100: the install took 3 s, that training 204 s with its dataset build and
# evaluations, 0.039 s a step at batch 32, and the evaluation 55 s.)
#
# That machine has python3 3.12 with jax 0.11.2 and its CUDA plugin, and no network. The packages it
# lacks, and the project's pins of pure-Python ones (optax, orbax-checkpoint, ...), travel as
# wheels in the git-ignored folder .whl (name it in the call's `carry`). They are installed here with
# --no-deps into /tmp/site, which goes first on PYTHONPATH, so they shadow the machine's versions
# while jax, jaxlib, numpy, opencv and matplotlib stay the machine's own (the first four too big to carry;
# matplotlib draws only the data-size plot).
#
# Filling .whl on a machine with pip and a network (python 3.12, manylinux x86_64), one version of each:
#     launch/device_env.sh --download
# The list is DEVICE_WHEELS below. It was checked complete against the machine's package list
# (/work/.library/device/KINDS.md) by each wheel's Requires-Dist, and by a python 3.12 venv holding
# jax 0.11.2 and the machine's other packages in which the tiny config trained and evaluated.

DEVICE_WHEELS=(
  # missing on the machine
  ml-collections==1.1.0 grain==0.2.18 array-record==0.8.6 tensorflow-datasets==4.9.10 tensorboardX==2.6.5
  dm-tree==0.1.10 immutabledict==4.3.1 simple-parsing==0.1.9 docstring-parser==0.18.0
  tensorflow-metadata==1.21.0 googleapis-common-protos==1.76.0 termcolor==3.3.0 toml==0.10.2
  portpicker==1.6.0
  # the project's pins (and the versions its suite ran with) over the machine's own
  absl-py==2.5.1 optax==0.2.8 orbax-checkpoint==0.12.8 tqdm==4.70.1 tifffile==2026.3.3
  sentencepiece==0.2.3 etils==1.15.0 protobuf==7.36.2 tensorstore==0.1.86
  # not the pin 0.12.8: flax up to 0.12.9 subclasses jax.experimental.hijax.HiPrimitive, which jax 0.11
  # no longer has (AttributeError on `from flax import nnx`); 0.12.10 is the first flax that imports there
  flax==0.12.10
)
# promise 2.3 (a tensorflow-datasets requirement) is published as source only: --download builds its wheel.

device_env_download() {
  local platforms=() n
  for n in 17 24 27 28 31 34 35; do platforms+=(--platform "manylinux_2_${n}_x86_64"); done
  platforms+=(--platform manylinux2014_x86_64 --platform manylinux1_x86_64)
  mkdir -p .whl &&
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      "${platforms[@]}" -d .whl "${DEVICE_WHEELS[@]}" &&
    python3 -m pip wheel -q --no-deps --no-binary=:all: -w .whl promise==2.3
}

device_env_install() {
  if ! compgen -G ".whl/*.whl" >/dev/null; then
    echo "device_env.sh: no wheels in .whl (run from the repo root and name .whl in the run's carry)" >&2
    return 1
  fi
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
    .whl/*.whl || return 1
  export PYTHONPATH="/tmp/site${PYTHONPATH:+:$PYTHONPATH}"
  export PYTHONUNBUFFERED=1
}

if [[ "${BASH_SOURCE[0]}" == "$0" ]]; then  # executed, not sourced
  if [[ "${1:-}" == "--download" ]]; then
    device_env_download
    exit $?
  fi
  echo "usage: source launch/device_env.sh (on the device) | launch/device_env.sh --download (here)" >&2
  exit 2
fi
device_env_install
