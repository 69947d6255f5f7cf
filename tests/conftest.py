"""Shared test fixtures: the real data beside the repository, and eight fake CPU devices."""

import os
import pathlib

# Sharding tests need several devices; on CPU XLA can pretend. Must precede the first jax import.
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=8")

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED_DATA = pathlib.Path(os.environ.get("KOSMOS_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_path(*parts: str) -> pathlib.Path:
    """A path under ../shared/data, or skip the test with the reason when it is not there."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not found at {path} (needs ../shared/data beside the repository)")
    return path


@pytest.fixture
def cornell_root() -> pathlib.Path:
    return shared_path("cornell")


@pytest.fixture
def kosmos_e_annotations() -> pathlib.Path:
    return shared_path("kosmos-e", "instructions-original.json")


@pytest.fixture
def jacquard_root() -> pathlib.Path:
    return shared_path("jacquard")
