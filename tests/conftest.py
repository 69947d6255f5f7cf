"""Shared test fixtures: the real data beside the repository, eight fake CPU devices, and XLA's
persistent compilation cache.

Fixtures that train a run or build a dataset are session-scoped even where one module uses them:
under xdist a worker interleaves the tests of several modules, and pytest tears a module-scoped
fixture down (and builds it again) whenever another module's test comes between two of its own.
"""

import hashlib
import importlib.util
import os
import pathlib
import platform
import subprocess
import sys

REPO = pathlib.Path(__file__).resolve().parents[1]

# Sharding tests need several devices; on CPU XLA can pretend. Must precede the first jax import.
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=8")


def cpu_features() -> str:
    """The host CPU's feature flags (Linux), else its name: XLA:CPU compiles for the features it finds."""
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def compilation_cache_dir() -> pathlib.Path:
    """Where the suite keeps its compiled programs: one folder per CPU feature set, since a checkout
    may move between machines and XLA refuses an executable built for features the host lacks."""
    features = hashlib.sha256(cpu_features().encode()).hexdigest()[:12]
    return REPO / ".pytest_cache" / f"jax-compilation-{platform.machine()}-{features}"


# The tiny models the suite trains compile the same programs again and again: in each xdist worker,
# in every subprocess a test starts (all inherit this environment) and in `make test-slow` after
# `make test`. XLA's persistent cache compiles each once, small programs too (most of the suite's
# compiles take under a second, and they add up). A bounded size turns on the cache's file lock
# (the `filelock` package of the test extra), which the two workers need to share one folder.
# JAX_ENABLE_COMPILATION_CACHE=false turns it off; the compile command and the benchmark that time
# compiles turn it off themselves.
if importlib.util.find_spec("filelock") is not None:
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(compilation_cache_dir()))
    os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(4 * 2**30))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

import pytest

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
