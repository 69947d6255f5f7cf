"""CPU speed of the baseline CNNs beside a peer (issue 24, item 3): the training step of GR-ConvNet
(RGB-D) and GG-CNN2 (depth) in this project's JAX, and of the same networks written in PyTorch, timed
in turn in one process.

    GLIBC_TUNABLES=glibc.malloc.hugetlb=1 PYTHON benchmarks/cnn_cpu.py [--out RECORD.json] [--rounds 8]

PYTHON: an environment with the project and PyTorch's CPU build (not .venv, whose tests must not see
torch), e.g. `.venv/bin/python -m venv /tmp/peer_venv && /tmp/peer_venv/bin/pip install -e '.[test]' torch`.

The networks as configs/baselines.py trains them (grconvnet_rgbd: c = 16, 4 channels; ggcnn2_d: 1
channel), batch 8 of 224 x 224 views, float32, BatchNorm in training mode. Each contestant does one
forward, backward and Adam update (lr 1e-3) on the same batch and the same fixed target maps, with
the network's published loss in both frameworks (GR-ConvNet: smooth L1, GG-CNN2: MSE, each the sum of
the four maps' means): `jax` (the project's modules, losses.per_image, optax.adam, one jitted step,
the state donated), `torch` (the same layer shapes, kernel sizes, strides and padding in NCHW,
torch.optim.Adam), `torch_channels_last` (the same in NHWC memory), and `jax_trainer` (the trainer's
own step, train.baseline_task: targets rendered from rectangles, AdamW with a schedule, norms and the
finite check: what a training run pays). Compilation and first calls are left out (a warm-up call
each); `rounds` rounds, each contestant once a round (timing.interleaved_times), so a neighbour's
load falls on all alike. FLOPs are XLA's count of the jax step, the same network for every side.
XLA_FLAGS, if set, is recorded: the runs that compare XLA:CPU options set it.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx

from baselines import baseline_configs, trainer_step  # benchmarks/baselines.py, beside this script
from timing import interleaved_times  # benchmarks/timing.py
from kosmos_jax.baselines.family import make_family
from kosmos_jax.baselines.layers import GraspMaps, input_channels
from kosmos_jax.baselines.losses import per_image
from kosmos_jax.models.flops import xla_flops
from kosmos_jax.train.baseline_task import family_config

VARIANTS = ("grconvnet_rgbd", "ggcnn2_d")
VIEW = 224
LR = 1e-3


def import_torch():
    try:
        import torch
    except ImportError:
        sys.exit("pip install torch (CPU build) to measure the peer")
    return torch


def fixed_inputs(channels: int, batch: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """NHWC images [B, H, W, C] and target maps [B, 4, H, W] (quality, cos, sin, width)."""
    rng = np.random.default_rng(seed)
    images = rng.uniform(-0.5, 0.5, (batch, VIEW, VIEW, channels)).astype(np.float32)
    targets = rng.uniform(-1.0, 1.0, (batch, 4, VIEW, VIEW)).astype(np.float32)
    return images, targets


def jax_step(variant: str, images: np.ndarray, targets: np.ndarray):
    """(zero-argument step, XLA's FLOPs of one step, parameter count) of the project's network."""
    family = make_family(family_config(baseline_configs.get_config(variant).model))
    graphdef, params, rest = family.init(0)
    tx = optax.adam(LR)
    kind = family.config.loss_kind

    def loss(params, rest, images, targets):
        network = nnx.merge(graphdef, params, rest, copy=True)
        value = jnp.mean(per_image(network(images), GraspMaps(*jnp.unstack(targets, axis=1)), kind))
        return value, nnx.split(network, nnx.Param, ...)[2]

    @functools.partial(jax.jit, donate_argnums=0)
    def step(state, images, targets):
        params, rest, opt_state = state
        (value, rest), grads = jax.value_and_grad(loss, has_aux=True)(params, rest, images, targets)
        updates, opt_state = tx.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), rest, opt_state), value

    holder = {"state": (params, rest, tx.init(params))}
    images, targets = jnp.asarray(images), jnp.asarray(targets)
    flops = xla_flops(step.lower(holder["state"], images, targets).compile())

    def one():
        holder["state"], value = step(holder["state"], images, targets)  # donated: carry it on
        return value

    return one, float(flops), int(sum(x.size for x in jax.tree.leaves(params)))


def torch_grconvnet(torch, in_channels: int, c: int = 16):
    """GR-ConvNet as grconvnet.py builds it, in NCHW: "SAME" padding, stride-2 layers padded by 1,
    PyTorch's ConvTranspose2d padding (k - s + 1) // 2, 2x2 heads padded after (XLA's SAME)."""
    nn = torch.nn

    class Residual(nn.Module):
        def __init__(self, features):
            super().__init__()
            self.body = nn.Sequential(nn.Conv2d(features, features, 3, padding=1), nn.BatchNorm2d(features),
                                      nn.ReLU(), nn.Conv2d(features, features, 3, padding=1),
                                      nn.BatchNorm2d(features))

        def forward(self, x):
            return x + self.body(x)

    def down(cin, cout, k, stride, padding):
        return [nn.Conv2d(cin, cout, k, stride=stride, padding=padding), nn.BatchNorm2d(cout), nn.ReLU()]

    def up(cin, cout, k, stride):
        return [nn.ConvTranspose2d(cin, cout, k, stride=stride, padding=(k - stride + 1) // 2),
                nn.BatchNorm2d(cout), nn.ReLU()]

    return nn.Sequential(*down(in_channels, c, 9, 1, 4), *down(c, 2 * c, 4, 2, 1), *down(2 * c, 4 * c, 4, 2, 1),
                         *[Residual(4 * c) for _ in range(5)], *up(4 * c, 2 * c, 4, 2), *up(2 * c, c, 4, 2),
                         nn.ConvTranspose2d(c, c, 9, padding=4), nn.ZeroPad2d((0, 1, 0, 1)), nn.Conv2d(c, 4, 2))


def torch_ggcnn2(torch, in_channels: int):
    """GG-CNN2 as ggcnn2.py builds it, in NCHW (filters 16, 16, 32, 16; dilations 2, 4)."""
    nn = torch.nn
    return nn.Sequential(
        nn.Conv2d(in_channels, 16, 11, padding=5), nn.ReLU(), nn.Conv2d(16, 16, 5, padding=2), nn.ReLU(),
        nn.MaxPool2d(2), nn.Conv2d(16, 16, 5, padding=2), nn.ReLU(), nn.Conv2d(16, 16, 5, padding=2), nn.ReLU(),
        nn.MaxPool2d(2), nn.Conv2d(16, 32, 5, padding=4, dilation=2), nn.ReLU(),
        nn.Conv2d(32, 32, 5, padding=8, dilation=4), nn.ReLU(),
        nn.ConvTranspose2d(32, 16, 3, stride=2, padding=1, output_padding=1), nn.ReLU(),
        nn.ConvTranspose2d(16, 16, 3, stride=2, padding=1, output_padding=1), nn.ReLU(), nn.Conv2d(16, 4, 1))


def torch_step(torch, variant: str, images: np.ndarray, targets: np.ndarray, channels_last: bool):
    """(zero-argument step, parameter count) of the PyTorch network."""
    torch.manual_seed(0)
    mode = baseline_configs.get_config(variant).model.mode
    build, loss = ((torch_grconvnet, torch.nn.functional.smooth_l1_loss) if variant.startswith("grconvnet")
                   else (torch_ggcnn2, torch.nn.functional.mse_loss))
    network = build(torch, input_channels(mode)).train()
    x = torch.from_numpy(np.ascontiguousarray(images.transpose(0, 3, 1, 2)))
    y = torch.from_numpy(targets)
    if channels_last:
        network, x = network.to(memory_format=torch.channels_last), x.contiguous(memory_format=torch.channels_last)
    optimizer = torch.optim.Adam(network.parameters(), lr=LR)

    def one():
        optimizer.zero_grad(set_to_none=True)
        predicted = network(x)
        value = sum(loss(predicted[:, i], y[:, i]) for i in range(4))
        value.backward()
        optimizer.step()
        return value.item()

    return one, sum(p.numel() for p in network.parameters())


def measure(torch, variant: str, batch: int, rounds: int) -> dict:
    images, targets = fixed_inputs(input_channels(baseline_configs.get_config(variant).model.mode), batch)
    ours, flops, jax_parameters = jax_step(variant, images, targets)
    peer, torch_parameters = torch_step(torch, variant, images, targets, channels_last=False)
    peer_nhwc, _ = torch_step(torch, variant, images, targets, channels_last=True)
    if jax_parameters != torch_parameters:
        raise AssertionError(f"{variant}: {jax_parameters} parameters in JAX, {torch_parameters} in PyTorch")
    times = interleaved_times({"jax": ours, "torch": peer, "torch_channels_last": peer_nhwc,
                               "jax_trainer": trainer_step(variant, batch)[1]}, rounds)
    best = {name: t["min"] for name, t in times.items()}
    return {"parameters": jax_parameters, "step_gflop": round(flops / 1e9, 2),
            **{f"{name}_seconds": round(s, 4) for name, s in best.items()},
            "jax_over_torch": round(best["jax"] / best["torch"], 2),
            "jax_over_torch_channels_last": round(best["jax"] / best["torch_channels_last"], 2),
            "jax_trainer_over_jax": round(best["jax_trainer"] / best["jax"], 2),
            "gflop_per_s": {name: round(flops / 1e9 / s, 1) for name, s in best.items()},
            "median_seconds": {name: round(t["median"], 4) for name, t in times.items()},
            "rounds": {name: t["rounds"] for name, t in times.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=8, help="training batch (the baselines' configs)")
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    parser.add_argument("--out", help="also write the JSON record here")
    args = parser.parse_args()
    torch = import_torch()
    start_load = [round(x, 2) for x in os.getloadavg()]
    print(f"load average at the start (1, 5, 15 min): {start_load}", file=sys.stderr, flush=True)
    measured = {}
    for variant in args.variants:
        measured[variant] = figures = measure(torch, variant, args.batch, args.rounds)
        print(f"{variant}: jax {figures['jax_seconds']:.3f} s, torch {figures['torch_seconds']:.3f} s",
              file=sys.stderr, flush=True)
    record = {"device": str(jax.devices()[0].device_kind), "jax": jax.__version__, "torch": torch.__version__,
              "torch_threads": torch.get_num_threads(), "cpu_count": os.cpu_count(),
              "xla_flags": os.environ.get("XLA_FLAGS", ""), "glibc_tunables": os.environ.get("GLIBC_TUNABLES", ""),
              "batch": args.batch, "view": f"{VIEW}x{VIEW}", "dtype": "float32", "rounds": args.rounds,
              "load_average_start": start_load, **measured,
              "load_average_end": [round(x, 2) for x in os.getloadavg()]}
    text = json.dumps(record, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
