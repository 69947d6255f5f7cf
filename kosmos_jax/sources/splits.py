"""Cross-validation folds, decided over photo ids BEFORE any augmentation (DESIGN.md section 3).

Three protocols (PROTOCOLS); KOSMOS-E's builds and sweeps take the first two, `public` is the
baselines' own (kosmos_jax.baselines):
- honest (default): image-wise folds are a seeded permutation of the PHOTOS; object-wise folds
  group photos by physical object id (Cornell's z.txt), so no object is in two folds, and balance
  the folds by photo count.
- paper: what KOSMOS-E's public code does (data/utils/data/cornell_data.py,
  generate_dataloader_five_fold_cross_validation). It folds the AUGMENTED samples: the sorted file
  list of the augmented set (`copies_per_photo` samples per photo, 9 in its 885 * 9 = 7965 set),
  shuffled with numpy's legacy `np.random.seed(123); np.random.shuffle` for image-wise ("IW"), so
  copies of a test photo land in training; and cut into contiguous blocks of that sorted list,
  unshuffled, for "object-wise" ("OW"). Block i is samples [floor(i/k * n), floor((i+1)/k * n)).
  Paper samples are named (photo id, copy index), the copy index counting a photo's augmented
  copies in their sorted order.
- public: what GR-ConvNet's and GG-CNN's public code does (train_network.py of skumra/robotic-grasping,
  train_ggcnn.py of dougsm/ggcnn): ONE split of the sorted photo list (their sorted `*/pcd*cpos.txt`
  glob), the first floor(0.9 n) photos train and the rest test (`--split 0.9`). Image-wise: the
  indices shuffled first with numpy's legacy `np.random.seed(123); np.random.shuffle` (`--ds-shuffle
  --random-seed 123`); "object-wise": not shuffled, the last tenth of the file list (their default,
  and the photos their evaluate.py / eval_ggcnn.py test on). There is no k-fold: fold 0 only; k is
  not used. Lists of photo ids, sorted.

Everything is a pure function of the ids and the seed; the input order of `photo_ids` does not
matter (ids are sorted first).

    train, test = split(photo_ids, fold=0, scheme="object", object_ids=ids, seed=0)

A validation split (honest protocol only) is held out of a fold's TRAINING photos, never its test
photos, by `validation_split`: image-wise by photo, object-wise by object, drawn with the fold seed
alone (its own stream of it), so builds that differ only in their augmentation seed share it.

    train, validation = validation_split(train, 0.1, "object", object_ids=ids_of_train, seed=0)
"""

from __future__ import annotations

import math
from typing import Hashable, NamedTuple, Sequence

import numpy as np

PAPER_SEED = 123
PAPER_COPIES_PER_PHOTO = 9
PUBLIC = "public"
PROTOCOLS = ("honest", "paper", PUBLIC)
KOSMOS_E_PROTOCOLS = ("honest", "paper")  # what KOSMOS-E's builds, views and sweeps take
PUBLIC_SEED = 123  # train_network.py's --random-seed
PUBLIC_TRAIN_FRACTION = 0.9  # --split
PUBLIC_REFUSED = ("protocol 'public' scores a baseline's quality, angle and width maps (GR-ConvNet, GG-CNN2: "
                  "configs/baselines.py with data.protocol='public', one split, fold 0); KOSMOS-E's datasets "
                  "and experiment sweeps take 'honest' or 'paper'")


VALIDATION_STREAM = 0x76616C  # "val": the validation draw's stream of the fold seed


class Split(NamedTuple):
    train: list
    test: list


class ValidationSplit(NamedTuple):
    train: list
    validation: list


def _sorted_unique(photo_ids: Sequence[str]) -> list[str]:
    ids = sorted(photo_ids)
    for previous, current in zip(ids, ids[1:]):
        if previous == current:
            raise ValueError(f"photo id {current!r} appears more than once")
    return ids


def _check_k(k: int, groups: int, what: str) -> None:
    if k < 2:
        raise ValueError(f"k={k}: need at least 2 folds")
    if k > groups:
        raise ValueError(f"k={k} folds is more than the {groups} {what} to split")


def image_wise_folds(photo_ids: Sequence[str], k: int = 5, seed: int = 0) -> dict[str, int]:
    """Honest image-wise folds: {photo id: fold}, fold sizes differing by at most one."""
    ids = _sorted_unique(photo_ids)
    _check_k(k, len(ids), "photos")
    order = np.random.default_rng(seed).permutation(len(ids))
    return {ids[index]: position % k for position, index in enumerate(order)}


def object_wise_folds(photo_ids: Sequence[str], object_ids: Sequence[Hashable | None],
                      k: int = 5, seed: int = 0) -> dict[str, int]:
    """Honest object-wise folds: {photo id: fold}; all photos of an object share a fold.

    Objects are shuffled with `seed`, then placed largest first (ties in shuffled order) into the
    fold with the fewest photos so far, which balances the folds by photo count.
    """
    if len(object_ids) != len(photo_ids):
        raise ValueError(f"{len(photo_ids)} photo ids but {len(object_ids)} object ids")
    missing = [photo for photo, obj in zip(photo_ids, object_ids) if obj is None]
    if missing:
        raise ValueError(f"object-wise folds need an object id for every photo; missing for "
                         f"{len(missing)} photos, e.g. {sorted(missing)[:5]}")
    _sorted_unique(photo_ids)
    members: dict[Hashable, list[str]] = {}
    for photo, obj in zip(photo_ids, object_ids):
        members.setdefault(obj, []).append(photo)
    _check_k(k, len(members), "objects")
    objects_sorted = sorted(members, key=repr)  # a canonical order before the seeded shuffle
    shuffled = [objects_sorted[i] for i in np.random.default_rng(seed).permutation(len(objects_sorted))]
    shuffled.sort(key=lambda obj: -len(members[obj]))  # stable: ties keep the shuffled order
    fold_sizes = [0] * k
    folds = {}
    for obj in shuffled:
        fold = int(np.argmin(fold_sizes))
        fold_sizes[fold] += len(members[obj])
        for photo in members[obj]:
            folds[photo] = fold
    return folds


def _paper_block_bounds(num_samples: int, k: int) -> list[int]:
    # The public code cuts at floor(f * n) for f in [0.2, 0.4, 0.6, 0.8]; i / k is the same double.
    return [0] + [math.floor(i / k * num_samples) for i in range(1, k)] + [num_samples]


def paper_object_wise_folds(num_samples: int, k: int = 5) -> np.ndarray:
    """KOSMOS-E's "object-wise" folds: fold of each sample of the sorted list, contiguous blocks."""
    _check_k(k, num_samples, "samples")
    bounds = _paper_block_bounds(num_samples, k)
    folds = np.empty(num_samples, np.int64)
    for fold in range(k):
        folds[bounds[fold]:bounds[fold + 1]] = fold
    return folds


def paper_image_wise_folds(num_samples: int, k: int = 5, seed: int = PAPER_SEED) -> np.ndarray:
    """KOSMOS-E's image-wise folds over augmented samples: fold of each sample index.

    Reproduces `idxs = list(range(n)); np.random.seed(seed); np.random.shuffle(idxs)` followed by
    the block cut, without touching numpy's global state.
    """
    _check_k(k, num_samples, "samples")
    order = list(range(num_samples))
    np.random.RandomState(seed).shuffle(order)
    blocks = paper_object_wise_folds(num_samples, k)
    folds = np.empty(num_samples, np.int64)
    folds[np.asarray(order, np.int64)] = blocks
    return folds


def paper_samples(photo_ids: Sequence[str], copies_per_photo: int = PAPER_COPIES_PER_PHOTO) -> list[tuple[str, int]]:
    """The augmented samples in the public code's sorted file order: (photo id, copy index)."""
    if copies_per_photo < 1:
        raise ValueError(f"copies_per_photo={copies_per_photo} must be at least 1")
    return [(photo, copy) for photo in _sorted_unique(photo_ids) for copy in range(copies_per_photo)]


def public_split(photo_ids: Sequence[str], shuffle: bool, seed: int = PUBLIC_SEED) -> Split:
    """The public code's one split (see the module docstring): sorted train and test photo ids."""
    ids = _sorted_unique(photo_ids)
    cut = math.floor(PUBLIC_TRAIN_FRACTION * len(ids))  # int(np.floor(args.split * dataset.length))
    if cut == 0 or cut == len(ids):
        raise ValueError(f"{len(ids)} photos: the public split of the first {PUBLIC_TRAIN_FRACTION:.0%} leaves "
                         "an empty train or test side; it needs at least 2 photos")
    order = list(range(len(ids)))
    if shuffle:
        np.random.RandomState(seed).shuffle(order)  # np.random.seed(seed); np.random.shuffle(indices)
    return Split(sorted(ids[i] for i in order[:cut]), sorted(ids[i] for i in order[cut:]))


def check_kosmos_e_protocol(protocol: str, where: str) -> None:
    """A ValueError naming `where` (a KOSMOS-E stage) unless `protocol` is one of KOSMOS_E_PROTOCOLS;
    for the baselines' `public`, saying why."""
    if protocol == PUBLIC:
        raise ValueError(f"{where}: {PUBLIC_REFUSED}")
    if protocol not in KOSMOS_E_PROTOCOLS:
        raise ValueError(f"{where}: unknown protocol {protocol!r}; expected one of {KOSMOS_E_PROTOCOLS}")


def folds_to_split(items: Sequence, folds: Sequence[int], fold: int, k: int) -> Split:
    """Items whose fold is `fold` are the test set, the rest training; input order kept."""
    if not 0 <= fold < k:
        raise ValueError(f"fold {fold} is out of range for k={k} folds (0..{k - 1})")
    train = [item for item, f in zip(items, folds) if f != fold]
    test = [item for item, f in zip(items, folds) if f == fold]
    return Split(train, test)


def fold_seed(protocol: str, seed: int | None = None) -> int:
    """The seed `protocol`'s split draws with: `seed`, else the protocol's own (honest 0; paper and public
    the public code's 123)."""
    if seed is not None:
        return int(seed)
    return {"honest": 0, "paper": PAPER_SEED, PUBLIC: PUBLIC_SEED}[protocol]


def split(photo_ids: Sequence[str], fold: int, scheme: str = "image", protocol: str = "honest",
          object_ids: Sequence[Hashable | None] | None = None, k: int = 5, seed: int | None = None,
          copies_per_photo: int = PAPER_COPIES_PER_PHOTO) -> Split:
    """Train and test items of fold `fold` (0-based).

    honest: lists of photo ids, sorted; seed defaults to 0. `object_ids` (aligned with
      `photo_ids`) is required for scheme="object".
    paper: lists of (photo id, copy index) augmented samples in sorted file order; seed (image-wise
      only) defaults to the public code's 123; object ids are not used (its "object-wise" split is
      contiguous blocks of the file list).
    public: `public_split`, shuffled for scheme "image" (seed defaults to 123), not for "object";
      fold must be 0 (one split), k and object ids are not used.
    """
    if scheme not in ("image", "object"):
        raise ValueError(f"scheme {scheme!r} must be 'image' or 'object'")
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol {protocol!r} must be one of {', '.join(PROTOCOLS)}")
    seed = fold_seed(protocol, seed)
    if protocol == "honest":
        if scheme == "image":
            folds = image_wise_folds(photo_ids, k, seed)
        else:
            if object_ids is None:
                raise ValueError("object-wise split needs object_ids (one per photo id)")
            folds = object_wise_folds(photo_ids, object_ids, k, seed)
        ids = sorted(folds)
        return folds_to_split(ids, [folds[i] for i in ids], fold, k)
    if protocol == "paper":
        samples = paper_samples(photo_ids, copies_per_photo)
        if scheme == "image":
            folds = paper_image_wise_folds(len(samples), k, seed)
        else:
            folds = paper_object_wise_folds(len(samples), k)
        return folds_to_split(samples, folds, fold, k)
    if fold != 0:  # public
        raise ValueError(f"fold {fold}: the public protocol has one split (the first "
                         f"{PUBLIC_TRAIN_FRACTION:.0%} of the photo list trains, the rest tests); only fold 0")
    return public_split(photo_ids, shuffle=scheme == "image", seed=seed)


def check_validation_fraction(fraction) -> float:
    """`fraction` as a float if it is a share of the training photos a validation split may take:
    a finite number in [0, 1); else a ValueError that says so."""
    try:
        value = float(fraction)
    except (TypeError, ValueError):
        raise ValueError(f"validation_fraction={fraction!r}: expected a number in [0, 1)") from None
    if not math.isfinite(value) or not 0.0 <= value < 1.0:
        raise ValueError(f"validation_fraction={fraction!r}: expected a number in [0, 1) (a share of the "
                         "training photos; 0: no validation split)")
    return value


def validation_target(fraction: float, photos: int) -> int:
    """Validation photos asked of `photos` training photos: fraction * photos rounded half up,
    at least 1 when the fraction is above 0 (0 when it is 0)."""
    fraction = check_validation_fraction(fraction)
    if fraction == 0.0:
        return 0
    return max(1, math.floor(fraction * photos + 0.5))


def validation_split(train_ids: Sequence[str], fraction: float, scheme: str = "image",
                     object_ids: Sequence[Hashable | None] | None = None, seed: int = 0) -> ValidationSplit:
    """Hold out a validation split from a fold's training photo ids (honest protocol): lists of
    photo ids, sorted; fraction 0 leaves `train_ids` whole.

    The target is `validation_target(fraction, len(train_ids))` photos. image-wise: that many
    photos, drawn by a seeded permutation of the sorted ids. object-wise (`object_ids` aligned
    with `train_ids`): whole objects, in a seeded order of the sorted objects, until their photos
    reach the target (so it may hold up to one object's photos more than the target). The draw
    uses `seed` (the fold seed) in a stream of its own. An error when no training photo (object-
    wise: no training object) would be left.
    """
    if scheme not in ("image", "object"):
        raise ValueError(f"scheme {scheme!r} must be 'image' or 'object'")
    ids = _sorted_unique(train_ids)
    target = validation_target(fraction, len(ids))
    if target == 0:
        return ValidationSplit(list(ids), [])
    rng = np.random.default_rng([int(seed), VALIDATION_STREAM])
    if scheme == "image":
        if target >= len(ids):
            raise ValueError(f"validation_fraction={fraction} of {len(ids)} training photos asks for {target} "
                             "validation photos and leaves no training photo; lower it")
        held = {ids[i] for i in rng.permutation(len(ids))[:target]}
    else:
        if object_ids is None or len(object_ids) != len(train_ids):
            raise ValueError("an object-wise validation split needs one object id per training photo id")
        if any(obj is None for obj in object_ids):
            raise ValueError("an object-wise validation split needs an object id for every training photo")
        members: dict[Hashable, list[str]] = {}
        for photo, obj in zip(train_ids, object_ids):
            members.setdefault(obj, []).append(photo)
        objects = sorted(members, key=repr)
        held = set()
        for index in rng.permutation(len(objects)):
            if len(held) >= target:
                break
            held.update(members[objects[index]])
        if len(held) >= len(ids):
            raise ValueError(f"validation_fraction={fraction} of {len(ids)} training photos ({len(objects)} objects) "
                             f"asks for {target} validation photos, which takes every training object; lower it")
    return ValidationSplit([i for i in ids if i not in held], [i for i in ids if i in held])
