"""AdamW with linear warm-up and linear decay, global-norm clipping, and no decay on norms, biases, embeddings.

The optimiser config (`config.optimizer`, an ml_collections.ConfigDict):
  name          "adamw"
  peak_lr       learning rate reached at the end of warm-up (above 0: `check_rates`)
  end_lr        learning rate at `decay_steps` and after (0 in the paper; 0 to peak_lr)
  warmup_steps  linear warm-up from 0 over this many updates
  decay_steps   update at which the linear decay reaches end_lr; None or 0: the run's total steps
  b1, b2, eps   Adam's moments and denominator (eps outside the square root, as PyTorch)
  weight_decay  decoupled (AdamW: lr * weight_decay * param)
  clip_norm     global gradient-norm clipping; None = off
  decay_mask    which parameters decay: "logical" (from logical axis names) or "path" (leaf names);
                optional, default "logical"
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import nnx

# A parameter with any of these logical axes is a LayerNorm or an embedding table (tokens, tied
# with the LM head; positions; the connector's latent queries).
NO_DECAY_AXES = frozenset({"norm", "vocab", "positions", "latents"})
STACK_AXIS = "layers"  # the stacked axis of scanned blocks: not a feature axis


def warmup_linear_decay(peak_lr: float, end_lr: float, warmup_steps: int, decay_steps: int) -> optax.Schedule:
    """0 -> peak_lr linearly over warmup_steps, then linearly to end_lr at decay_steps, then end_lr."""
    if not 0 <= warmup_steps <= decay_steps:
        raise ValueError(f"need 0 <= warmup_steps ({warmup_steps}) <= decay_steps ({decay_steps})")

    def schedule(count):
        count = jnp.asarray(count, jnp.float32)
        warm = peak_lr * count / max(warmup_steps, 1)
        done = jnp.clip((count - warmup_steps) / max(decay_steps - warmup_steps, 1), 0.0, 1.0)
        return jnp.where(count < warmup_steps, warm, peak_lr + (end_lr - peak_lr) * done)

    return schedule


def _decays_logical(path, var: nnx.Variable) -> bool:
    axes = var.get_metadata().get("logical_axes")
    if axes is None:
        raise ValueError(f"parameter {jax.tree_util.keystr(path)} has no logical_axes; cannot tell if it decays")
    features = [axis for axis in axes if axis != STACK_AXIS]
    return len(features) >= 2 and not NO_DECAY_AXES.intersection(features)


def _decays_path(path, var: nnx.Variable) -> bool:
    last = path[-1]
    return getattr(last, "key", getattr(last, "name", None)) == "kernel"


DECAY_RULES: dict[str, Callable] = {"logical": _decays_logical, "path": _decays_path}


def decay_mask(params: nnx.State, rule: str = "logical") -> nnx.State:
    """True where weight decay applies, one bool in place of each parameter variable."""
    decays = DECAY_RULES[rule]
    return jax.tree_util.tree_map_with_path(decays, params, is_leaf=lambda x: isinstance(x, nnx.Variable))


def check_rates(opt_config) -> None:
    """Refuse rates no run means: peak_lr must be above 0 (a zero or negative rate trains nothing, or ascends
    the loss, without a word), end_lr between 0 and peak_lr (both finite)."""
    peak, end = float(opt_config.peak_lr), float(opt_config.end_lr)
    if not math.isfinite(peak) or peak <= 0:
        raise ValueError(f"optimizer.peak_lr={opt_config.peak_lr}: a learning rate must be a positive number")
    if not math.isfinite(end) or not 0 <= end <= peak:
        raise ValueError(f"optimizer.end_lr={opt_config.end_lr}: must lie between 0 and optimizer.peak_lr={peak}")


def make_optimizer(opt_config, total_steps: int) -> tuple[optax.GradientTransformation, optax.Schedule]:
    """(gradient transformation, learning-rate schedule of the update count) from the optimiser config."""
    if opt_config.name != "adamw":
        raise ValueError(f"unknown optimizer {opt_config.name!r}; only 'adamw' is implemented")
    check_rates(opt_config)
    decay_steps = opt_config.decay_steps or total_steps
    schedule = warmup_linear_decay(opt_config.peak_lr, opt_config.end_lr, opt_config.warmup_steps, decay_steps)
    rule = opt_config.get("decay_mask", "logical")
    if rule not in DECAY_RULES:
        raise ValueError(f"unknown decay_mask rule {rule!r}; expected one of {sorted(DECAY_RULES)}")
    adamw = optax.adamw(
        learning_rate=schedule, b1=opt_config.b1, b2=opt_config.b2, eps=opt_config.eps,
        weight_decay=opt_config.weight_decay, mask=lambda params: decay_mask(params, rule),
    )
    if opt_config.clip_norm is None:
        return adamw, schedule
    return optax.chain(optax.clip_by_global_norm(opt_config.clip_norm), adamw), schedule
