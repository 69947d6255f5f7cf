"""README.md's commands, run or checked, so that the README cannot drift from the code.

Every command in README.md's code blocks is either run or checked:
- run, in a sandbox folder that links configs/, launch/ and results/ (so paths resolve as in the repository),
  with this interpreter's bin folder first on PATH (`python`, `kosmos-grasp`): the tiny training
  command, its steps cut to 2, writes runs/tiny once for the module; the commands that use
  runs/tiny (evaluate, predict, the Python blocks, on a synthetic photo), --check_only and
  --aggregate_only sweeps and every launch script with DRY_RUN=1 (sbatch runs the script with
  bash) are run as written;
- checked, when expensive or needing files that are not here (make demo, a sweep, the TPU plan and
  its compiles, KOSMOS-2 weights under PATH/TO, ../shared/data): only what they name, as every
  command is.
What a command names, in code blocks and inline code alike: each `python -m MODULE` is a runnable
module, each `kosmos-grasp COMMAND` a command of kosmos_jax/cli.py, each `make TARGET` a Makefile
target, each configs/*.py[:VARIANT] a config whose get_config takes the variant, each
`--config.a.b=...` a field of its command's config, each other flag one its module's --help lists,
and each path under launch/, benchmarks/, notebooks/, tests/, kosmos_jax/ or configs/ a file or
folder that exists (results/ is written by whoever runs the experiments).
"""

from __future__ import annotations

import functools
import importlib.util
import json
import os
import pathlib
import re
import shlex
import shutil
import subprocess
import sys

import ml_collections
import pytest

from kosmos_jax import cli
from kosmos_jax.experiments import spec

REPO = pathlib.Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()
BIN = pathlib.Path(sys.executable).parent
FAST = ["--config.train.steps=2", "--config.train.checkpoint_every=2", "--config.optimizer.warmup_steps=1"]
TINY_RUN = "runs/tiny"
NOT_HERE = ("PATH/TO", "../shared/", "JOBID")  # placeholders, and data that may not be beside the repository
SHELLS = ("", "sh", "bash", "shell")
PATH_PREFIXES = ("launch/", "benchmarks/", "notebooks/", "tests/", "kosmos_jax/", "configs/")

pytestmark = pytest.mark.xdist_group("readme_commands")  # one worker: the tiny run is shared

# -- reading the README ------------------------------------------------------------------------------


def code_blocks(text: str) -> list[tuple[str, str]]:
    """(language, body) of every fenced block."""
    return [(m.group(1).strip(), m.group(2)) for m in re.finditer(r"^```([\w-]*)\n(.*?)^```", text, re.M | re.S)]


def shell_commands(text: str) -> list[list[str]]:
    """The words of each command line of the shell blocks (comments dropped, `\\` lines joined)."""
    commands = []
    for language, body in code_blocks(text):
        if language in SHELLS:
            for line in body.replace("\\\n", " ").splitlines():
                words = shlex.split(line, comments=True)
                if words:
                    commands.append(words)
    return commands


def python_blocks(text: str) -> list[str]:
    return [body for language, body in code_blocks(text) if language == "python"]


def code_text(text: str) -> str:
    """The code blocks and inline code spans: where the README names commands and paths."""
    blocks = [body for _, body in code_blocks(text)]
    prose = re.sub(r"^```.*?^```", "", text, flags=re.M | re.S)
    return "\n".join(blocks + re.findall(r"`([^`\n]+)`", prose))


def split_env(words: list[str]) -> tuple[dict[str, str], list[str]]:
    """(VAR=value assignments before the command, the command's words)."""
    env = {}
    while words and re.fullmatch(r"[A-Z_][A-Z0-9_]*=.*", words[0]):
        name, _, value = words[0].partition("=")
        env[name] = value
        words = words[1:]
    return env, words


def label(words: list[str]) -> str:
    return shlex.join(words)[:140]


COMMANDS = shell_commands(README)
PYTHON_BLOCKS = python_blocks(README)

# -- what a command is -------------------------------------------------------------------------------


def launch_script(argv: list[str]) -> tuple[str, list[str]] | None:
    """(script, its arguments) of a launch-script command (`launch/x.sh ...`, `bash launch/x ...`,
    `sbatch [options] launch/x ...`); None for any other command. device_env.sh is not a launcher."""
    if argv[0] in ("bash", "sbatch"):
        rest = argv[1:]
        while rest and rest[0].startswith("-"):
            rest = rest[1:]
        argv = rest
    if argv and argv[0].startswith("launch/") and argv[0] != "launch/device_env.sh":
        return argv[0], argv[1:]
    return None


def module_of(argv: list[str]) -> str | None:
    """The module a `python -m M ...` or `kosmos-grasp COMMAND ...` command runs."""
    if argv[:2] == ["python", "-m"] and len(argv) > 2:
        return argv[2]
    if argv[0] == "kosmos-grasp" and len(argv) > 1 and argv[1] in cli.COMMANDS:
        return cli.COMMANDS[argv[1]][0]
    return None


def is_tiny_training(argv: list[str]) -> bool:
    return (module_of(argv) == "kosmos_jax.train" and "--config=configs/kosmos_e.py:tiny" in argv
            and f"--workdir={TINY_RUN}" in argv)


def is_cheap(words: list[str]) -> bool:
    """Run by this test (else only checked)."""
    env, argv = split_env(words)
    if launch_script(argv):
        return True  # printed, not run: DRY_RUN=1
    line = " ".join(words)
    if any(marker in line for marker in NOT_HERE) or argv[0] in ("make", "source") or argv[0].endswith("device_env.sh"):
        return False
    module = module_of(argv)
    if module is None:
        return False
    if "--help" in argv or "--check_only" in argv or "--aggregate_only" in argv or is_tiny_training(argv):
        return True
    return module not in ("kosmos_jax.train", "kosmos_jax.train.compile") and TINY_RUN in line


CHEAP = [c for c in COMMANDS if is_cheap(c)]
CHECKED = [c for c in COMMANDS if not is_cheap(c)]

# -- what the README names exists ------------------------------------------------------------------


def make_targets() -> set[str]:
    return set(re.findall(r"^([\w-]+):", (REPO / "Makefile").read_text(), re.M))


def runnable(module: str) -> bool:
    try:
        found = importlib.util.find_spec(module)
    except ModuleNotFoundError:
        return False
    if found is None:
        return False
    return not found.submodule_search_locations or importlib.util.find_spec(f"{module}.__main__") is not None


@functools.cache
def config_of(spec_text: str) -> ml_collections.ConfigDict:
    return spec.load_config(spec_text)


def config_spec(argv: list[str]) -> str | None:
    """FILE:VARIANT of the config a command passes (`--config=...`, or a launcher's argument)."""
    for word in argv:
        if word.startswith("--config="):
            return word.partition("=")[2]
    return next((w for w in argv if re.fullmatch(r"configs/[\w/]+\.py(:\w+)?", w)), None)


def has_field(config, dotted: str) -> bool:
    node = config
    for part in dotted.split("."):
        if not isinstance(node, ml_collections.ConfigDict) or part not in node:
            return False
        node = node[part]
    return True


def test_the_opening_shows_the_two_commands():
    assert README.startswith("# kosmos_jax\n\n```\nmake demo\nmake test\n```\n")


def test_the_readme_has_commands_of_every_kind():
    """The README keeps cheap commands of each section, so this test keeps running them."""
    cheap = [" ".join(c) for c in CHEAP]
    for needle in ("kosmos_jax.train --config=configs/kosmos_e.py:tiny --workdir=runs/tiny", "kosmos_jax.evaluate",
                   "predict --workdir=runs/tiny", "--check_only", "--aggregate_only", "DRY_RUN=1",
                   "launch/local.sh", "launch/tpu_vm.sh", "launch/slurm.sbatch", "launch/slurm_array.sbatch"):
        assert any(needle in c for c in cheap), f"no command the test runs has {needle!r}"
    assert PYTHON_BLOCKS and any("GraspPredictor" in block for block in PYTHON_BLOCKS)


def test_named_modules_commands_targets_and_paths_exist():
    named = code_text(README)
    modules = set(re.findall(r"python -m ([a-z_][\w.]*)", named))
    assert "kosmos_jax.train" in modules
    assert not [m for m in sorted(modules) if not runnable(m)], "README names modules that `python -m` cannot run"
    subcommands = set(re.findall(r"kosmos-grasp ([a-z][\w-]*)", named))
    assert subcommands and subcommands <= set(cli.COMMANDS), subcommands - set(cli.COMMANDS)
    targets = set(re.findall(r"\bmake ([a-z][\w-]*)", named))
    assert {"demo", "test", "plan"} <= targets and targets <= make_targets(), targets - make_targets()
    paths = {p.rstrip(".,") for p in re.findall(r"(?<![\w./])((?:%s)[\w./-]*)" % "|".join(PATH_PREFIXES), named)}
    missing = sorted(p for p in paths if not (REPO / p.partition(":")[0]).exists())
    assert not missing, f"README names paths that do not exist: {missing}"
    configs = set(re.findall(r"(configs/[\w/]+\.py(?::\w+)?)", named))
    assert "configs/kosmos_e.py:tiny" in configs
    for config in sorted(configs):
        config_of(config)  # an unknown variant raises the config file's own error


def overrides_of(argv: list[str]) -> list[str]:
    return [w.partition("=")[0].removeprefix("--config.") for w in argv if w.startswith("--config.")]


def flags_of(argv: list[str]) -> set[str]:
    return {w[2:].partition("=")[0] for w in argv if w.startswith("--") and not w.startswith("--config.")} - {"help"}


@pytest.mark.parametrize("words", [c for c in COMMANDS if overrides_of(split_env(c)[1])], ids=label)
def test_every_config_override_is_a_field(words):
    _, argv = split_env(words)
    overrides = overrides_of(argv)
    spec_text = config_spec(argv)
    assert spec_text, f"{label(words)}: --config.* overrides without a config"
    config = config_of(spec_text)
    assert not [o for o in overrides if not has_field(config, o)], f"{label(words)}: {spec_text} lacks these fields"


@functools.cache
def help_text(module: str) -> str:
    """`kosmos-grasp COMMAND --help` of the command that runs `module`, else `python -m module --help`."""
    name = next((n for n, (m, _, _) in cli.COMMANDS.items() if m == module), None)
    argv = [str(BIN / "kosmos-grasp"), name] if name else [sys.executable, "-m", module]
    done = subprocess.run([*argv, "--help"], capture_output=True, text=True, timeout=120, cwd=REPO, env=sandbox_env())
    text = done.stdout + done.stderr
    assert done.returncode == 0 and "--help" in text, f"{shlex.join(argv)} --help: {text[-2000:]}"
    return text


@pytest.mark.parametrize("name", sorted(cli.COMMANDS))
def test_each_kosmos_grasp_command_has_help(name):
    text = help_text(cli.COMMANDS[name][0])
    assert "usage" in text.lower() or "flags:" in text.lower(), text[-2000:]


@pytest.mark.parametrize("words", [c for c in COMMANDS if module_of(split_env(c)[1]) and flags_of(split_env(c)[1])],
                         ids=label)
def test_every_flag_is_one_the_module_takes(words):
    _, argv = split_env(words)
    flags = flags_of(argv)
    text = help_text(module_of(argv))
    listed = lambda flag: re.search(r"--(\[no\])?%s(?![\w-])" % re.escape(flag), text)  # absl: --[no]flag
    assert not [f for f in sorted(flags) if not listed(f)], f"{label(words)}: flags its --help lacks"


@pytest.mark.parametrize("words", CHECKED, ids=label)
def test_checked_commands_name_what_exists(words):
    """A command not run here: its program (make target, module, launch file, benchmark script) exists."""
    _, argv = split_env(words)
    if argv[0] == "make":
        assert argv[1] in make_targets()
    elif argv[0] == "source" or argv[0].endswith("device_env.sh"):
        assert (REPO / argv[-1 if argv[0] == "source" else 0]).is_file()
    elif argv[0] == "python" and argv[1].startswith("benchmarks/"):
        assert (REPO / argv[1]).is_file(), f"{label(words)}: no such benchmark"
    else:
        module = module_of(argv)
        assert module and runnable(module), f"{label(words)}: neither a make target, a launcher nor a module"

# -- running the cheap ones ------------------------------------------------------------------------


def sandbox_env(**extra: str) -> dict[str, str]:
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", "JAX_PLATFORMS": "cpu",
           "GLIBC_TUNABLES": "glibc.malloc.hugetlb=1", **extra}
    env.pop("XLA_FLAGS", None)  # conftest's eight fake devices: one is enough here, and faster to compile for
    return env


@pytest.fixture(scope="session")
def sandbox(tmp_path_factory) -> pathlib.Path:
    """A folder where README commands run as in the repository, holding runs/tiny (the README's tiny
    training command, 2 steps) and photo.png (a synthetic scene's photo)."""
    root = tmp_path_factory.mktemp("readme")
    for name in ("configs", "launch", "results"):  # results/: the committed fold records a sweep can carry in
        (root / name).symlink_to(REPO / name)
    training = next((c for c in CHEAP if is_tiny_training(split_env(c)[1])), None)
    assert training, "README has no tiny training command"
    done = run(root, training)
    assert done.returncode == 0, done.stderr[-3000:]
    photo = min(root.glob("datasets/synthetic-*/**/*r.png"))
    shutil.copyfile(photo, root / "photo.png")
    return root


def run(root: pathlib.Path, words: list[str]) -> subprocess.CompletedProcess:
    """One README command in `root`: launch scripts under DRY_RUN=1, tiny training with FAST steps."""
    env, argv = split_env(words)
    script = launch_script(argv)
    if script:
        path, arguments = script
        argv = ["bash", path, *arguments]
        env = {"DRY_RUN": "1", "SLURM_ARRAY_TASK_ID": "0", **env}
    elif is_tiny_training(argv):
        argv = [*argv, *FAST]
    return subprocess.run(argv, cwd=root, env=sandbox_env(**env), capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("words", CHEAP, ids=label)
def test_cheap_command_runs(sandbox, words):
    done = run(sandbox, words)
    assert done.returncode == 0, f"{label(words)}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    _, argv = split_env(words)
    if launch_script(argv):
        assert "kosmos_jax." in done.stdout, done.stdout  # the command it would run
    if "--json" in argv:
        record = json.loads(done.stdout.strip().splitlines()[-1])
        assert ("accuracy" in record) or {"x", "y", "theta"} <= set(record)
    for word in argv:
        if word.startswith("--out="):
            assert (sandbox / word.partition("=")[2]).read_bytes()[:4] == b"\x89PNG"
        if word.startswith("--overlays="):
            assert list(sandbox.glob(f"{TINY_RUN}/eval/*/overlays/*.png"))


@pytest.mark.parametrize("block", PYTHON_BLOCKS, ids=lambda b: b.strip().splitlines()[-1][:60])
def test_python_block_runs(sandbox, block):
    done = subprocess.run([sys.executable, "-c", block], cwd=sandbox, env=sandbox_env(), capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
