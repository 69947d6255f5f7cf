"""Cross-validation folds: partitions, no object across folds, determinism, the paper's folds."""

import math

import numpy as np
import pytest

from kosmos_jax.sources import cornell, splits

SEEDS = [0, 1, 7, 123]


def toy_photos(num_objects=40, seed=0):
    """Photo ids with 1..8 photos per object, as Cornell has."""
    rng = np.random.default_rng(seed)
    photo_ids, object_ids = [], []
    for obj in range(num_objects):
        for _ in range(int(rng.integers(1, 9))):
            photo_ids.append(f"pcd{len(photo_ids) + 100:04d}")
            object_ids.append(obj)
    return photo_ids, object_ids


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("k", [2, 5, 10])
def test_image_wise_is_a_balanced_partition(seed, k):
    photo_ids, _ = toy_photos()
    tests = [splits.split(photo_ids, f, "image", k=k, seed=seed) for f in range(k)]
    tested = [pid for t in tests for pid in t.test]
    assert sorted(tested) == sorted(photo_ids)  # every photo tested exactly once
    for train, test in tests:
        assert not set(train) & set(test) and len(train) + len(test) == len(photo_ids)
    sizes = [len(t.test) for t in tests]
    assert max(sizes) - min(sizes) <= 1


@pytest.mark.parametrize("seed", SEEDS)
def test_object_wise_partition_keeps_objects_whole(seed):
    photo_ids, object_ids = toy_photos(seed=seed)
    object_of = dict(zip(photo_ids, object_ids))
    tests = [splits.split(photo_ids, f, "object", object_ids=object_ids, seed=seed) for f in range(5)]
    assert sorted(p for t in tests for p in t.test) == sorted(photo_ids)
    fold_of_object = {}
    for fold, (train, test) in enumerate(tests):
        assert not {object_of[p] for p in train} & {object_of[p] for p in test}
        for p in test:
            assert fold_of_object.setdefault(object_of[p], fold) == fold
    sizes = [len(t.test) for t in tests]
    assert max(sizes) - min(sizes) <= max(np.bincount(object_ids))  # balanced by photo count


def test_object_wise_on_real_cornell_objects(cornell_root):
    photos = cornell.load_photos(cornell_root, load_images=False)
    ids, objs = [p.id for p in photos], [p.object_id for p in photos]
    folds = splits.object_wise_folds(ids, objs, k=5, seed=3)
    by_object = {}
    for pid, obj in zip(ids, objs):
        by_object.setdefault(obj, set()).add(folds[pid])
    assert all(len(f) == 1 for f in by_object.values())
    assert sorted(set(folds.values())) == [0, 1, 2, 3, 4]


def test_deterministic_per_seed_and_independent_of_input_order():
    photo_ids, object_ids = toy_photos()
    reverse_ids, reverse_objs = photo_ids[::-1], object_ids[::-1]
    for seed in SEEDS:
        assert splits.image_wise_folds(photo_ids, seed=seed) == splits.image_wise_folds(reverse_ids, seed=seed)
        assert (splits.object_wise_folds(photo_ids, object_ids, seed=seed)
                == splits.object_wise_folds(reverse_ids, reverse_objs, seed=seed))
    assert splits.image_wise_folds(photo_ids, seed=0) != splits.image_wise_folds(photo_ids, seed=1)
    assert (splits.object_wise_folds(photo_ids, object_ids, seed=0)
            != splits.object_wise_folds(photo_ids, object_ids, seed=1))


def test_clear_errors():
    photo_ids, object_ids = toy_photos(num_objects=3)
    with pytest.raises(ValueError, match="out of range"):
        splits.split(photo_ids, 5, "image", k=5)
    with pytest.raises(ValueError, match="out of range"):
        splits.split(photo_ids, -1, "image", k=5)
    with pytest.raises(ValueError, match="3 objects"):
        splits.split(photo_ids, 0, "object", object_ids=object_ids, k=5)
    with pytest.raises(ValueError, match="object_ids"):
        splits.split(photo_ids, 0, "object")
    with pytest.raises(ValueError, match="missing"):
        splits.split(photo_ids, 0, "object", object_ids=[None] + object_ids[1:], k=2)
    with pytest.raises(ValueError, match="photos"):
        splits.image_wise_folds(photo_ids[:3], k=5)
    with pytest.raises(ValueError, match="more than once"):
        splits.image_wise_folds(photo_ids + photo_ids[:1], k=2)
    with pytest.raises(ValueError, match="scheme"):
        splits.split(photo_ids, 0, "random")
    with pytest.raises(ValueError, match="protocol"):
        splits.split(photo_ids, 0, "image", protocol="fair")


def public_code_folds(n, eval_format):
    """KOSMOS-E's fold construction, step by step with numpy's global RNG (restored after)."""
    state = np.random.get_state()
    try:
        idxs = list(range(n))
        if eval_format == "IW":
            np.random.seed(123)
            np.random.shuffle(idxs)
        split = [0.2, 0.4, 0.6, 0.8]
        sets = [idxs[:int(np.floor(split[0] * n))]]
        for i in range(len(split) - 1):
            sets.append(idxs[int(np.floor(split[i] * n)):int(np.floor(split[i + 1] * n))])
        sets.append(idxs[int(np.floor(split[-1] * n)):])
    finally:
        np.random.set_state(state)
    return sets


@pytest.mark.parametrize("n", [7965, 885 * 16, 101 * 9, 13])
def test_paper_folds_match_the_public_code(n):
    for eval_format, folds in (("IW", splits.paper_image_wise_folds(n)),
                               ("OW", splits.paper_object_wise_folds(n))):
        for fold, expected in enumerate(public_code_folds(n, eval_format)):
            assert sorted(np.flatnonzero(folds == fold).tolist()) == sorted(expected)


def test_paper_image_wise_leaks_copies_of_test_photos_into_training():
    photo_ids = list(cornell.FULL_SET_IDS)
    train, test = splits.split(photo_ids, 0, "image", protocol="paper")
    assert len(train) + len(test) == 885 * 9 and len(test) == math.floor(0.2 * 885 * 9)
    leaked = {p for p, _ in test} & {p for p, _ in train}
    assert len(leaked) > 0.9 * len({p for p, _ in test})
    train, test = splits.split(photo_ids, 0, "object", protocol="paper")
    assert test == [(p, c) for p in photo_ids[:177] for c in range(9)]  # the first block, sorted
    assert not {p for p, _ in test} & {p for p, _ in train}
