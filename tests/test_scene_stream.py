"""Scenes made on the fly (train/scene_stream.py): batches that resume exactly from (chunk, batch),
chunks that never repeat a scene or an example index, processes that split each global batch, and
stream seeds that can never reach the test split's scenes."""

import ml_collections
import numpy as np
import pytest

from kosmos_jax.experiments.spec import load_config
from kosmos_jax.train import data as data_lib
from kosmos_jax.train import trainer
from kosmos_jax.train.metrics_log import read_metrics
from kosmos_jax.train.scene_stream import CHUNK_STRIDE, SceneStream

pytestmark = pytest.mark.xdist_group("scene_stream")

BATCH = 128  # a tiny chunk (8 photos, 2 views each, every kind) holds a few such batches: 5 cross a chunk


@pytest.fixture(scope="session")
def stream_parts(tmp_path_factory):
    """(build config, tokenizer) of configs/pretrain.py:tiny_stream."""
    config = load_config("configs/pretrain.py:tiny_stream")
    config.data.root = str(tmp_path_factory.mktemp("stream_data"))
    dataset = data_lib.prepare(config.data)
    return config, data_lib.build_config(config.data), dataset.tokenizer()


def stream(stream_parts, **options):
    config, build_config, tokenizer = stream_parts
    return SceneStream(build_config, tokenizer, photos=config.data.stream.photos, seed=config.data.stream.seed,
                       global_batch=options.pop("global_batch", BATCH), **options)


@pytest.fixture(scope="session")
def five(stream_parts):
    one = stream(stream_parts)
    batches = [next(one) for _ in range(5)]
    return batches, one.get_state()


def test_batches_resume_exactly_from_a_saved_position(stream_parts, five):
    batches, _ = five
    first = stream(stream_parts)
    for _ in range(2):
        next(first)
    state = first.get_state()
    second = stream(stream_parts)
    second.set_state(state)
    for want in batches[2:]:
        got = next(second)
        assert got.keys() == want.keys()
        for name in want:
            np.testing.assert_array_equal(got[name], want[name], err_msg=name)


def test_chunks_hold_new_scenes_and_new_example_indices(five):
    batches, state = five
    assert state["chunk"] >= 1, "five batches of 128 should reach the second chunk"
    indices = np.concatenate([b["example_index"] for b in batches])
    assert len(np.unique(indices)) == len(indices)
    chunks = set((indices // CHUNK_STRIDE).tolist())
    assert len(chunks) >= 2
    first = {b["image"][i].tobytes() for b in batches for i in range(BATCH) if b["example_index"][i] < CHUNK_STRIDE}
    later = {b["image"][i].tobytes() for b in batches for i in range(BATCH) if b["example_index"][i] >= CHUNK_STRIDE}
    assert first and later and not first & later


def test_two_processes_split_each_global_batch(stream_parts, five):
    batches, _ = five
    parts = [stream(stream_parts, process_index=p, process_count=2) for p in range(2)]
    for want in batches[:3]:
        rows = [next(part) for part in parts]
        assert all(len(r["tokens"]) == BATCH // 2 for r in rows)
        assert sorted(np.concatenate([r["example_index"] for r in rows]).tolist()) == sorted(want["example_index"].tolist())


def test_a_batch_the_processes_cannot_share_is_refused(stream_parts):
    with pytest.raises(ValueError, match="not divisible by the 3 processes"):
        stream(stream_parts, global_batch=8, process_count=3)


def test_stream_seeds_must_lie_above_the_test_scenes_seed():
    data = ml_collections.ConfigDict(dict(source="synthetic", synthetic_seed=1000,
                                          stream=dict(photos=8, seed=1000)))
    with pytest.raises(ValueError, match="must exceed config.data.synthetic_seed=1000"):
        trainer.stream_settings(data)
    data.stream.seed = 1001
    assert trainer.stream_settings(data) == {"photos": 8, "seed": 1001}
    data.stream.photos = 0
    assert trainer.stream_settings(data) is None


@pytest.mark.slow
def test_a_stream_run_resumed_logs_the_losses_of_one_never_stopped(tmp_path):
    def run(workdir, steps):
        config = load_config("configs/pretrain.py:tiny_stream")
        config.data.root = str(tmp_path / "data")
        config.train.steps, config.train.checkpoint_every = steps, 2
        config.optimizer.decay_steps, config.optimizer.warmup_steps = 4, 1  # one schedule for both lengths
        trainer.train(config, workdir)
        return {r["step"]: r["loss"] for r in read_metrics(workdir) if "split" not in r}

    straight = run(tmp_path / "straight", 4)
    run(tmp_path / "stopped", 2)
    resumed = run(tmp_path / "stopped", 4)
    assert straight == resumed and sorted(straight) == [1, 2, 3, 4]
