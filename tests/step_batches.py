"""What the one-step train-step tests share: an AdamW at a constant learning rate and a batch of
random images whose sequences are <s>, the image slots, </image>, a few instruction words and a
two-token answer; one step of the tiny model on such a batch."""

import dataclasses

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np
from flax import nnx

from kosmos_jax.models import config as model_config
from kosmos_jax.models import kosmos2, mesh
from kosmos_jax.train import optimizer, state, step


def constant_adamw(lr: float) -> ml_collections.ConfigDict:
    return ml_collections.ConfigDict(dict(name="adamw", peak_lr=lr, end_lr=lr, warmup_steps=0, decay_steps=None,
                                          b1=0.9, b2=0.98, eps=1e-6, weight_decay=0.0, clip_norm=1.0))


def answer_batch(rng: np.random.Generator, count: int, slots: int, words: int, stored: int, vocab: int) -> dict:
    """Numpy arrays of `count` examples: slots at positions 1..slots, `words` instruction tokens after
    </image>, the loss on the last two tokens, a target grasp centre anywhere in the `stored` px view."""
    length = 2 + slots + words + 2
    image_mask = np.zeros((count, length), bool)
    image_mask[:, 1:1 + slots] = True
    loss_mask = np.zeros((count, length), bool)
    loss_mask[:, -2:] = True
    grasp = np.zeros((count, 5), np.float32)
    grasp[:, :2] = rng.uniform(0, stored, (count, 2))
    return dict(image=rng.integers(0, 256, (count, stored, stored, 3), dtype=np.uint8),
                tokens=rng.integers(3, vocab, (count, length)).astype(np.int32), loss_mask=loss_mask,
                image_mask=image_mask, length=np.full(count, length, np.int32), grasp=grasp,
                example_index=np.arange(count))


def one_tiny_step(auxiliary, count: int, stored: int, extra: dict | None = None, vision_width: int | None = None):
    """(the tiny model without dropout, the batch as jax arrays, the metrics of one train step with
    `auxiliary`'s losses from that model) for an `answer_batch` of `count` examples (4 words), with
    the `extra` fields added; `vision_width` widens the tiny tower (for losses that need more reads)."""
    tiny = model_config.TINY.replace(text=dataclasses.replace(model_config.TINY.text, dropout=0.0,
                                                              attention_dropout=0.0))
    if vision_width:
        tiny = tiny.replace(vision=dataclasses.replace(tiny.vision, hidden_size=vision_width))
    on = mesh.make_mesh(1, 1, 1, devices=jax.devices()[:1])
    tx, schedule = optimizer.make_optimizer(constant_adamw(1e-3), total_steps=1)
    batch = {**answer_batch(np.random.default_rng(0), count, tiny.latent_query_num, words=4, stored=stored,
                            vocab=tiny.text.vocab_size), **(extra or {})}
    model = nnx.view(kosmos2.build(tiny), deterministic=True)
    train_step = step.make_train_step(tiny, tx, schedule, on, seed=0, auxiliary=auxiliary)
    _, params, _ = kosmos2.split_model(model)
    _, metrics = train_step(state.init_train_state(params, tx, on), batch)
    return model, {key: jnp.asarray(value) for key, value in batch.items()}, metrics
