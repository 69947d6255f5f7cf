"""A/B in one process: GR-ConvNet step with the project's strided convs vs space-to-depth (candidate), and torch."""
import sys, json, os, importlib.util, contextlib
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[4] / "benchmarks"))
import jax, numpy as np
import cnn_cpu
from cnn_cpu import *
from flax import nnx
import kosmos_jax.baselines.grconvnet as grc
import kosmos_jax.baselines.layers as layers
spec = importlib.util.spec_from_file_location("strided", "/tmp/candidate/kosmos_jax/baselines/strided.py")
strided = importlib.util.module_from_spec(spec); spec.loader.exec_module(strided)
original = layers.conv
def candidate_conv(in_features, out_features, kernel, *, rngs, stride=1, dilation=1):
    extra = {"conv_general_dilated": strided.space_to_depth_conv} if stride > 1 else {}
    return nnx.Conv(in_features, out_features, (kernel, kernel), strides=stride, kernel_dilation=dilation,
                    padding="SAME", kernel_init=layers.xavier, kernel_metadata=layers.KERNEL_AXES,
                    bias_metadata=layers.VECTOR_AXES, rngs=rngs, **extra)
@contextlib.contextmanager
def patched():
    grc.conv = candidate_conv
    try: yield
    finally: grc.conv = original
torch = import_torch()
variant = "grconvnet_rgbd"
images, targets = fixed_inputs(4, 8)
main_step, flops_main, _ = jax_step(variant, images, targets)
with patched():
    cand_step, flops_cand, _ = jax_step(variant, images, targets)
    cand_trainer = trainer_step(variant, 8)
main_trainer = trainer_step(variant, 8)
a, b = float(main_step()), float(cand_step())
first = {"first_step_loss_main": a, "first_step_loss_space_to_depth": b, "relative_difference": abs(a - b) / abs(a), "step_gflop_main": round(flops_main / 1e9, 2), "step_gflop_space_to_depth": round(flops_cand / 1e9, 2)}
load_start = [round(x, 2) for x in os.getloadavg()]
peer, _ = torch_step(torch, variant, images, targets, channels_last=False)
calls = {"jax_main": main_step, "jax_space_to_depth": cand_step, "torch": peer}
if os.environ.get("TRAINER"):
    calls.update(trainer_main=main_trainer, trainer_space_to_depth=cand_trainer)
t = interleaved_times(calls, rounds=int(os.environ.get("ROUNDS", 6)))
print(json.dumps({"command": "GLIBC_TUNABLES=glibc.malloc.hugetlb=1 ROUNDS=%s TRAINER=%s /tmp/peer_venv/bin/python ab.py" % (os.environ.get("ROUNDS", 6), os.environ.get("TRAINER", "")), "jax": jax.__version__, "torch": torch.__version__, "torch_threads": torch.get_num_threads(), "load_average_start": load_start, "load_average_end": [round(x, 2) for x in os.getloadavg()], **first, **{k: {"min": round(v["min"], 4), "median": round(v["median"], 4), "rounds": v["rounds"]} for k, v in t.items()}}, indent=1))
