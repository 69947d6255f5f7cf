"""`kosmos-grasp`: every subcommand fronts its module (its --help is the module's own), the command
table, and `import kosmos_jax` staying light (GraspPredictor imported on first use, no jax before).
The end-to-end `kosmos-grasp predict --json` on a trained run is in tests/test_predict.py."""

import importlib.util
import os
import shutil
import subprocess
import sys

import pytest

from kosmos_jax import cli

ENV = dict(os.environ, GLIBC_TUNABLES="glibc.malloc.hugetlb=1")


def run(*argv) -> subprocess.CompletedProcess:
    return subprocess.run(list(argv), env=ENV, capture_output=True, text=True, timeout=300)


def kosmos_grasp() -> str:
    """The installed console script, beside this interpreter (pip install -e . writes it)."""
    script = shutil.which("kosmos-grasp", path=os.path.dirname(sys.executable))
    if script is None:
        pytest.fail("kosmos-grasp is not installed beside this Python: run `pip install -e .`")
    return script


def test_the_top_level_help_lists_every_command():
    done = run(kosmos_grasp(), "--help")
    assert done.returncode == 0
    for name in ("build", "train", "evaluate", "experiments", "plan", "predict"):
        assert f"\n  {name} " in done.stdout
    assert run(kosmos_grasp()).returncode == 2
    unknown = run(kosmos_grasp(), "fly")
    assert unknown.returncode == 2 and "error: unknown command 'fly'" in unknown.stderr


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_each_command_shows_its_modules_own_help(name):
    module, fixed, _ = cli.COMMANDS[name]
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{module} is not in this checkout yet")
    fronted = run(kosmos_grasp(), name, "--help")
    direct = run(sys.executable, "-m", module, *fixed, "--help")
    assert (fronted.returncode, fronted.stdout) == (direct.returncode, direct.stdout)
    assert fronted.returncode == 0
    assert "--" in fronted.stdout and len(fronted.stdout.splitlines()) > 3, fronted.stdout + fronted.stderr


def test_plan_is_compile_with_plan_and_the_rest_pass_through():
    assert cli.command_line("plan", ["--config=configs/kosmos_e.py:paper"]) == [
        sys.executable, "-m", "kosmos_jax.train.compile", "--plan", "--config=configs/kosmos_e.py:paper"]
    assert cli.command_line("train", ["--workdir=w"])[2:] == ["kosmos_jax.train", "--workdir=w"]


def test_a_missing_module_is_said_not_raised(monkeypatch, capsys):
    monkeypatch.setitem(cli.COMMANDS, "experiments", ("kosmos_jax.no_such_stage", (), "absent"))
    assert cli.main(["experiments", "--help"]) == 1
    assert "error: kosmos-grasp experiments runs kosmos_jax.no_such_stage" in capsys.readouterr().err


def test_the_predictor_is_exported_lazily():
    code = ("import sys, kosmos_jax, kosmos_jax.cli, kosmos_jax.predict; assert 'jax' not in sys.modules; "
            "from kosmos_jax import GraspPredictor, Grasp; assert 'jax' in sys.modules; "
            "print(GraspPredictor.__module__, Grasp.__name__)")
    done = run(sys.executable, "-c", code)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["kosmos_jax.predict.predictor", "Grasp"]
