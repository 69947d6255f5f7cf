"""Decoding benchmark, one run: answers per second with and without the grasp grammar.

    GLIBC_TUNABLES=glibc.malloc.hugetlb=1 .venv/bin/python benchmarks/decode.py [--size small --batch 16]
        [--tokenizer WORKDIR/tokenizer.model]

The `small` model with random weights and the project's tokenizer (trained here on formatted
answers and instruction sentences, or a run's tokenizer.model), decoded the way
`python -m kosmos_jax.evaluate` decodes: kosmos_jax.scoring's Decoder (pixels, image
embeddings, KV-cache greedy decoding) on individual-mode prompts, each part (location, angle) with
its own budget. An example is one answer; both decodings make the same number of steps, so the
ratio is the grammar's cost per step. Compilation is left out (a warm-up call per part).
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from kosmos_jax import grasp_text
from kosmos_jax.instruct.kinds import TEMPLATES
from kosmos_jax.models import config as config_lib
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.scoring.model_answers import Decoder
from kosmos_jax.scoring.prompts import left_padded
from kosmos_jax.scoring.questions import questions
from kosmos_jax.text import layout
from kosmos_jax.text import tokens as special
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.text.tokenizer import load_tokenizer, train_tokenizer

INSTRUCTIONS = ("", "Grasp the black remote control.", "Grasp the handle of the mug.", "Grasp the red object.",
                TEMPLATES["angle"].format(code=156))


def project_tokenizer(path: str | None, config: FormatConfig):
    if path:
        return load_tokenizer(path, scheme="native", numbers="digits")
    rng = np.random.default_rng(0)
    size = config.image_size
    answers = [grasp_text.format_grasp([*rng.uniform(0, size - 1, 2), *rng.uniform(1, 150, 2),
                                        rng.uniform(-np.pi / 2, np.pi / 2)], config.representation,
                                       config.angle_code, size) for _ in range(200)]
    return train_tokenizer([*INSTRUCTIONS[1:], *answers], numbers="digits", text_pieces=300,
                           representations=(config.representation,))


def prompts(tokenizer, cue: str, batch: int):
    """`batch` prompts <s><image> slots </image> instruction cue, left-padded."""
    rows = []
    for number in range(batch):
        instruction = INSTRUCTIONS[number % len(INSTRUCTIONS)]
        ids = layout.prefix_ids(tokenizer) + [i for text in (instruction, cue) if text for i in tokenizer.encode(text)]
        slots = np.zeros(len(ids), bool)
        slots[2:2 + special.IMAGE_SLOTS] = True
        rows.append((np.asarray(ids, np.int32), slots))
    return left_padded(rows, max(len(ids) for ids, _ in rows), tokenizer.pad_id)


def seconds_per_batch(run, repeats: int) -> float:
    run()  # compile and warm up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="small", choices=sorted(config_lib.SIZES))
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--tokenizer", default=None, help="a native tokenizer.model (default: train one here)")
    args = parser.parse_args()
    format_config = FormatConfig()  # xya, angle code, individual outputs: the paper's best
    tokenizer = project_tokenizer(args.tokenizer, format_config)
    model_config = config_lib.get_config(args.size, latent_query_num=special.IMAGE_SLOTS).with_vocab_size(
        tokenizer.vocab_size)
    params = split_model(build(model_config, seed=1))[1]
    decoder = Decoder(model_config, make_mesh(1, 1, 1, devices=jax.devices()[:1]))
    size = model_config.vision.image_size
    images = np.random.default_rng(0).integers(0, 256, (args.batch, size, size, 3), dtype=np.uint8)
    parts, totals = {}, {"constrained": 0.0, "unconstrained": 0.0}
    for (answer, part), question in questions(tokenizer, format_config, tokenizer.vocab_size).items():
        if answer != "grasp":
            continue
        batch = prompts(tokenizer, question.prompt.cue, args.batch)
        figures = {"max_new_tokens": question.max_new_tokens, "prompt_tokens": batch[0].shape[1]}
        for name, constraint in (("constrained", question.prompt.constraint), ("unconstrained", None)):
            run = lambda: decoder(params, images, *batch, constraint, question.max_new_tokens)
            seconds = seconds_per_batch(run, args.repeats)
            totals[name] += seconds
            figures[f"examples_per_s_{name}"] = round(args.batch / seconds, 2)
        parts[part] = figures
    rate = {name: round(args.batch * len(parts) / seconds, 2) for name, seconds in totals.items()}
    print(json.dumps({
        "device": str(jax.devices()[0].device_kind), "size": args.size, "vocab_size": tokenizer.vocab_size,
        "batch": args.batch, "format": "xya, angle code, individual (location and angle answers)",
        "examples_per_s_constrained": rate["constrained"], "examples_per_s_unconstrained": rate["unconstrained"],
        "constrained_over_unconstrained": round(rate["constrained"] / rate["unconstrained"], 3),
        "parts": parts,
    }, indent=2))


if __name__ == "__main__":
    main()
