"""Keep jax from starting libtpu on a machine with no TPU.

The `tpu` extra (libtpu, which `make test` and `make plan` install to compile for TPU topologies)
makes jax try a TPU backend at every start; where there is no TPU chip, libtpu logs several lines
of errors on stderr before jax falls back to the CPU. Where the CPU is the only backend that can
start anyway (no TPU chip, no NVIDIA GPU) and the user has not chosen platforms, saying so
(JAX_PLATFORMS=cpu) changes nothing but that noise. Compiling for a TPU topology is unaffected.
"""

from __future__ import annotations

import glob
import importlib.util
import os
import pathlib

GOOGLE_PCI_VENDOR = "0x1ae0"  # the PCI vendor id of TPU chips


def tpu_chip_present(pci_root: str = "/sys/bus/pci/devices") -> bool:
    for vendor in glob.glob(os.path.join(pci_root, "*", "vendor")):
        try:
            if pathlib.Path(vendor).read_text().strip() == GOOGLE_PCI_VENDOR:
                return True
        except OSError:
            continue
    return False


def nvidia_gpu_present() -> bool:
    return os.path.exists("/proc/driver/nvidia/version") or bool(glob.glob("/dev/nvidia[0-9]*"))


def libtpu_installed() -> bool:
    return importlib.util.find_spec("libtpu") is not None


def quiet_libtpu_without_tpu(environ=os.environ) -> None:
    """Set JAX_PLATFORMS=cpu where libtpu is installed and only the CPU can run jax (before jax starts)."""
    if "JAX_PLATFORMS" in environ or not libtpu_installed():
        return  # the user's choice stands; without libtpu jax starts no TPU backend
    if not tpu_chip_present() and not nvidia_gpu_present():
        environ["JAX_PLATFORMS"] = "cpu"
