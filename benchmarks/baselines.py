"""Baselines benchmark, one run: the training step and prediction images per second of GR-ConvNet
(RGB-D) and GG-CNN2 (depth) beside the `small` KOSMOS-E's, and the ratios.

    GLIBC_TUNABLES=glibc.malloc.hugetlb=1 .venv/bin/python benchmarks/baselines.py [--batch 8 --predict-batch 16]

The baselines as configs/baselines.py trains them (grconvnet_rgbd: c = 16, 4 channels; ggcnn2_d: 1
channel; 224 x 224 views): the trainer's own baseline step (train.baseline_task: targets drawn from the
batch's rectangles, published loss, Adam) and their prediction (baselines.family: the maps, then the
peak of the blurred quality map). KOSMOS-E `small` (the project's tokenizer, random weights): the
trainer's step at its config's length (benchmarks/train.py's full_step), and one grasp an image the way
the evaluate command decodes it: greedy, with the grasp grammar, the location answer then the angle
answer (benchmarks/decode.py's prompts). Every step has the same batch; compilation is left out
(a warm-up call each). The load average is printed first: the machine is shared, so the absolute
figures move with it, the ratios (measured minutes apart in one run) less.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np

from decode import project_tokenizer, prompts  # benchmarks/decode.py, beside this script
from timing import best_time  # benchmarks/timing.py
from train import full_step, random_batch  # benchmarks/train.py
from kosmos_jax.baselines.family import make_family
from kosmos_jax.baselines.layers import input_channels
from kosmos_jax.models import config as config_lib
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.scoring.model_answers import Decoder
from kosmos_jax.scoring.questions import questions
from kosmos_jax.text import tokens as special
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.train.baseline_task import family_config, initial_state, make_baseline_step
from kosmos_jax.train.mesh import replicated
from kosmos_jax.train.optimizer import make_optimizer

REPO = pathlib.Path(__file__).resolve().parents[1]
# configs/baselines.py by its path: the name `baselines` alone would find this script
_spec = importlib.util.spec_from_file_location("baseline_configs", REPO / "configs" / "baselines.py")
baseline_configs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(baseline_configs)

VARIANTS = ("grconvnet_rgbd", "ggcnn2_d")
VIEW = 224


def say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def view_batch(channels: int, batch: int, seed: int = 0) -> dict:
    """Normalised-looking views and three rectangles a view inside them (of eight slots)."""
    rng = np.random.default_rng(seed)
    grasps = np.zeros((batch, 8, 5), np.float32)
    grasps[:, :3] = np.stack([rng.uniform(40, VIEW - 40, (batch, 3)), rng.uniform(40, VIEW - 40, (batch, 3)),
                              rng.uniform(20, 60, (batch, 3)), rng.uniform(10, 30, (batch, 3)),
                              rng.uniform(-np.pi / 2, np.pi / 2, (batch, 3))], axis=-1)
    mask = np.zeros((batch, 8), bool)
    mask[:, :3] = True
    images = rng.uniform(-0.5, 0.5, (batch, VIEW, VIEW, channels)).astype(np.float32)
    return {"image": jnp.asarray(images), "grasps": jnp.asarray(grasps), "mask": jnp.asarray(mask)}


def trainer_step(variant: str, batch: int):
    """The trainer's own step of one configs/baselines.py variant on one device, compiled on first call:
    (family, call: one step of no argument, state: the state now, which each call donates and replaces)."""
    config = baseline_configs.get_config(variant)
    family = make_family(family_config(config.model))
    mesh = make_mesh(1, 1, 1, devices=jax.devices()[:1])
    tx, schedule = make_optimizer(config.optimizer, config.train.steps)
    state = initial_state(family, tx, config.train.seed)
    sharding = jax.tree.map(lambda _: replicated(mesh), state)
    step = make_baseline_step(family, tx, schedule, mesh, sharding)
    inputs = view_batch(input_channels(family.config.mode), batch)
    holder = {"state": jax.device_put(state, sharding)}

    def one():
        holder["state"], metrics = step(holder["state"], inputs)  # the state is donated: carry it on
        return metrics

    return family, one, lambda: holder["state"]


def baseline(variant: str, batch: int, predict_batch: int) -> dict:
    """The trainer's step and the prediction of one configs/baselines.py variant, in seconds."""
    family, one, current_state = trainer_step(variant, batch)
    channels = input_channels(family.config.mode)
    step_seconds = best_time(one, repeats=5)
    predict = jax.jit(family.predict)
    images = view_batch(channels, predict_batch, seed=1)["image"]
    state = current_state()
    predict_seconds = best_time(predict, state.params, state.model_state, images, repeats=5)
    parameters = sum(x.size for x in jax.tree.leaves(state.params))
    return {"network": family.config.network, "mode": family.config.mode, "channels_in": channels,
            "parameters": int(parameters), "step_seconds": step_seconds, "predict_seconds": predict_seconds}


def kosmos_e_small(batch: int, length: int, predict_batch: int) -> dict:
    """The small model's trainer step and its decoded grasps (location and angle answers, constrained)."""
    format_config = FormatConfig()  # xya, angle code, individual answers: the paper's best
    tokenizer = project_tokenizer(None, format_config)
    cfg = config_lib.get_config("small", latent_query_num=special.IMAGE_SLOTS).with_vocab_size(tokenizer.vocab_size)
    step_seconds = best_time(full_step(cfg, random_batch(cfg, batch, length))["call"], repeats=5)
    params = split_model(build(cfg, seed=1))[1]
    decoder = Decoder(cfg, make_mesh(1, 1, 1, devices=jax.devices()[:1]))
    size = cfg.vision.image_size
    images = np.random.default_rng(0).integers(0, 256, (predict_batch, size, size, 3), dtype=np.uint8)
    predict_seconds, parts = 0.0, {}
    for (answer, part), question in questions(tokenizer, format_config, tokenizer.vocab_size).items():
        if answer != "grasp":  # the location and angle answers of a "grasp" instruction
            continue
        asked = prompts(tokenizer, question.prompt.cue, predict_batch)
        seconds = best_time(lambda: decoder(params, images, *asked, question.prompt.constraint,
                                            question.max_new_tokens), repeats=2)
        parts[part] = round(seconds, 4)
        predict_seconds += seconds
    return {"vocab_size": tokenizer.vocab_size, "length": length, "step_seconds": step_seconds,
            "predict_seconds": predict_seconds, "predict_seconds_by_part": parts}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=8, help="training batch of every model (the baselines' configs)")
    parser.add_argument("--length", type=int, default=128, help="KOSMOS-E's token length (its config's max_length)")
    parser.add_argument("--predict-batch", type=int, default=16, help="images a prediction call (evaluate's default)")
    args = parser.parse_args()
    start_load = [round(x, 2) for x in os.getloadavg()]
    print(f"load average at the start (1, 5, 15 min): {start_load}", flush=True)
    measured = {}
    for variant in VARIANTS:
        measured[variant] = baseline(variant, args.batch, args.predict_batch)
        say(f"{variant}: step {measured[variant]['step_seconds']:.3f} s, "
            f"predict {args.predict_batch / measured[variant]['predict_seconds']:.1f} images/s")
    measured["kosmos_e_small"] = kosmos = kosmos_e_small(args.batch, args.length, args.predict_batch)
    say(f"kosmos_e_small: step {kosmos['step_seconds']:.3f} s, "
        f"predict {args.predict_batch / kosmos['predict_seconds']:.2f} images/s")
    figures = {name: {**{k: v for k, v in m.items() if not k.endswith("seconds")},
                      "train_step_seconds": round(m["step_seconds"], 4),
                      "train_images_per_s": round(args.batch / m["step_seconds"], 2),
                      "predict_images_per_s": round(args.predict_batch / m["predict_seconds"], 2)}
               for name, m in measured.items()}
    ratios = {variant: {"kosmos_e_step_over_baseline_step":
                        round(kosmos["step_seconds"] / measured[variant]["step_seconds"], 1),
                        "baseline_predict_rate_over_kosmos_e":
                        round(kosmos["predict_seconds"] / measured[variant]["predict_seconds"], 1)}
              for variant in VARIANTS}
    print(json.dumps({
        "device": str(jax.devices()[0].device_kind), "train_batch": args.batch, "predict_batch": args.predict_batch,
        "view": f"{VIEW}x{VIEW}", "load_average_start": start_load, **figures, "ratios": ratios,
        "load_average_end": [round(x, 2) for x in os.getloadavg()],
    }, indent=2))


if __name__ == "__main__":
    main()
