"""What the tests that run commands as a user does share: `python -m MODULE ...` in the repository
root on one CPU device, and a tiny training run of a few steps written by the trainer."""

import os
import pathlib
import subprocess
import sys

REPO = pathlib.Path(__file__).resolve().parents[1]


def run_module(*args) -> subprocess.CompletedProcess:
    """`python -m ARGS` as a user runs it, on one CPU device."""
    env = dict(os.environ, GLIBC_TUNABLES="glibc.malloc.hugetlb=1")
    env.pop("XLA_FLAGS", None)  # conftest's eight fake devices: only slower to compile for
    return subprocess.run([sys.executable, "-m", *map(str, args)], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=600)


def train_tiny(workdir: pathlib.Path, root: pathlib.Path, *flags: str, steps: int = 2) -> pathlib.Path:
    """`configs/kosmos_e.py:tiny` trained for `steps` steps in `workdir` (its datasets in `root`), one
    checkpoint at the end; `flags` add or override config flags."""
    done = run_module("kosmos_jax.train", "--config=configs/kosmos_e.py:tiny", f"--workdir={workdir}",
                      f"--config.data.root={root}", f"--config.train.steps={steps}",
                      f"--config.train.checkpoint_every={steps}", "--config.optimizer.warmup_steps=1", *flags)
    assert done.returncode == 0, done.stderr[-3000:]
    return workdir
