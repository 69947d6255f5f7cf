"""Per-op (per-thunk) time of our GR-ConvNet step and the trainer's, from a jax.profiler trace."""
import sys, glob, os, collections, re
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[4] / "benchmarks"))
import jax
from cnn_cpu import *
from jax._src.lib import _profile_data
variant = sys.argv[1]
images, targets = fixed_inputs(input_channels(baseline_configs.get_config(variant).model.mode), 8)
ours, _, _ = jax_step(variant, images, targets)
trainer = trainer_step(variant, 8)
for f in (ours, trainer):
    jax.block_until_ready(f()); jax.block_until_ready(f())
for name, f in (("ours", ours), ("trainer", trainer)):
    d = f"/tmp/cnnprobe/trace_{variant}_{name}"
    os.system(f"rm -rf {d}")
    with jax.profiler.trace(d):
        for _ in range(2):
            jax.block_until_ready(f())
    path = glob.glob(f"{d}/**/*.xplane.pb", recursive=True)[0]
    data = _profile_data.ProfileData.from_file(path)
    totals = collections.Counter()
    for plane in data.planes:
        for line in plane.lines:
            for ev in line.events:
                totals[(plane.name[:20], line.name[:30], ev.name[:70])] += ev.duration_ns / 2e6  # ms a step
    print("==", name)
    for k, v in totals.most_common(45):
        print("%9.1f ms  %s" % (v, k))
