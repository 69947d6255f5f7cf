"""The Makefile's malloc settings, as `make -n demo` prints them and as a probe target's recipe (an echo) sees
them: make demo keeps freed memory mapped, every other target uses huge pages alone, and a GLIBC_TUNABLES the
caller gives wins everywhere."""

import os
import re
import shutil
import subprocess

import pytest

from user_commands import REPO

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
MAKEFILE = (REPO / "Makefile").read_text()
KEEP_FREED = re.search(r"^KEEP_FREED := (\S+)$", MAKEFILE, re.M).group(1)
HUGE_PAGES = re.search(r"^export GLIBC_TUNABLES \?= (\S+)$", MAKEFILE, re.M).group(1)


def make(*arguments: str, environment: dict | None = None) -> str:
    # a clean caller: no setting of its own, nor a parent make's flags (make test runs this suite)
    env = {key: value for key, value in os.environ.items()
           if key not in ("GLIBC_TUNABLES", "MAKEFLAGS", "MFLAGS", "MAKELEVEL")} | (environment or {})
    done = subprocess.run(["make", "--no-print-directory", *arguments], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout


def demo_line(*assignments: str, environment: dict | None = None) -> str:
    """The line `make -n demo` prints for the demo module (nothing runs)."""
    printed = make("-n", "demo", *assignments, environment=environment)
    return next(line for line in printed.splitlines() if " -m kosmos_jax.demo " in line)


def exported_to_other_targets(*assignments: str, environment: dict | None = None) -> str:
    """GLIBC_TUNABLES as a recipe of any other target sees it: a probe target added with --eval echoes it."""
    return make("--eval", "probe-tunables: ; @echo $$GLIBC_TUNABLES", "probe-tunables", *assignments,
                environment=environment).strip()


def test_make_demo_keeps_freed_memory_mapped_and_the_other_targets_do_not():
    assert KEEP_FREED.startswith(HUGE_PAGES + ":") and "trim_threshold" in KEEP_FREED
    assert demo_line().startswith(f"GLIBC_TUNABLES={KEEP_FREED} ")
    assert exported_to_other_targets() == HUGE_PAGES


@pytest.mark.parametrize("how", ["environment", "command line"])
def test_a_setting_the_caller_gives_wins_in_make_demo_and_elsewhere(how):
    given = "glibc.malloc.hugetlb=0"
    assignments, environment = ((), {"GLIBC_TUNABLES": given}) if how == "environment" else ((f"GLIBC_TUNABLES={given}",), None)
    assert demo_line(*assignments, environment=environment).startswith(f"GLIBC_TUNABLES={given} ")
    assert exported_to_other_targets(*assignments, environment=environment) == given
