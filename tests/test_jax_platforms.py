"""kosmos_jax keeps jax from starting libtpu (and logging its errors) on a machine without a TPU."""

import importlib.util
import os
import subprocess
import sys

import pytest

from kosmos_jax import jax_platforms
from kosmos_jax.jax_platforms import tpu_chip_present


@pytest.mark.parametrize("environ, libtpu, tpu, gpu, expected", [
    ({}, True, False, False, "cpu"),
    ({}, False, False, False, None),  # no libtpu: jax starts no TPU backend anyway
    ({}, True, True, False, None),  # a TPU VM: jax must find its chips
    ({}, True, False, True, None),  # a GPU machine: jax must find the GPU
    ({"JAX_PLATFORMS": "tpu"}, True, False, False, "tpu"),  # the user's choice stands
    ({"JAX_PLATFORMS": ""}, True, False, False, ""),
])
def test_cpu_is_chosen_only_where_it_is_the_only_backend_and_the_user_chose_nothing(
        monkeypatch, environ, libtpu, tpu, gpu, expected):
    monkeypatch.setattr(jax_platforms, "libtpu_installed", lambda: libtpu)
    monkeypatch.setattr(jax_platforms, "tpu_chip_present", lambda: tpu)
    monkeypatch.setattr(jax_platforms, "nvidia_gpu_present", lambda: gpu)
    environ = dict(environ)
    jax_platforms.quiet_libtpu_without_tpu(environ)
    assert environ.get("JAX_PLATFORMS") == expected


def test_a_tpu_chip_is_found_by_its_pci_vendor(tmp_path):
    for device, vendor in (("0000:00:04.0", "0x8086\n"), ("0000:00:05.0", "0x10de\n")):
        (tmp_path / device).mkdir()
        (tmp_path / device / "vendor").write_text(vendor)
    assert not tpu_chip_present(str(tmp_path))
    (tmp_path / "0000:00:06.0").mkdir()
    (tmp_path / "0000:00:06.0" / "vendor").write_text("0x1ae0\n")
    assert tpu_chip_present(str(tmp_path))
    assert not tpu_chip_present(str(tmp_path / "missing"))


@pytest.mark.skipif(importlib.util.find_spec("libtpu") is None, reason="libtpu not installed (pip install -e '.[tpu]')")
@pytest.mark.skipif(tpu_chip_present(), reason="this machine has a TPU: jax is meant to start libtpu here")
def test_a_jax_program_after_import_kosmos_jax_logs_nothing_from_libtpu():
    environ = {key: value for key, value in os.environ.items() if key != "JAX_PLATFORMS"}
    program = "import kosmos_jax, jax.numpy as jnp; print(float(jnp.ones(3).sum()))"
    finished = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, env=environ, timeout=120)
    assert finished.returncode == 0, finished.stderr
    assert finished.stdout.strip() == "3.0"
    assert "TPU" not in finished.stderr, finished.stderr
