"""Shared test fixtures: the real data beside the repository, and eight fake CPU devices.

Fixtures that train a run or build a dataset are session-scoped even where one module uses them:
under xdist a worker interleaves the tests of several modules, and pytest tears a module-scoped
fixture down (and builds it again) whenever another module's test comes between two of its own.
"""

import os
import pathlib
import subprocess
import sys

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


@pytest.fixture
def dead_pid() -> int:
    """The pid of a process that has already exited (for staging folders of killed writers)."""
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(finished.stdout)


@pytest.fixture(scope="session")
def synthetic_15(tmp_path_factory) -> pathlib.Path:
    """15 synthetic Cornell-format photos of seed 0 (5 objects: enough for 5 object-wise folds), made
    once a session for the modules that build datasets from them."""
    import shutil

    from kosmos_jax.sources.synthetic import scenes
    root = tmp_path_factory.mktemp("synthetic_15")
    shutil.rmtree(root)
    scenes.write_dataset(root, photos=15, seed=0)
    return root
