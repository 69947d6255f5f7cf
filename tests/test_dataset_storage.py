"""TFDS array_record builders (no TensorFlow) and the grain pipeline: round trips, image tables,
shards, resume, atomic writes; the samples of a split."""

import dataclasses
import json
import sys

import cv2
import numpy as np
import pytest

from kosmos_jax.annotators.base import MissingWordsError, ObjectWords
from kosmos_jax.sources import cornell
from kosmos_jax.instruct.sample import View
from kosmos_jax.dataset import pipeline
from kosmos_jax.dataset.images import digest, png_bytes
from kosmos_jax.dataset.samples import MosaicCounts, split_samples
from kosmos_jax.train import batches as batches_lib
from kosmos_jax.dataset.tfds_builders import (build_cornell, dataset_folder, make_config, open_cornell, open_splits,
                                              write_instruct_grasp)

LENGTH, SIZE = 80, 16
IMAGES = 4  # distinct images of the test records: examples share them, as a view's examples do


def _image(number: int) -> np.ndarray:
    return np.random.default_rng(1000 + number).integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)


SHARED_IMAGES = [_image(n) for n in range(IMAGES)]


def _record(index: int, answers: int = 2, image: np.ndarray | None = None) -> dict:
    """Record `index`; its image is one of SHARED_IMAGES (the same array object) unless given."""
    rng = np.random.default_rng(index)
    tokens = rng.integers(4, 500, LENGTH).astype(np.int32)
    return {
        "image": SHARED_IMAGES[index % IMAGES] if image is None else image,
        "tokens": tokens,
        "loss_mask": np.arange(LENGTH) > 70,
        "image_mask": (np.arange(LENGTH) >= 2) & (np.arange(LENGTH) < 66),
        "length": np.int32(75),
        "truncated": False,
        "grasp": np.array([index, 2, 3, 4, 0.5], np.float32),
        "grasp_mask": np.array([1, 1, 0, 0, 1], bool),
        "answers": rng.uniform(0, SIZE, (answers, 5)).astype(np.float32),
        "kind": "name",
        "scene": "single",
        "part": "location",
        "instruction": f"Grasp object {index}.",
        "target_text": "Grasp center point coordinates: x_1,y_2",
        "photo_ids": [f"pcd{index:04d}"],
        "object_ids": np.array([index % 3], np.int64),
        "target": np.int32(0),
    }


def _config(**fields):
    return make_config(**{"max_length": LENGTH, "image_size": SIZE, **fields})


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    out = tmp_path_factory.mktemp("instruct")
    records = {"train": [_record(i) for i in range(23)], "test": [_record(100 + i, answers=1 + i) for i in range(5)]}
    path = write_instruct_grasp(records, out, _config(kinds=("name",), fold=2))
    return path, records


_WITHOUT_TENSORFLOW = """
import importlib.abc, importlib.util, sys

# Every finder wrapped so that tensorflow is not found: `import tensorflow` fails and find_spec
# gives None, exactly as when it is not installed (libraries probe both ways).
class Hide(importlib.abc.MetaPathFinder):
    def __init__(self, inner):
        self.inner = inner

    def find_spec(self, name, path=None, target=None):
        if name == "tensorflow" or name.startswith("tensorflow."):
            return None
        return self.inner.find_spec(name, path, target)

    def invalidate_caches(self):
        getattr(self.inner, "invalidate_caches", lambda: None)()

sys.meta_path[:] = [Hide(finder) for finder in sys.meta_path]
try:
    import tensorflow
    raise SystemExit("the block did not hold")
except ModuleNotFoundError:
    pass
assert importlib.util.find_spec("tensorflow") is None
sys.path.insert(0, sys.argv[2])
import test_dataset_storage as t
from kosmos_jax.dataset import pipeline
from kosmos_jax.dataset.tfds_builders import open_splits, write_instruct_grasp

records = {"train": [t._record(i) for i in range(6)], "test": [t._record(9)]}
path = write_instruct_grasp(records, sys.argv[1], t._config())
(batch,) = list(pipeline.make_dataset(open_splits(path)["train"], 6, shuffle=False))
assert sorted(batch["grasp"][:, 0].astype(int).tolist()) == list(range(6))
assert not any(m == "tensorflow" or m.startswith("tensorflow.") for m in sys.modules)
print("written and read without TensorFlow")
"""


def test_no_tensorflow_needed(tmp_path):
    """Writing and reading work where `import tensorflow` fails, whether or not it is installed here."""
    import pathlib
    import subprocess

    tests = pathlib.Path(__file__).parent
    result = subprocess.run([sys.executable, "-c", _WITHOUT_TENSORFLOW, str(tmp_path), str(tests)],
                            capture_output=True, text=True, cwd=tests.parent, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "written and read without TensorFlow" in result.stdout


def test_instruct_grasp_round_trip(written):
    path, records = written
    assert "/honest-image-fold2-name-aug1-xya-code-individual-target-digits-len80-seed0-foldseed0-" in str(path)
    splits = open_splits(path)
    assert sorted(splits) == ["test", "train"] and len(splits["train"]) == 23 and len(splits["test"]) == 5
    stored = {bytes(r["instruction"]).decode(): r for r in (splits["train"][i] for i in range(23))}
    for original in records["train"]:
        back = stored[original["instruction"]]
        assert back["image"].dtype == np.uint8
        assert np.array_equal(back["image"], original["image"])  # the joined image is the record's own
        assert np.array_equal(back["tokens"], original["tokens"])
        assert np.array_equal(back["loss_mask"], original["loss_mask"])
        assert np.array_equal(back["answers"], original["answers"])
        assert [bytes(p).decode() for p in back["photo_ids"]] == original["photo_ids"]
        assert back["object_ids"].tolist() == original["object_ids"].tolist()


def _cornell_folder(root):
    rng = np.random.default_rng(3)
    corners = "10 10\n40 10\n40 20\n10 20\n50.5 60\n70 60\n70 80\n50.5 80\n"
    for n, with_depth in ((100, True), (101, False)):
        rgb = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
        cv2.imwrite(str(root / f"pcd{n:04d}r.png"), rgb[..., ::-1])
        (root / f"pcd{n:04d}cpos.txt").write_text(corners)
        (root / f"pcd{n:04d}cneg.txt").write_text("")
        if with_depth:
            cv2.imwrite(str(root / f"pcd{n:04d}d.tiff"), rng.uniform(0, 1, (48, 64)).astype(np.float32))


def test_cornell_folder_round_trip(tmp_path):
    source = tmp_path / "cornell"
    source.mkdir()
    _cornell_folder(source)
    path = build_cornell(source, tmp_path / "tfds")
    split = open_cornell(path)
    assert len(split) == 2
    photos = {p.id: p for p in cornell.load_photos(source)}
    for i in range(2):
        record = split[i]
        photo = photos[bytes(record["id"]).decode()]
        assert np.array_equal(record["rgb"], photo.rgb)
        assert np.array_equal(record["grasps"], photo.grasps)
        if photo.depth is None:
            assert record["depth"].shape == (0, 0)
        else:
            assert np.array_equal(record["depth"], photo.depth)
    assert build_cornell(source, tmp_path / "tfds") == path  # the same files: the same folder
    # an edited source is another dataset, never the old folder
    (source / "pcd0101cpos.txt").write_text("10 10\n40 10\n40 20\n10 20\n")
    edited = build_cornell(source, tmp_path / "tfds")
    assert edited != path
    assert [split["name"] for split in json.loads((edited / "dataset_info.json").read_text())["splits"]] == ["full"]
    grasps = {bytes(r["id"]).decode(): len(r["grasps"]) for r in (open_cornell(edited)[i] for i in range(2))}
    assert grasps == {"pcd0100": 2, "pcd0101": 1}


def test_cornell_folder_missing(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        build_cornell(tmp_path / "nowhere", tmp_path / "tfds")


def _ids(batch):
    return batch["grasp"][:, 0].astype(int).tolist()


def test_batches_shapes_and_padding(written):
    path, _ = written
    source = open_splits(path)["test"]
    (batch,) = list(pipeline.make_dataset(source, batch_size=5, shuffle=False, max_answers=8))
    assert batch["image"].shape == (5, SIZE, SIZE, 3) and batch["image"].dtype == np.uint8
    assert batch["tokens"].shape == (5, LENGTH) and batch["tokens"].dtype == np.int32
    assert batch["answers"].shape == (5, 8, 5)
    dtypes = {name: batch[name].dtype for name in batch}
    assert dtypes == {"image": np.uint8, "tokens": np.int32, "loss_mask": bool, "image_mask": bool, "length": np.int32,
                      "grasp": np.float32, "grasp_mask": bool, "answers": np.float32, "answers_mask": bool,
                      "example_index": np.int64}
    assert batch["example_index"].tolist() == list(range(5))
    assert sorted(batch["answers_mask"].sum(axis=1).tolist()) == [1, 2, 3, 4, 5]
    for answers, mask in zip(batch["answers"], batch["answers_mask"]):
        assert np.all(answers[~mask] == 0)


def test_shuffle_is_seeded_and_shards_partition(written):
    path, _ = written
    source = open_splits(path)["train"]
    order = lambda **kw: sum((_ids(b) for b in pipeline.make_dataset(source, 1, drop_remainder=False, **kw)), [])
    assert order(seed=1) == order(seed=1)
    assert order(seed=1) != order(seed=2)
    assert sorted(order(seed=1)) == list(range(23))
    # each batch row says which example of the split it is, through the shuffle and the shards
    for batch in pipeline.make_dataset(source, 4, seed=3, process_index=1, process_count=2):
        examples = [source.examples[int(i)] for i in batch["example_index"]]
        assert [int(np.asarray(e["grasp"])[0]) for e in examples] == _ids(batch)
    # every example once, uneven shards, only when asked for
    shards = [order(seed=5, process_index=i, process_count=3, even_shards=False) for i in range(3)]
    assert sorted(sum(shards, [])) == list(range(23))
    assert [len(s) for s in shards] == [8, 8, 7]


def test_the_default_order_is_the_examples_own_source_shuffled(written):
    # runs made before `order` existed drew their examples from a grain source of the records themselves:
    # the default must draw them in the same order, or resumed and repeated runs would change
    path, _ = written
    source = open_splits(path)["train"]
    shuffled = pipeline.grain.MapDataset.source(source.examples).shuffle(seed=9)
    expected = [int(np.asarray(shuffled[i]["grasp"])[0]) for i in range(len(shuffled))]
    assert sum((_ids(b) for b in pipeline.make_dataset(source, 1, seed=9)), []) == expected


@pytest.mark.parametrize("process_count, batch_size", [(2, 1), (3, 1), (3, 2), (4, 3), (5, 2)])
def test_processes_get_even_disjoint_shards(written, process_count, batch_size):
    path, _ = written
    source = open_splits(path)["train"]  # 23 examples: never a multiple of these counts
    per_epoch = 23 // process_count
    make = lambda index, size: list(pipeline.make_dataset(source, size, seed=5, num_epochs=2, process_index=index,
                                                          process_count=process_count))
    counts = [len(make(index, batch_size)) for index in range(process_count)]
    assert counts == [2 * per_epoch // batch_size] * process_count  # the same count on every process
    shards = [sum((_ids(b) for b in make(index, 1)), []) for index in range(process_count)]
    epochs = [[s[:per_epoch] for s in shards], [s[per_epoch: 2 * per_epoch] for s in shards]]
    for epoch in epochs:
        seen = sum(epoch, [])
        assert len(seen) == len(set(seen)) == process_count * per_epoch  # disjoint, remainder left out
    # the left-out remainder differs between epochs, so no example is never seen
    if 23 % process_count:
        assert set(sum(epochs[0], [])) != set(sum(epochs[1], []))


def test_epochs_reshuffle(written):
    path, _ = written
    source = open_splits(path)["train"]
    ids = sum((_ids(b) for b in pipeline.make_dataset(source, 1, seed=0, num_epochs=2)), [])
    first, second = ids[:23], ids[23:]
    assert sorted(first) == sorted(second) == list(range(23)) and first != second


def test_iterator_state_restores_exactly(written):
    path, _ = written
    source = open_splits(path)["train"]
    options = pipeline.grain.ReadOptions(num_threads=2, prefetch_buffer_size=4)
    make = lambda: iter(pipeline.make_dataset(source, batch_size=3, seed=7, num_epochs=None, read_options=options))
    iterator = make()
    for _ in range(5):  # 5 + 6 batches of 3 cross the end of the 23-example epoch
        next(iterator)
    state = iterator.get_state()
    json.dumps(state)  # plain data, storable beside a checkpoint
    expected = [next(iterator) for _ in range(6)]
    fresh = make()
    fresh.set_state(state)
    for want in expected:
        got = next(fresh)
        assert got.keys() == want.keys()
        for name in want:
            assert np.array_equal(got[name], want[name]), name


def test_pipeline_errors(written, tmp_path):
    path, _ = written
    source = open_splits(path)["train"]
    with pytest.raises(ValueError, match="batch_size"):
        pipeline.make_dataset(source, 0)
    with pytest.raises(ValueError, match="process_index 3 outside 0..2"):
        pipeline.make_dataset(source, 1, process_index=3, process_count=3)
    with pytest.raises(FileNotFoundError, match="not a written TFDS dataset"):
        open_splits(tmp_path)
    with pytest.raises(ValueError, match="max_answers=1"):
        next(iter(pipeline.make_dataset(open_splits(path)["test"], 5, shuffle=False, max_answers=1)))


@pytest.fixture(scope="module")
def two_kinds(tmp_path_factory):
    """A train split of 12 examples: 0, 3, 6 and 9 of kind "non", the others "multi-name"."""
    out = tmp_path_factory.mktemp("two_kinds")
    records = [{**_record(i), "kind": "non" if i % 3 == 0 else "multi-name"} for i in range(12)]
    path = write_instruct_grasp({"train": records, "test": [_record(100)]}, out, _config(kinds=("non", "multi-name")))
    return open_splits(path)["train"]


def test_kind_repeats_draw_each_example_of_a_kind_that_many_times_an_epoch(two_kinds):
    order = batches_lib.repeated_order(two_kinds, {"non": 3})
    assert sorted(order.tolist()) == sorted([0, 0, 0, 3, 3, 3, 6, 6, 6, 9, 9, 9] + [1, 2, 4, 5, 7, 8, 10, 11])
    epoch = sum((_ids(b) for b in pipeline.make_dataset(two_kinds, 1, seed=4, order=order)), [])
    assert sorted(epoch) == sorted(order.tolist()) and epoch != sorted(epoch)  # every draw, shuffled
    # two processes share the epoch's draws without overlap
    shards = [sum((_ids(b) for b in pipeline.make_dataset(two_kinds, 1, seed=4, order=order, process_index=i,
                                                          process_count=2)), []) for i in range(2)]
    assert sorted(shards[0] + shards[1]) == sorted(order.tolist())
    assert batches_lib.repeated_order(two_kinds, {}) is None


def test_kind_repeats_resume_exactly(two_kinds):
    order = batches_lib.repeated_order(two_kinds, {"multi-name": 2})
    make = lambda: iter(pipeline.make_dataset(two_kinds, 5, seed=7, num_epochs=None, order=order))
    iterator = make()
    for _ in range(3):
        next(iterator)
    state = iterator.get_state()
    expected = [_ids(next(iterator)) for _ in range(4)]  # 7 batches of 5 cross the 20-draw epoch
    fresh = make()
    fresh.set_state(state)
    assert [_ids(next(fresh)) for _ in range(4)] == expected


@pytest.mark.parametrize("text, error", [("non", "not KIND=N"), ("non=0", "not KIND=N"), ("non=x", "not KIND=N"),
                                         ("=3", "not KIND=N"), ("non=2,non=3", "names 'non' twice")])
def test_kind_repeats_refuse_what_is_not_kind_equals_count(text, error):
    with pytest.raises(ValueError, match=error):
        batches_lib.kind_repeats(text)


def test_kind_repeats_read_and_refuse_a_kind_the_split_lacks(two_kinds):
    assert batches_lib.kind_repeats("") == {} and batches_lib.kind_repeats(None) == {}
    assert batches_lib.kind_repeats(" non=3 , multi-name=1") == {"non": 3, "multi-name": 1}
    with pytest.raises(ValueError, match="'multi-colour', which the training split does not hold.*multi-name, non"):
        batches_lib.repeated_order(two_kinds, batches_lib.kind_repeats("multi-colour=2"))


def test_shards_keep_generation_order(tmp_path, monkeypatch):
    from kosmos_jax.dataset.tfds_builders import InstructGrasp

    monkeypatch.setattr(InstructGrasp, "SHARD_EXAMPLES", 10)
    records = {"train": [_record(i) for i in range(23)], "test": [_record(50)]}
    path = write_instruct_grasp(records, tmp_path, _config(fold=4))
    assert len(sorted(path.glob("instruct_grasp-train.array_record-*-of-00003"))) == 3
    train = open_splits(path)["train"]
    assert [int(train[i]["grasp"][0]) for i in range(len(train))] == list(range(23))
    with pytest.raises(ValueError, match="split 'test' has no examples"):
        write_instruct_grasp({"train": records["train"], "test": []}, tmp_path / "empty", _config())
    assert not (tmp_path / "empty" / "instruct_grasp").exists()  # nothing published


def test_each_image_is_stored_once(written):
    path, records = written
    splits = open_splits(path)
    # 23 train records over 4 shared arrays, 5 test records over 4 of them
    assert len(splits["train"].images) == len(splits["test"].images) == IMAGES
    for name, split in splits.items():
        rows = {}
        for i in range(len(split)):
            example = split.examples[i]
            assert "image" not in example  # pixels live in the table only
            key = digest(records[name][i]["image"])
            assert rows.setdefault(key, example["image_index"]) == example["image_index"]
        assert sorted(rows.values()) == list(range(IMAGES))  # rows in first-use order, all used


def test_equal_pixels_share_a_row_and_other_pixels_do_not(tmp_path):
    first, other = _image(7), _image(8)
    images = [first, first.copy(), other, first, other.copy()]  # copies: other objects, same pixels
    records = {"train": [_record(i, image=image) for i, image in enumerate(images)], "test": [_record(9)]}
    split = open_splits(write_instruct_grasp(records, tmp_path, _config()))["train"]
    assert [split.examples[i]["image_index"] for i in range(5)] == [0, 0, 1, 0, 1]
    assert len(split.images) == 2
    for i, image in enumerate(images):
        assert np.array_equal(split[i]["image"], image)
    wrong_size = {"train": [_record(0, image=np.zeros((SIZE, SIZE + 1, 3), np.uint8))], "test": [_record(1)]}
    with pytest.raises(ValueError, match=r"shape \(16, 17, 3\) in split 'train'"):
        write_instruct_grasp(wrong_size, tmp_path / "wrong", _config())


def test_batches_join_each_example_its_own_image(written):
    path, _ = written
    for name in ("train", "test"):
        for batch in pipeline.make_dataset(open_splits(path)[name], batch_size=4, seed=3, drop_remainder=False):
            for index, image in zip(_ids(batch), batch["image"]):
                assert np.array_equal(image, SHARED_IMAGES[index % IMAGES])


def test_an_existing_dataset_is_never_written_over_silently(tmp_path):
    records = {"train": [_record(i) for i in range(6)], "test": [_record(9)]}
    config = _config(identity={"recipe": "random"})
    path = write_instruct_grasp(records, tmp_path, config)
    assert path == dataset_folder(tmp_path, config)
    with pytest.raises(FileExistsError, match="already holds this dataset"):
        write_instruct_grasp(records, tmp_path, config)
    # the identity is in the name: another recipe (not in the readable part) is another folder
    other = _config(identity={"recipe": "paper"})
    assert other.name != config.name and other.name.rsplit("-", 1)[0] == config.name.rsplit("-", 1)[0]
    assert write_instruct_grasp(records, tmp_path, other) != path
    # overwrite replaces the old examples, none of them survive
    fewer = {"train": [_record(i) for i in range(3)], "test": [_record(9)]}
    assert write_instruct_grasp(fewer, tmp_path, config, overwrite=True) == path
    assert len(open_splits(path)["train"]) == 3
    assert not list(tmp_path.glob(".staging-*"))


def test_an_interrupted_write_leaves_no_dataset(tmp_path):
    def failing(count):
        for i in range(count):
            if i == 4:
                raise RuntimeError("interrupted")
            yield _record(i)

    config = _config()
    with pytest.raises(RuntimeError, match="interrupted"):
        write_instruct_grasp({"train": failing(10), "test": [_record(9)]}, tmp_path, config)
    assert not dataset_folder(tmp_path, config).exists() and not list(tmp_path.glob(".staging-*"))

    def broken_finish(folder):
        assert (folder / "dataset_info.json").is_file()  # complete but not yet published
        raise OSError("disk full")

    records = {"train": [_record(i) for i in range(6)], "test": [_record(9)]}
    with pytest.raises(OSError, match="disk full"):
        write_instruct_grasp(records, tmp_path, config, finish=broken_finish)
    assert not dataset_folder(tmp_path, config).exists()
    # after all that, the dataset is written from scratch
    path = write_instruct_grasp(records, tmp_path, config, finish=lambda folder: (folder / "extra.txt").write_text("x"))
    assert len(open_splits(path)["train"]) == 6 and (path / "extra.txt").read_text() == "x"


# -- samples of a split -------------------------------------------------------------------------

def _colour_views(colours):
    """One 32 px view per colour (None: its colour is unknown, with a reason), distinct names."""
    views = []
    for number, colour in enumerate(colours):
        unknown = {"colour": f"photo p{number}: no pixel differs"} if colour is None else {}
        words = ObjectWords(name=f"thing{number}", colour=colour, unknown=unknown)
        views.append(View(f"p{number}", np.full((32, 32, 3), number, np.uint8), np.array([[16.0, 16, 8, 4, 0]]),
                          words, object_id=number))
    return views


def test_samples_of_unknown_words_are_skipped_and_counted():
    views = _colour_views(["red", "green", None, "blue", "yellow", "purple"])
    mosaics, skipped = MosaicCounts(), {}
    made = list(split_samples(views, ("name", "colour"), ("colour",), 0, "train", mosaics, skipped=skipped))
    colour = [s for _, s in made if s.kind == "colour" and s.scene == "single"]
    assert [s.photo_ids for s in colour] == [(v.photo_id,) for v in views if v.photo_id != "p2"]
    assert sum(s.kind == "name" for _, s in made) == len(views)  # its other kinds are made
    assert skipped == {"colour": 1, "multi-colour": 1}
    multi = [s for _, s in made if s.scene == "multi"]
    assert mosaics.built == len(multi) == len(views) - 1
    assert not any("p2" in s.photo_ids for s in multi)  # unknown colour is never a distractor either
    # words merely missing (no reason given) are still an error naming the photo
    views[2] = dataclasses.replace(views[2], words=ObjectWords(name="thing2"))
    with pytest.raises(MissingWordsError, match="'p2' has no 'colour' words"):
        list(split_samples(views, ("colour",), (), 0, "train"))


def test_encoding_on_threads_writes_the_bytes_and_rows_of_one_thread(tmp_path, monkeypatch):
    from kosmos_jax.dataset import images as image_tables

    monkeypatch.setattr(image_tables, "PENDING_IMAGES", 3)  # the writer waits for the oldest often
    rng = np.random.default_rng(5)
    distinct = [rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8) for _ in range(11)]
    order = [0, 1, 1, 2, 0, 3, 4, 5, 6, 2, 7, 8, 9, 10, 10, 3]
    tables = {}
    for encoders in (1, 2):
        folder = tmp_path / f"encoders{encoders}"
        folder.mkdir()
        writer = image_tables.ImageTableWriter(folder, "train", (SIZE, SIZE, 3), shard_images=4, encoders=encoders)
        rows = []
        for i in order:
            given = distinct[i].copy()
            rows.append(writer.index(given))
            given[...] = 0  # the caller's array reused once the row is known: the stored image stays
        tables[encoders] = (rows, writer.close(), folder)
    (rows_1, description_1, folder_1), (rows_2, description_2, folder_2) = tables[1], tables[2]
    assert rows_2 == rows_1 == [0, 1, 1, 2, 0, 3, 4, 5, 6, 2, 7, 8, 9, 10, 10, 3]
    assert description_2 == description_1 and description_1["shard_lengths"] == [4, 4, 3]
    for name in description_1["files"]:
        assert (folder_2 / name).read_bytes() == (folder_1 / name).read_bytes()
    table = image_tables.ImageTable(folder_2, description_2)
    for i, row in zip(order, rows_2):
        assert np.array_equal(table[row], distinct[i])
