"""Scenes made on the fly (train/scene_stream.py): batches that resume exactly from (chunk, batch),
chunks that never repeat a scene or an example index, processes that split each global batch, and
stream seeds that can never reach the test split's scenes."""

import json
import pathlib
import signal
import subprocess
import sys
import time

import ml_collections
import numpy as np
import pytest

from kosmos_jax.experiments.spec import load_config
from kosmos_jax.train import batches as batches_lib
from kosmos_jax.train import trainer
from kosmos_jax.train.metrics_log import train_losses
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.train.scene_stream import CHUNK_STRIDE, SceneStream
from kosmos_jax.train.tower_labels import LABEL_NAMES

pytestmark = pytest.mark.xdist_group("scene_stream")

REPO = pathlib.Path(__file__).resolve().parent.parent

BATCH = 128  # a tiny chunk (8 photos, 2 views each, every kind) holds a few such batches: 5 cross a chunk


@pytest.fixture(scope="session")
def stream_parts(tmp_path_factory):
    """(build config, tokenizer) of configs/pretrain.py:tiny_stream."""
    config = load_config("configs/pretrain.py:tiny_stream")
    config.data.root = str(tmp_path_factory.mktemp("stream_data"))
    dataset = batches_lib.prepare(config.data)
    return config, batches_lib.build_config(config.data), dataset.tokenizer()


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


def test_each_example_carries_its_target_objects_category_and_main_colour(stream_parts, tmp_path):
    """Oracle: the chunk's scenes written again from their seed, and the photo whose place holds the
    target grasp (a mosaic's quadrant in its photo order, or the one photo)."""
    categories, colours = LABEL_NAMES["category"], LABEL_NAMES["colour"]
    config, _, _ = stream_parts
    chunk = stream(stream_parts).chunk(0)
    scenes.write_dataset(tmp_path / "scenes", photos=config.data.stream.photos, seed=config.data.stream.seed)
    meta = json.loads((tmp_path / "scenes" / scenes.META_NAME).read_text())["photos"]
    side = chunk.arrays["image"].shape[1]
    mosaics = 0
    for row, label in enumerate(chunk.labels):
        photos = label.split(" (")[0].split("+")
        x, y = chunk.arrays["grasp"][row, :2]
        place = 0 if len(photos) == 1 else 2 * int(y >= side / 2) + int(x >= side / 2)
        mosaics += len(photos) == 4
        assert chunk.arrays["category"][row] == categories.index(meta[photos[place]]["category"]), label
        assert chunk.arrays["colour"][row] == colours.index(meta[photos[place]]["colour"][0]), label
    assert mosaics and mosaics < len(chunk.labels)
    assert set(chunk.arrays["category"].tolist()) == {categories.index(m["category"]) for m in meta.values()}
    assert set(chunk.arrays["colour"].tolist()) == {colours.index(m["colour"][0]) for m in meta.values()}


def test_stream_seeds_must_lie_above_the_test_scenes_seed():
    data = ml_collections.ConfigDict(dict(source="synthetic", synthetic_seed=1000,
                                          stream=dict(photos=8, seed=1000)))
    with pytest.raises(ValueError, match="must exceed config.data.synthetic_seed=1000"):
        trainer.stream_settings(data)
    data.stream.seed = 1001
    assert trainer.stream_settings(data) == {"photos": 8, "seed": 1001}
    data.stream.photos = 0
    assert trainer.stream_settings(data) is None


def test_kind_repeats_is_refused_beside_the_stream():
    data = ml_collections.ConfigDict(dict(source="synthetic", synthetic_seed=1000, kind_repeats="non=3",
                                          stream=dict(photos=8, seed=1001)))
    with pytest.raises(ValueError, match="kind_repeats weighs the built dataset's examples"):
        trainer.stream_settings(data)
    data.stream.photos = 0
    assert trainer.stream_settings(data) is None


def test_the_stream_may_ask_for_other_kinds_than_the_build():
    data = ml_collections.ConfigDict(dict(source="synthetic", synthetic_seed=1000,
                                          stream=dict(photos=8, seed=1001, kinds="")))
    assert "kinds" not in trainer.stream_settings(data)  # the build's kinds, and the description of older runs
    data.stream.kinds = "non, multi-colour,multi"
    assert trainer.stream_settings(data)["kinds"] == ["non", "multi-colour", "multi-name", "multi-shape",
                                                      "multi-purpose", "multi-position", "multi-strategy"]
    data.stream.kinds = "non,multi-colours"
    with pytest.raises(ValueError, match="colours"):
        trainer.stream_settings(data)


def test_a_stream_with_its_own_kinds_makes_only_those(stream_parts):
    config = ml_collections.ConfigDict(stream_parts[0].to_dict())
    config.data.stream.kinds = "non,multi-colour"
    config.train.batch_size = 8
    batches = trainer.scene_batches(config, trainer.stream_settings(config.data), stream_parts[2])
    labels = []
    for _ in range(3):
        next(batches)
        labels += batches.last_labels
    assert {label.rpartition(" ")[2] for label in labels} == {"(non)", "(multi-colour)"}
    assert any("+" in label for label in labels)  # the mosaics' four photo ids


@pytest.mark.slow  # three tiny pretraining runs in subprocesses, about two minutes on 2 cores
def test_a_stream_run_killed_with_9_resumes_with_the_losses_of_one_never_stopped(tmp_path):
    steps = 6

    def command(workdir):
        return [sys.executable, "-m", "kosmos_jax.train", "--config=configs/pretrain.py:tiny_stream",
                f"--workdir={workdir}", f"--config.data.root={tmp_path / 'data'}", f"--config.train.steps={steps}",
                "--config.train.checkpoint_every=2", "--config.optimizer.warmup_steps=1"]

    def finish(workdir):
        done = subprocess.run(command(workdir), cwd=REPO, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        return done

    finish(tmp_path / "straight")
    killed = subprocess.Popen(command(tmp_path / "killed"), cwd=REPO, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    checkpoints = tmp_path / "killed" / "checkpoints"
    while not any(p.name.isdigit() for p in checkpoints.glob("*")):  # orbax renames a step's folder once written
        assert killed.poll() is None and time.monotonic() < deadline, "the run ended or stalled before a checkpoint"
        time.sleep(0.005)
    killed.kill()
    assert killed.wait(timeout=60) == -signal.SIGKILL
    assert max(train_losses(tmp_path / "killed")) < steps  # stopped midway, not at the end
    assert "resuming" in finish(tmp_path / "killed").stderr
    straight, resumed = train_losses(tmp_path / "straight"), train_losses(tmp_path / "killed")
    assert sorted(straight) == list(range(1, steps + 1)) and resumed == straight  # exact floats, every step


def test_a_capped_chunk_keeps_that_many_of_the_full_chunks_examples(stream_parts):
    """Oracle: the uncapped chunk 0; the capped one holds `examples` of its examples (their labels and
    token rows), the same ones on every remake, and a cap above the count keeps all."""
    full = stream(stream_parts).chunk(0)
    by_label = {}
    for row, label in enumerate(full.labels):
        by_label.setdefault(label, []).append(full.arrays["tokens"][row])
    cap = len(full.labels) // 3
    capped = stream(stream_parts, examples=cap).chunk(0)
    assert len(capped.labels) == cap
    for row, label in enumerate(capped.labels):
        assert any(np.array_equal(capped.arrays["tokens"][row], tokens) for tokens in by_label[label]), label
    again = stream(stream_parts, examples=cap).chunk(0)
    assert again.labels == capped.labels
    np.testing.assert_array_equal(again.arrays["tokens"], capped.arrays["tokens"])
    assert len(stream(stream_parts, examples=10 * len(full.labels)).chunk(0).labels) == len(full.labels)
    with pytest.raises(ValueError, match="examples=-1 must be >= 0"):
        stream(stream_parts, examples=-1)


def test_the_stream_records_a_chunk_cap_only_when_set():
    data = ml_collections.ConfigDict(dict(source="synthetic", synthetic_seed=1000,
                                          stream=dict(photos=8, seed=1001, kinds="", examples=0)))
    assert "examples" not in trainer.stream_settings(data)  # the description of older runs
    data.stream.examples = 96
    assert trainer.stream_settings(data)["examples"] == 96


def test_best_targets_leave_each_scene_one_grasp_and_are_recorded_only_when_set(stream_parts):
    """Oracle: the same chunk from the scenes' own draws, whose single-photo examples answer with several grasps;
    with targets="best" every example answers with one grasp a photo (four on a mosaic's photos, at most)."""
    own = stream(stream_parts).chunk(0)
    best = stream(stream_parts, targets="best").chunk(0)
    single = lambda chunk: [row for row, label in enumerate(chunk.labels) if label.endswith("(non)")]
    assert single(own) and single(best)
    assert max(own.arrays["answers_mask"][row].sum() for row in single(own)) > 1
    assert {int(best.arrays["answers_mask"][row].sum()) for row in single(best)} == {1}
    assert max(best.arrays["answers_mask"].sum(axis=1)) <= 4
    with pytest.raises(ValueError, match="targets='top'"):
        stream(stream_parts, targets="top")
    data = ml_collections.ConfigDict(dict(source="synthetic", synthetic_seed=1000,
                                          stream=dict(photos=8, seed=1001, kinds="", examples=0, targets="")))
    assert "targets" not in trainer.stream_settings(data)  # the description of older runs
    data.stream.targets = "best"
    assert trainer.stream_settings(data)["targets"] == "best"
