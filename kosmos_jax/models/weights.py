"""KOSMOS-2 weights in transformers' folder layout, without torch: import, export, vocabulary growth.

A folder holds `config.json` and either `model.safetensors` or shards listed in
`model.safetensors.index.json`. The key of every parameter is its nnx path with the leaf renamed
(kernel/scale/embedding -> weight); Linear kernels are transposed ((out, in) in PyTorch, (in, out)
here) and the patch-conv kernel permuted ((out, in, kh, kw) there, (kh, kw, in, out) here).
Checkpoints stored in bfloat16 or float16 import as float32 parameters. A model with scanned layers
(`scan_layers`) holds each block parameter once, stacked over the layers; it reads and writes the
same per-layer keys (`...layers.3.self_attn.q_proj.weight`).
"""

from __future__ import annotations

import json
import pathlib
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from safetensors import safe_open
from safetensors.numpy import save_file

from kosmos_jax.models.config import EXTENSION_FIELDS, Kosmos2Config
from kosmos_jax.models.kosmos2 import Kosmos2, abstract_model
from kosmos_jax.models.layers import LAYERS

TIED_HEAD = "text_model.lm_head.weight"
EMBED_TOKENS = "text_model.model.embed_tokens.weight"
# Buffers some checkpoints carry; computed here, never loaded.
IGNORED_KEYS = ("vision_model.model.embeddings.position_ids", "text_model.model.embed_positions.weights")
VISION_POSITIONS = "vision_model.model.embeddings.position_embedding.weight"  # the tower's [1 + patches, D] table


def hf_key(path: tuple) -> str:
    *parents, leaf = (str(p) for p in path)
    leaf = "weight" if leaf in ("kernel", "scale", "embedding") else leaf
    return ".".join([*parents, leaf])


def to_hf(path: tuple, value: np.ndarray) -> np.ndarray:
    if str(path[-1]) == "kernel":
        return np.ascontiguousarray(value.transpose(3, 2, 0, 1) if value.ndim == 4 else value.T)
    return np.ascontiguousarray(value)


def from_hf(path: tuple, value: np.ndarray) -> np.ndarray:
    if str(path[-1]) == "kernel":
        return value.transpose(2, 3, 1, 0) if value.ndim == 4 else value.T
    return value


# -- layouts: one variable per layer (transformers' keys) or one stacked over the layers (scan) ----
def _after_layers(path: tuple, indexed: bool) -> int | None:
    """The position just after `layers` in a path that holds (indexed) or lacks a layer index there."""
    for at, name in enumerate(path[:-1], start=1):
        if name == LAYERS and isinstance(path[at], int) == indexed:
            return at
    return None


def _stack_position(path: tuple) -> int | None:
    """Where a stacked variable's path takes the layer index; None if the variable is not stacked."""
    return _after_layers(path, indexed=False)


def layer_paths(path: tuple, shape: tuple[int, ...]) -> list[tuple]:
    """The per-layer paths of a variable of that shape: its own path when it is not stacked."""
    at = _stack_position(path)
    return [path] if at is None else [(*path[:at], i, *path[at:]) for i in range(shape[0])]


def unstack_layers(flat: dict[tuple, object]) -> dict[tuple, object]:
    """{path: array} of a scanned model -> the per-layer layout's {path: array}, sorted by path."""
    out = {}
    for path, value in flat.items():
        if _stack_position(path) is None:
            out[path] = value
        else:
            out.update(zip(layer_paths(path, value.shape), value))
    return dict(sorted(out.items(), key=lambda item: item[0]))


def stack_layers(flat: dict[tuple, object]) -> dict[tuple, object]:
    """{path: array} of the per-layer layout -> the scanned layout's {path: array}, sorted by path."""
    out, layers = {}, {}
    for path, value in flat.items():
        at = _after_layers(path, indexed=True)
        if at is None:
            out[path] = value
        else:
            layers.setdefault((*path[:at], *path[at + 1:]), {})[path[at]] = value
    for path, by_index in layers.items():
        out[path] = jnp.stack([by_index[i] for i in range(len(by_index))])
    return dict(sorted(out.items(), key=lambda item: item[0]))


def with_layout(model: Kosmos2, scan_layers: bool) -> Kosmos2:
    """The same model (parameters and rng state) with its blocks stacked or listed; a new model."""
    if model.config.scan_layers == scan_layers:
        return model
    graphdef, target = nnx.split(abstract_model(model.config.replace(scan_layers=scan_layers)))
    source = {path: var.get_value() for path, var in nnx.to_flat_state(nnx.state(model))}
    values = stack_layers(source) if scan_layers else unstack_layers(source)
    flat = nnx.to_flat_state(target)
    return nnx.merge(graphdef, nnx.from_flat_state([(path, var.replace(values[path])) for path, var in flat]))


# -- reading ------------------------------------------------------------------------------------
def read_config(folder: str | pathlib.Path, **runtime) -> Kosmos2Config:
    path = pathlib.Path(folder) / "config.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no config.json in the checkpoint folder")
    return Kosmos2Config.from_hf_dict(json.loads(path.read_text()), source=str(path), **runtime)


def _weight_files(folder: pathlib.Path) -> dict[str, pathlib.Path]:
    """key -> file holding it."""
    index = folder / "model.safetensors.index.json"
    if index.is_file():
        weight_map = json.loads(index.read_text()).get("weight_map")
        if not isinstance(weight_map, dict):
            raise ValueError(f"{index}: no 'weight_map' object")
        return {key: folder / name for key, name in weight_map.items()}
    single = folder / "model.safetensors"
    if not single.is_file():
        raise FileNotFoundError(f"{folder}: neither model.safetensors nor model.safetensors.index.json")
    with safe_open(single, framework="np") as f:
        return {key: single for key in f.keys()}


def read_tensors(folder: str | pathlib.Path) -> dict[str, np.ndarray]:
    """Every tensor of the checkpoint, in its stored dtype (params_from_tensors casts to float32)."""
    folder = pathlib.Path(folder)
    by_file: dict[pathlib.Path, list[str]] = {}
    for key, file in _weight_files(folder).items():
        by_file.setdefault(file, []).append(key)
    tensors = {}
    for file, keys in by_file.items():
        if not file.is_file():
            raise FileNotFoundError(f"{file}: shard named in the index is missing")
        with safe_open(file, framework="np") as f:
            for key in keys:
                tensors[key] = f.get_tensor(key)
    return tensors


def _fill_rng_state(rest: nnx.State, seed: int) -> nnx.State:
    base = jax.random.key(seed)
    leaves, treedef = jax.tree.flatten(rest)
    filled = []
    for i, leaf in enumerate(leaves):
        if jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            key = jax.random.fold_in(base, i)
            filled.append(key if leaf.shape == () else jax.random.split(key, leaf.shape))  # stacked: one per layer
        else:
            filled.append(jnp.zeros(leaf.shape, leaf.dtype))
    return jax.tree.unflatten(treedef, filled)


def params_from_tensors(cfg: Kosmos2Config, tensors: dict[str, np.ndarray], source: str = "checkpoint"):
    """(graphdef, param state, other state shapes) with every parameter taken from `tensors`."""
    graphdef, params, rest = nnx.split(abstract_model(cfg), nnx.Param, ...)
    flat = nnx.to_flat_state(params)
    expected = {hf_key(layer_path) for path, var in flat for layer_path in layer_paths(path, var.shape)}
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected) - {TIED_HEAD, *IGNORED_KEYS})
    if missing or unexpected:
        raise ValueError(f"{source}: keys do not match a {cfg.text.layers}-layer KOSMOS-2: "
                         f"missing {missing[:8]}{'...' if len(missing) > 8 else ''}, "
                         f"unexpected {unexpected[:8]}{'...' if len(unexpected) > 8 else ''}")
    if TIED_HEAD in tensors and not np.array_equal(tensors[TIED_HEAD], tensors[EMBED_TOKENS]):
        raise ValueError(f"{source}: {TIED_HEAD} differs from {EMBED_TOKENS}; untied heads are not supported")
    values = [jnp.asarray(_read_variable(path, var.shape, tensors, source), jnp.float32) for path, var in flat]
    params = nnx.from_flat_state([(path, var.replace(value)) for (path, var), value in zip(flat, values)])
    return graphdef, params, rest


def _read_variable(path: tuple, shape: tuple[int, ...], tensors: dict[str, np.ndarray], source: str) -> np.ndarray:
    """One variable's value from its tensor, or from one tensor per layer when it is stacked."""
    stacked = _stack_position(path) is not None
    layer_shape = shape[1:] if stacked else shape
    values = []
    for layer_path in layer_paths(path, shape):
        key = hf_key(layer_path)
        value = from_hf(layer_path, tensors[key])
        if value.shape != layer_shape:
            raise ValueError(f"{source}: {key} has shape {tensors[key].shape}, the config implies "
                             f"{to_hf(layer_path, np.zeros(layer_shape, np.float32)).shape}")
        values.append(value)
    return np.stack(values) if stacked else values[0]


def load_pretrained(folder: str | pathlib.Path, seed: int = 0, **runtime) -> Kosmos2:
    """A Kosmos2 with the weights of a transformers-layout folder (config.json + safetensors)."""
    cfg = read_config(folder, **runtime)
    graphdef, params, rest = params_from_tensors(cfg, read_tensors(folder), source=str(folder))
    return nnx.merge(graphdef, params, _fill_rng_state(rest, seed))


# -- writing ------------------------------------------------------------------------------------
def model_tensors(model: Kosmos2) -> dict[str, np.ndarray]:
    flat = nnx.to_flat_state(nnx.state(model, nnx.Param))
    arrays = unstack_layers({path: np.asarray(var.get_value(), np.float32) for path, var in flat})
    return {hf_key(path): to_hf(path, value) for path, value in arrays.items()}


def save_pretrained(model: Kosmos2, folder: str | pathlib.Path, max_shard_bytes: int | None = None,
                    extensions: bool = False) -> pathlib.Path:
    """Write config.json and model.safetensors (or shards + index when over `max_shard_bytes`).

    The tied LM head is not written, as transformers does for tied weights. A model transformers'
    KOSMOS-2 cannot compute (a grid code in its connector) is refused unless `extensions`: its
    config.json then names this project's model type (config.EXTENDED_MODEL_TYPE), which transformers
    refuses and read_config reads back. A model without such a field is written alike either way."""
    if model.config.needs_extensions and not extensions:
        extended = {name: getattr(model.config, name) for name in EXTENSION_FIELDS}
        raise ValueError(f"this model's connector adds a grid code or reads the instruction ({extended}), which "
                         "transformers' KOSMOS-2 lacks: its export would compute other image embeddings; "
                         "save_pretrained(..., extensions=True) writes a folder "
                         "only this project reads")
    config = model.config.to_extended_hf_dict() if model.config.needs_extensions else model.config.to_hf_dict()
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "config.json").write_text(json.dumps(config, indent=2) + "\n")
    tensors = model_tensors(model)
    metadata = {"format": "pt"}
    total = sum(t.nbytes for t in tensors.values())
    if max_shard_bytes is None or total <= max_shard_bytes:
        save_file(tensors, str(folder / "model.safetensors"), metadata=metadata)
        return folder
    shards: list[dict[str, np.ndarray]] = [{}]
    size = 0
    for key, tensor in tensors.items():
        if shards[-1] and size + tensor.nbytes > max_shard_bytes:
            shards.append({})
            size = 0
        shards[-1][key] = tensor
        size += tensor.nbytes
    weight_map = {}
    for i, shard in enumerate(shards):
        name = f"model-{i + 1:05d}-of-{len(shards):05d}.safetensors"
        save_file(shard, str(folder / name), metadata=metadata)
        weight_map.update({key: name for key in shard})
    index = {"metadata": {"total_size": total}, "weight_map": weight_map}
    (folder / "model.safetensors.index.json").write_text(json.dumps(index, indent=2) + "\n")
    return folder


# -- vocabulary growth --------------------------------------------------------------------------
def grow_vocabulary(model: Kosmos2, new_vocab_size: int, seed: int = 0, noise: float = 1e-3,
                    source_ids: Sequence[Sequence[int]] | None = None) -> Kosmos2:
    """Add rows to the (tied) token embedding, in place; returns the model.

    By default a new row is the mean of the existing rows plus small noise: the new token starts
    with a logit near the average one (no token suddenly dominates) and distinct from the others.
    With `source_ids`, new row i is instead the mean of the rows `source_ids[i]` (e.g. the pieces
    the tokenizer used to spell the new token's text before it existed), plus the same noise.
    """
    embed = model.text_model.model.embed_tokens
    table = embed.embedding.get_value()
    old = table.shape[0]
    if new_vocab_size < old:
        raise ValueError(f"new vocabulary size {new_vocab_size} is smaller than the current {old}")
    if new_vocab_size == old:
        return model
    added = new_vocab_size - old
    if source_ids is None:
        base = jnp.broadcast_to(table.mean(axis=0), (added, table.shape[1]))
    else:
        if len(source_ids) != added or any(len(ids) == 0 for ids in source_ids):
            raise ValueError(f"source_ids needs {added} non-empty id lists, got {[len(i) for i in source_ids]}")
        bad = [i for ids in source_ids for i in ids if not 0 <= i < old]
        if bad:
            raise ValueError(f"source_ids {bad} outside the current vocabulary of {old}")
        base = jnp.stack([table[jnp.asarray(ids)].mean(axis=0) for ids in source_ids])
    extra = base + noise * table.std() * jax.random.normal(jax.random.key(seed), base.shape, table.dtype)
    embed.embedding.set_value(jnp.concatenate([table, extra], axis=0))
    embed.num_embeddings = new_vocab_size
    model.config = model.config.with_vocab_size(new_vocab_size)
    model.text_model.model.cfg = model.config.text
    return model
