"""The compile command: topology names, meshes of the TPU plan, the memory table, and THE train step
compiled for 8 fake CPU devices by the command line."""

import importlib.util
import json
import os
import subprocess
import sys

import pytest

from kosmos_jax.experiments.spec import load_config
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.preprocess import STORED_IMAGE_SIZE
from kosmos_jax.train import compile as train_compile
from kosmos_jax.train import plan, step
from kosmos_jax.train.mesh import batch_sharding

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COMMAND = [sys.executable, "-m", "kosmos_jax.train.compile", "--config=configs/kosmos_e.py:tiny"]


def _config(variant):
    return load_config(f"configs/kosmos_e.py:{variant}")


def _run(*args, timeout=60, **extra_env):
    env = {**os.environ, "GLIBC_TUNABLES": os.environ.get("GLIBC_TUNABLES", "glibc.malloc.hugetlb=1"), **extra_env}
    return subprocess.run([*COMMAND, *args], cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("name, devices, host_bounds", [
    ("v5e:2x2", 4, (2, 2, 1)),
    ("v5e:2x4", 8, (2, 4, 1)),  # a v5litepod-8 is one host
    ("v4:2x2x1", 4, (2, 2, 1)),
    ("v6e:2x2", 4, (2, 2, 1)),
    ("v5e:16x16", 256, (2, 2, 1)),  # 64 hosts of 4 chips
    ("v5p:4x4x4", 64, (2, 2, 1)),
    ("cpu:8", 8, None),
])
def test_topology_names(name, devices, host_bounds):
    topology = train_compile.parse_topology(name)
    assert topology.device_count == devices
    if host_bounds is not None:
        assert topology.platform == "tpu" and topology.host_bounds == host_bounds
    else:
        assert topology.platform == "cpu"


@pytest.mark.parametrize("name", ["v5e", "tpu:8", "v9:2x2", "v5e:2x0", "v5e:2x2x1x1", "cpu:0", "cpu:x", "gpu:8"])
def test_unknown_topology_is_refused(name):
    with pytest.raises(ValueError, match="unknown topology"):
        train_compile.parse_topology(name)


def test_the_batch_is_what_the_trainer_feeds_the_step():
    config = _config("paper")
    mesh = make_mesh(1, -1, 1)
    batch = train_compile.batch_spec(config, mesh)
    assert set(batch) == set(step.TRAIN_KEYS)
    assert batch["image"].shape == (64, STORED_IMAGE_SIZE, STORED_IMAGE_SIZE, 3) and batch["tokens"].shape == (64, 256)
    assert all(spec.sharding == batch_sharding(mesh) for spec in batch.values())


def test_plan_meshes_use_every_chip_and_split_the_paper_batch():
    paper = _config("paper")
    for entry in plan.PLAN:
        data, fsdp, tensor = entry.mesh
        assert data * fsdp * tensor == train_compile.parse_topology(entry.topology).device_count, entry
        assert paper.train.batch_size % (data * fsdp) == 0, entry
        planned = plan.entry_config(paper, entry)
        assert (planned.mesh.data, planned.mesh.fsdp, planned.mesh.tensor) == entry.mesh
        assert planned.model.remat == entry.remat
    assert paper.mesh.fsdp == -1 and not paper.model.remat, "entry_config must not change the config it copies"


def test_planned_runs():
    paper = _config("paper")
    runs = train_compile.planned_runs(paper, None, every_planned=True)
    assert [topology.name for _, topology in runs] == [entry.topology for entry in plan.PLAN]
    assert [config.model.remat for config, _ in runs] == [entry.remat for entry in plan.PLAN]
    with pytest.raises(ValueError, match="not both"):
        train_compile.planned_runs(paper, "v5e:2x4", every_planned=True)
    with pytest.raises(ValueError, match="give --topology"):
        train_compile.planned_runs(paper, None, every_planned=False)
    [(config, topology)] = train_compile.planned_runs(paper, "v5e:2x4", every_planned=False)
    assert config is paper and topology.device_count == 8


def test_total_counts_donated_outputs_once():
    memory = train_compile.StepMemory(argument=100, output=90, alias=80, temp=50, code=5, peak=120)
    assert memory.total == 100 + 90 - 80 + 50 + 5


def test_table_shows_gib_and_fit():
    gib = train_compile.GiB
    row = {"topology": "v5e:2x4", "devices": 8, "mesh": {"data": 1, "fsdp": 8, "tensor": 1}, "remat": False,
           "scan_layers": True, "batch_size": 64, "max_length": 256, "per_device_argument_bytes": 2 * gib,
           "per_device_output_bytes": 2 * gib, "per_device_temp_bytes": 6 * gib, "per_device_total_bytes": 8 * gib,
           "per_device_peak_bytes": 7.5 * gib,
           "hbm_bytes": 16 * gib, "fits": True, "model_flops": {"model": 3.5e15}, "xla_flops": 1.2e14,
           "compile_s": 95.4}
    header, rule, line = train_compile.format_table([row]).splitlines()
    assert header.split()[:2] == ["topology", "devices"] and set(rule) == {"-"}
    assert line.split() == ["v5e:2x4", "8", "1x8x1", "no", "yes", "64x256", "2.00", "2.00", "6.00", "8.00", "7.50", "16.00",
                            "yes", "3500", "120", "95"]


def test_a_program_too_large_for_the_chip_reports_what_it_needed():
    gib = 2**30
    whole = ("RESOURCE_EXHAUSTED: XLA:TPU compile permanent error. Ran out of memory in memory space hbm. "
             "Used 20.50G of 15.75G hbm. Exceeded hbm capacity by 4.75G.")
    assert train_compile.hbm_overflow(whole) == ("total", round(20.5 * gib), round(15.75 * gib))
    temporaries = ("RESOURCE_EXHAUSTED: Ran out of memory on HBM, the total memory required for HLO temporaries "
                   "(23.71G) exceeds available HBM (15.75G).")
    assert train_compile.hbm_overflow(temporaries) == ("temp", round(23.71 * gib), round(15.75 * gib))
    assert train_compile.hbm_overflow("INTERNAL: something else") is None
    report = train_compile.refusal_report(("temp", 20 * gib, 15 * gib), argument_bytes=2 * gib)
    assert report["per_device_total_bytes"] == 22 * gib and report["fits"] is False
    row = {"topology": "v5e:2x2", "devices": 4, "mesh": {"data": 1, "fsdp": 4, "tensor": 1}, "remat": False,
           "scan_layers": False, "batch_size": 64, "max_length": 256, "compile_s": 80.0,
           "model_flops": {"model": 3.5e15}, "xla_flops": None,
           **train_compile.refusal_report(("total", round(20.5 * gib), round(15.75 * gib)), argument_bytes=0)}
    line = train_compile.format_table([row]).splitlines()[-1]
    assert line.split() == ["v5e:2x2", "4", "1x4x1", "no", "no", "64x256", "-", "-", "-", "20.50", "-", "15.75", "NO", "3500",
                            "-", "80"]


def test_bytes_a_device_holds_of_sharded_inputs():
    mesh = make_mesh(1, -1, 1)
    batch = train_compile.batch_spec(_config("tiny"), mesh)  # 8 rows over 8 devices
    per_row = 224 * 224 * 3 + 96 * (4 + 1 + 1) + 4 + 5 * 4 + 4  # image, tokens and masks, length, grasp, example_index
    assert train_compile.sharded_bytes(batch) == per_row


def test_mesh_that_does_not_divide_the_devices_is_refused():
    config = _config("tiny")
    config.mesh.data = 3
    with pytest.raises(ValueError, match=r"cpu:8: mesh sizes \(3, 1, 1\) do not divide 8 devices"):
        train_compile.compile_plan(config, train_compile.parse_topology("cpu:8"))


@pytest.mark.slow  # 34 s (make test's --durations, 2026-11-28, 2 cores)
def test_compile_command_on_eight_cpu_devices(tmp_path):
    cache = tmp_path / "jax-cache"  # a user's persistent cache, set to keep every compile
    done = _run("--topology=cpu:8", "--json", "--config.mesh.data=2", "--config.mesh.fsdp=4", timeout=600,
                JAX_COMPILATION_CACHE_DIR=str(cache), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["topology"] == "cpu:8" and result["devices"] == 8
    assert result["mesh"] == {"data": 2, "fsdp": 4, "tensor": 1}
    parts = [result[f"per_device_{part}_bytes"] for part in ("argument", "output", "temp", "code")]
    assert result["per_device_total_bytes"] == sum(parts) - result["per_device_alias_bytes"] > 0
    # The state is donated: the new parameters and optimiser state are written over the old ones.
    assert result["per_device_alias_bytes"] > 0.9 * result["per_device_output_bytes"]
    assert result["fits"] is True and result["hbm_bytes"] > result["per_device_total_bytes"]
    assert result["per_device_peak_bytes"] is None  # the CPU backend's peak leaves temporaries out
    model = train_compile.model_flops(_config("tiny")).model
    assert result["model_flops"]["model"] == model
    assert result["xla_flops"] > model  # XLA counts the image's resize and elementwise work too
    assert result["compile_s"] > 0 and (result["batch_size"], result["max_length"]) == (8, 96)
    assert not cache.exists() or not any(cache.iterdir())  # compile_s timed a compile: nothing read or kept


@pytest.mark.slow  # 14 s (make test's --durations, 2026-11-28, 2 cores)
def test_compile_command_refuses_what_it_cannot_compile():
    unknown = _run("--topology=v9:2x2")
    assert unknown.returncode == 1 and "compile: unknown topology 'v9:2x2'" in unknown.stderr
    refused = _run("--topology=v5e:3x3")
    assert refused.returncode == 1
    assert "libtpu refuses topology v5e:3x3" in refused.stderr or "needs libtpu" in refused.stderr
    undivided = _run("--topology=cpu:8", "--config.mesh.data=3")
    assert undivided.returncode == 1 and "mesh sizes (3, 1, 1) do not divide 8 devices" in undivided.stderr


@pytest.mark.skipif(importlib.util.find_spec("libtpu") is None, reason="libtpu not installed (pip install -e '.[tpu]')")
def test_tpu_topologies_give_one_device_a_chip():
    code = ("from kosmos_jax.train.compile import parse_topology, topology_devices\n"
            "for name in ('v5e:2x4', 'v4:2x2x1', 'v6e:2x2'):\n"
            "    devices = topology_devices(parse_topology(name))\n"
            "    print(name, len(devices), devices[0].device_kind)\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.splitlines() == ["v5e:2x4 8 TPU v5 lite", "v4:2x2x1 4 TPU v4", "v6e:2x2 4 TPU v6 lite"]


@pytest.mark.slow  # 36 s (make test's --durations, 2026-12-02, 2 cores)
@pytest.mark.skipif(importlib.util.find_spec("libtpu") is None, reason="libtpu not installed (pip install -e '.[tpu]')")
def test_compile_command_on_a_tpu_topology():
    # The smallest planned topology, about a minute on 2 cores: the TPU backend analyses no lowered
    # program (cost_analysis() is None), which once crashed the command there and nowhere else.
    done = _run("--topology=v5e:2x2", "--json", timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert (result["topology"], result["devices"], result["device_kind"]) == ("v5e:2x2", 4, "TPU v5 lite")
    assert result["fits"] is True and 0 < result["per_device_peak_bytes"] <= result["hbm_bytes"]
    assert result["model_flops"]["model"] == train_compile.model_flops(_config("tiny")).model
    assert result["xla_flops"] is None or result["xla_flops"] > 0  # libtpu 0.0.42 gives the compiled program's
