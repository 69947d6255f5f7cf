"""Build an INSTRUCT-GRASP dataset from a Cornell-format folder and print its statistics as JSON.

    python -m kosmos_jax.dataset.build --source=DIR --out=DIR --protocol=honest --split=image --fold=0 \
        [--annotations=FILE] [--augmentations=16] [--kinds=all] [--seed=0] [--fold_seed=0] \
        [--validation_fraction=0.1] [--overwrite]

Steps: read the photos (kosmos_jax.sources.cornell) -> words of each object (--annotations: the
KOSMOS-E file or a synthetic_meta.json; else the folder's synthetic_meta.json; else colour from
pixels, where a photo whose pixels name no colour loses only its colour kinds, listed in the
statistics) -> folds over photos or objects BEFORE augmentation (kosmos_jax.sources.splits, drawn
with --fold_seed only, so builds that differ in --seed, the augmentation and instruction seed,
share their test folds) -> with --validation_fraction F > 0 (honest protocol only), a validation
split held out of the fold's TRAINING photos (image-wise by photo, object-wise by whole objects;
never a test photo): F times the training photos, rounded half up, at least 1, object-wise whole
objects until their photos reach that (`splits.validation_split`), drawn with --fold_seed alone;
F = 0 (the default) makes no validation split and leaves the dataset's identity as before -> views
(kosmos_jax.dataset.views: honest: --augmentations augmented views per training photo and one
un-rotated crop per test or validation photo, the same code path and crop for both; paper:
--augmentations augmented copies of every photo, folded as the public code folds them) -> samples of every kind, mosaics drawn within a split
(kosmos_jax.dataset.samples) -> text examples (kosmos_jax.text.formatter) -> tokenizer (trained on
the training split's text, or --tokenizer FILE, a KOSMOS-2 SentencePiece model) -> array_record
files under OUT (kosmos_jax.dataset.tfds_builders; each distinct image once per split, examples
refer to it by index), the tokenizer and build_stats.json beside them.

The dataset's folder is named by its main settings and a hash of its identity (`build_identity`):
every setting but --out and --overwrite, and the content of every file read (source folder,
annotations, tokenizer). A build whose folder already exists reuses it and says so ("reused": true,
with the stored statistics) without reading the photos; --overwrite rebuilds it. The folder is
written under a staging name and renamed into place when complete, so an interrupted build never
leaves a folder that a rerun would take as built.

Checked on every example, else the build fails naming the sample: the target grasp's centre lies
inside the image; the angle code is in [0, 255]; the target text parses back to the grasp (within
half a pixel and one angle bin; TLBRA-patch only within its image); and, in the honest
protocol, no test photo (object-wise: no test object) is in any training sample, mosaics included,
and likewise none of validation's in training or test samples, nor test's in validation samples.
Re-read once written: each split holds as many examples as were made, and the image joined back to
a spread of examples (about `SPOT_CHECKS` a split, the last one included) is the image it was made
from. The statistics list, per split, the photo ids and object ids its samples were made from, the
distinct images stored and the bytes on disk.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import sys
from typing import Sequence

import numpy as np
from absl import flags

from kosmos_jax import commands, grasp_text
from kosmos_jax.sources import splits
from kosmos_jax.dataset import identity as identity_lib
from kosmos_jax.dataset import images as image_table
from kosmos_jax.dataset import samples as sample_stage
from kosmos_jax.dataset import tfds_builders
from kosmos_jax.dataset.built import STATS_FILE
from kosmos_jax.dataset.checks import BuildCheckError, check_example, check_separation, check_written, spot_numbers
from kosmos_jax.dataset.inputs import RULE_KINDS, WordSource, object_words, read_photos, word_source, words_unknown
from kosmos_jax.dataset.views import augment_config, count_views, make_views
from kosmos_jax.text import layout
from kosmos_jax.text.formatter import LOSS_MODES, OVERFLOW_MODES, FormatConfig, format_sample
from kosmos_jax.text.target_rows import TARGET_CHOICES
from kosmos_jax.text.tokenizer import load_tokenizer, train_tokenizer

# BuildConfig fields that say where and whether to write, not what: left out of the identity
NOT_DATA = ("out", "overwrite")
# BuildConfig fields naming files read: in the identity by absolute path and content digest
INPUT_FILES = ("source", "annotations", "tokenizer")
# BuildConfig fields added after datasets were built and recorded: left out of the identity at the value
# that makes the data of before (so those datasets, their folder names and the runs on them stay valid)
LEFT_OUT_AT = {"validation_fraction": 0.0, "tokenizer_scheme": "fairseq"}


@dataclasses.dataclass(frozen=True)
class BuildConfig:
    source: str
    out: str | None = None
    protocol: str = "honest"
    split: str = "image"
    fold: int = 0
    folds: int = 5
    annotations: str | None = None
    augmentations: int = 1
    recipe: str = "random"
    kinds: tuple[str, ...] | None = None
    seed: int = 0  # augmentation, instructions, mosaics, target choice
    fold_seed: int | None = None  # fold assignment only; None: honest 0, paper the public code's 123
    train_crop: str | None = None
    test_crop: str | None = None
    representation: str = "xya"
    angle_code: bool = True
    individual: bool = True
    loss_on: str = "target"
    target_grasp: str = "random"
    numbers: str = "digits"
    max_length: int = 192  # KOSMOS-E's strategy sentences run to ~100 text tokens
    overflow: str = "error"
    tokenizer: str | None = None
    tokenizer_scheme: str = "fairseq"  # of --tokenizer: "fairseq" (KOSMOS-2's) or "native" (a run's own, trained here)
    text_pieces: int = 1000
    unambiguous: bool = True
    batch_size: int = 8
    validation_fraction: float = 0.0  # share of the training photos held out as split "validation" (honest only)
    overwrite: bool = False  # rebuild a dataset whose folder exists (else it is reused)

    def folds_seed(self) -> int:
        """The seed of the fold assignment actually used."""
        return splits.fold_seed(self.protocol, self.fold_seed)

    def format_config(self) -> FormatConfig:
        return FormatConfig(self.representation, self.angle_code, self.individual, self.loss_on,
                            self.target_grasp, 224, self.max_length, self.overflow)

    def split_names(self) -> tuple[str, ...]:
        """The splits the build writes, in their order: train, test, and validation when asked for."""
        return ("train", "test") + (("validation",) if self.validation_fraction else ())


def check_validation(config: BuildConfig) -> None:
    """A ValueError unless `config.validation_fraction` is a number in [0, 1) that the protocol
    supports (a validation split needs the honest protocol)."""
    fraction = splits.check_validation_fraction(config.validation_fraction)
    if fraction and config.protocol != "honest":
        raise ValueError(f"validation_fraction={config.validation_fraction}: a validation split needs the honest "
                         "protocol; the paper protocol folds augmented copies of each photo, so its held-out copies "
                         "would share photos with training")

# -- splits and views ---------------------------------------------------------------------------

def photo_split(config: BuildConfig, photos) -> dict[str, list]:
    """{split: [(photo id, copy)]} for the paper protocol, {split: [photo id]} for honest."""
    ids = [p.id for p in photos]
    object_ids = [p.object_id for p in photos]
    if config.protocol == "honest" and config.split == "object" and any(o is None for o in object_ids):
        missing = [p.id for p in photos if p.object_id is None][:5]
        raise ValueError(f"object-wise folds need an object id for every photo (processedData/z.txt); none for {missing}")
    train, test = splits.split(ids, config.fold, config.split, config.protocol,
                               object_ids=object_ids if config.split == "object" else None, k=config.folds,
                               seed=config.folds_seed(),
                               copies_per_photo=config.augmentations)
    if not config.validation_fraction:
        return {"train": list(train), "test": list(test)}
    check_validation(config)
    object_of = dict(zip(ids, object_ids))
    train, validation = splits.validation_split(
        train, config.validation_fraction, config.split, seed=config.folds_seed(),
        object_ids=[object_of[i] for i in train] if config.split == "object" else None)
    return {"train": list(train), "test": list(test), "validation": list(validation)}


def split_views(config: BuildConfig, photos, words) -> tuple[dict, dict]:
    """{split: [View]} in a fixed order, and {split: ViewCounts} (views made, grasps dropped,
    views left without grasps)."""
    index = {p.id: i for i, p in enumerate(photos)}
    by_id = {p.id: p for p in photos}
    chosen = photo_split(config, photos)
    views, counts = {}, {}
    if config.protocol == "honest":
        train_crop = config.train_crop or "gt_centroid"
        test_crop = config.test_crop or "image_centre"
        for split in config.split_names():
            # validation views are made as test views are: one un-rotated crop a photo, the test crop, the
            # test seed (a photo's keys fold in its index among all photos, so the two splits' keys differ)
            crop_only, policy = (False, train_crop) if split == "train" else (True, test_crop)
            members = [by_id[i] for i in chosen[split]]
            made, dropped = make_views(members, words, augment_config(config.augmentations, config.recipe, policy),
                                       config.seed + (0 if split == "train" else 1), index, crop_only, config.batch_size)
            views[split] = [made[key] for key in sorted(made)]
            counts[split] = count_views(sorted(dropped), made, dropped)
        return views, counts
    policy = config.train_crop or "gt_centroid"
    if config.test_crop not in (None, policy):
        raise ValueError("the paper protocol folds augmented copies, so train and test share one crop policy")
    made, dropped = make_views(photos, words, augment_config(config.augmentations, config.recipe, policy),
                               config.seed, index, False, config.batch_size)
    for split in ("train", "test"):
        keys = [tuple(key) for key in chosen[split]]
        views[split] = [made[key] for key in keys if key in made]
        counts[split] = count_views(keys, made, dropped)
    return views, counts

# -- identity and reuse -------------------------------------------------------------------------

def build_settings(config: BuildConfig) -> dict:
    """The identity but for the inputs' contents, as JSON data: every BuildConfig field but
    `NOT_DATA` (a field added later is in by default) and those of `LEFT_OUT_AT` at their value
    there, the fold seed resolved, the input files by absolute path ({"path": ...}), and the text
    format as resolved."""
    settings = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)
                if f.name not in NOT_DATA and not (f.name in LEFT_OUT_AT and getattr(config, f.name) == LEFT_OUT_AT[f.name])}
    settings["fold_seed"] = config.folds_seed()
    for name in INPUT_FILES:
        path = getattr(config, name)
        settings[name] = None if path is None else {"path": str(pathlib.Path(path).resolve())}
    return identity_lib.normalised({"build": settings, "format": dataclasses.asdict(config.format_config())})


def build_identity(config: BuildConfig, words_from: WordSource) -> dict:
    """Everything that decides the dataset's contents: `build_settings` with each input file's
    content digest ("sha256"; the annotation file's taken when `words_from` read it)."""
    identity = build_settings(config)
    inputs = identity["build"]
    inputs["source"]["sha256"] = identity_lib.content_digest(config.source)
    if config.annotations is not None:
        inputs["annotations"]["sha256"] = words_from.sha256
    if config.tokenizer is not None:
        inputs["tokenizer"]["sha256"] = identity_lib.content_digest(config.tokenizer)
    return identity


def dataset_config(config: BuildConfig, single, multi, identity: dict) -> tfds_builders.InstructGraspConfig:
    return tfds_builders.make_config(
        identity=identity, protocol=config.protocol, split_by=config.split, fold=config.fold, folds=config.folds,
        kinds=tuple(single) + tuple(sample_stage.MULTI_PREFIX + k for k in multi),
        augmentations=config.augmentations, seed=config.seed, fold_seed=config.folds_seed(),
        representation=config.representation, angle_code=config.angle_code, individual=config.individual,
        loss_on=config.loss_on, numbers=config.numbers, max_length=config.max_length,
        image_size=config.format_config().image_size)


def reused_stats(dataset_dir: pathlib.Path, identity: dict) -> dict:
    """The stored statistics of an existing dataset folder of this identity, marked "reused"."""
    path = dataset_dir / STATS_FILE
    if not path.is_file():
        raise FileExistsError(f"{dataset_dir} exists but holds no {STATS_FILE}, so it was not written by a "
                              "finished build; rebuild it with --overwrite")
    stored = json.loads(path.read_text())
    if stored.get("identity") != identity:
        raise FileExistsError(f"{dataset_dir} holds a dataset of another identity (its {STATS_FILE} differs from "
                              "this build's); rebuild it with --overwrite")
    return {**stored, "reused": True}

# -- the build ----------------------------------------------------------------------------------

def _examples(config: BuildConfig, views, single, multi, split, mosaics=None, skipped=None):
    """(sample, example) of a split, in a fixed order."""
    format_config = config.format_config()
    tag = sample_stage.SPLIT_TAGS[split]
    samples = sample_stage.split_samples(views, single, multi, config.seed, split, mosaics, config.unambiguous,
                                         skipped=skipped)
    for number, (_, sample) in enumerate(samples):
        rng = np.random.default_rng([config.seed, 99, tag, number])  # the same in both passes
        for example in format_sample(sample, format_config, rng):
            yield sample, example


def _token_stats(lengths: list[int]) -> dict:
    if not lengths:
        return {"min": 0, "mean": 0.0, "max": 0}
    values = np.asarray(lengths)
    return {"min": int(values.min()), "mean": round(float(values.mean()), 2), "p95": int(np.percentile(values, 95)),
            "max": int(values.max())}


def build(config: BuildConfig, write: bool = True, tokenize: bool = True) -> dict:
    """Build (or, with write=False, only plan, check and count) one dataset; returns the statistics
(JSON data: lists, not tuples).

    tokenize=False stops after the checks and the statistics of pass 1 (no token lengths). When
    writing into a folder that already holds this dataset (same identity), returns its stored
    statistics with "reused": true instead, unless `config.overwrite`.

    The statistics' "identity" is `build_identity` when writing; a plan-only build hashes no input
    (that is needed only to name and reuse a written dataset), so its "identity" is
    `build_settings`: the input files by path, without "sha256". Either way "word_source",
    "kinds" (as resolved) and "photos" (how many were read) sit beside it."""
    source = pathlib.Path(config.source)
    splits.check_kosmos_e_protocol(config.protocol, "the KOSMOS-E dataset build")
    if not source.is_dir():
        raise FileNotFoundError(f"source folder {source} does not exist")
    check_validation(config)
    names = config.split_names()
    format_config = config.format_config()
    words_from = word_source(source, config.annotations)
    kinds = config.kinds if config.kinds is not None else (("all",) if words_from.name != "rules" else RULE_KINDS)
    single, multi = sample_stage.parse_kinds(kinds)
    if write:
        if config.out is None:
            raise ValueError("--out is required to write the dataset")
        if not tokenize:
            raise ValueError("writing a dataset needs its tokens (tokenize=True)")
        identity = build_identity(config, words_from)
        out = pathlib.Path(config.out)
        written_config = dataset_config(config, single, multi, identity)
        dataset_dir = tfds_builders.dataset_folder(out, written_config)
        if dataset_dir.exists() and not config.overwrite:
            return reused_stats(dataset_dir, identity)
    else:
        identity = build_settings(config)

    photos, image_files = read_photos(source)
    words = object_words(words_from, photos, image_files)
    views, view_counts = split_views(config, photos, words)

    # pass 1: samples, checks, statistics, the tokenizer's corpus
    stats: dict = {"splits": {}}
    ids = {}
    corpus: list[str] = []
    for split in names:
        mosaics = sample_stage.MosaicCounts()
        samples_by_kind: dict[str, int] = {}
        examples_by_kind: dict[str, int] = {}
        photo_ids, object_ids = set(), set()
        skipped: dict[str, int] = {}
        last = None
        for sample, example in _examples(config, views[split], single, multi, split, mosaics, skipped):
            if sample is not last:
                label = sample_stage.kind_label(sample)
                samples_by_kind[label] = samples_by_kind.get(label, 0) + 1
                photo_ids.update(sample.photo_ids)
                object_ids.update(o for o in sample.object_ids if o is not None)
                last = sample
            label = sample_stage.kind_label(sample)
            examples_by_kind[label] = examples_by_kind.get(label, 0) + 1
            check_example(example, format_config)
            if split == "train":
                corpus.append(example.text)
        ids[split] = {"photos": photo_ids, "objects": object_ids}
        counts = view_counts[split]
        stats["splits"][split] = {
            "views": counts.views,
            "views_used": len(views[split]),
            "samples": sum(samples_by_kind.values()),
            "samples_by_kind": dict(sorted(samples_by_kind.items())),
            "examples": sum(examples_by_kind.values()),
            "examples_by_kind": dict(sorted(examples_by_kind.items())),
            "grasps_dropped_by_crop": counts.grasps_dropped_by_crop,
            "views_without_grasps": counts.views_without_grasps,
            "mosaics": mosaics.built,
            "mosaics_redrawn": mosaics.redraws,
            "mosaics_skipped": mosaics.skipped,
            "mosaic_skip_reasons": mosaics.skip_reasons,
            "samples_skipped_without_words": dict(sorted(skipped.items())),
            "photo_ids": sorted(photo_ids),
            "object_ids": sorted(int(o) for o in object_ids),
        }
    if "validation" in names and not stats["splits"]["validation"]["examples"]:
        raise ValueError(f"the validation split's {len(views['validation'])} views made no example (its photos' "
                         "views kept no grasp); raise --validation_fraction")
    stats["separation"] = check_separation(ids, config.protocol, config.split)
    stats["identity"] = identity
    stats["word_source"] = words_from.name
    stats["kinds"] = {"single": list(single), "multi": list(multi)}
    stats["photos"] = len(photos)
    stats["photos_without_words"] = words_unknown(words)
    if not corpus:
        raise ValueError("the training split has no examples; nothing to train a tokenizer on or to write")

    if not tokenize:
        return identity_lib.normalised(stats)
    if config.tokenizer:
        tokenizer = load_tokenizer(config.tokenizer, scheme=config.tokenizer_scheme, numbers=config.numbers)
    else:
        tokenizer = train_tokenizer(corpus, numbers=config.numbers, text_pieces=config.text_pieces,
                                    representations=(config.representation,))
    stats["tokenizer"] = {"scheme": tokenizer.scheme, "numbers": tokenizer.numbers, "vocab_size": tokenizer.vocab_size}

    # pass 2: the same examples, tokenized (and written)
    lengths = {split: [] for split in names}
    truncated = {split: 0 for split in names}
    # digests of the images of a spread of examples, to check what the written dataset joins back
    spots = {split: dict.fromkeys(spot_numbers(stats["splits"][split]["examples"])) for split in names}

    def records(split):
        for number, (sample, example) in enumerate(_examples(config, views[split], single, multi, split)):
            encoded = layout.encode_example(example, tokenizer, format_config)
            lengths[split].append(int(encoded["length"]))
            truncated[split] += int(encoded["truncated"])
            if number in spots[split]:
                spots[split][number] = image_table.digest(example.image)
            yield tfds_builders.example_record(encoded, example)

    def token_stats():
        for split in names:
            stats["splits"][split]["token_length"] = _token_stats(lengths[split])
            stats["splits"][split]["truncated"] = truncated[split]

    if not write:
        for split in names:
            for _ in records(split):
                pass
        token_stats()
        return identity_lib.normalised(stats)

    def finish(staged: pathlib.Path):
        """Runs on the complete staged folder, before it is published under its final name."""
        token_stats()
        tokenizer.save(staged / "tokenizer.model")
        examples = {split: stats["splits"][split]["examples"] for split in names}
        usage = tfds_builders.disk_usage(staged)
        for split, images in check_written(staged, examples, spots).items():
            stats["splits"][split].update(images=images, bytes_on_disk=usage["splits"][split])
        stats["tokenizer"]["path"] = str(dataset_dir / "tokenizer.model")
        stats["dataset_dir"] = str(dataset_dir)
        stats["dataset_name"] = written_config.name
        stats["bytes_on_disk"] = usage["total"]  # all but this statistics file
        stats["reused"] = False
        (staged / STATS_FILE).write_text(json.dumps(stats, indent=1))

    tfds_builders.write_instruct_grasp({split: records(split) for split in names}, out, written_config,
                                       overwrite=config.overwrite, finish=finish)
    return identity_lib.normalised(stats)  # as JSON reads it back, so a reuse returns the same

# -- command line -------------------------------------------------------------------------------

PROG = "python -m kosmos_jax.dataset.build"


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("string", "source", None, "Cornell-format folder")
    define("string", "out", None, "TFDS data_dir to write into")
    define("enum", "protocol", "honest", "scoring protocol (public: refused, it scores a baseline's maps)",
           enum_values=["honest", "paper", "public"])
    define("enum", "split", "image", "fold scheme", enum_values=["image", "object"])
    define("integer", "fold", 0, "the test fold")
    define("integer", "folds", 5, "number of folds")
    define("string", "annotations", None, "KOSMOS-E instructions-original.json or a synthetic_meta.json")
    define("integer", "augmentations", 1, "augmented views per (training) photo: the build size")
    define("enum", "recipe", "random", "random: N rotations; paper: N/4 whole-degree rotations x 4 whole-pixel "
           "shifts", enum_values=["random", "paper"])
    define("list", "kinds", None, "comma-separated: non, angle, part, name, colour, shape, purpose, strategy, "
           "position, multi-<kind>, or single / multi / all (default: all the words allow)")
    define("integer", "seed", 0, "augmentation, instructions and mosaics (not the folds)")
    define("integer", "fold_seed", None, "the fold assignment only (default: 0, or the public code's "
           f"{splits.PAPER_SEED} in the paper protocol), so builds that differ in --seed share their test folds")
    crops = ["gt_centroid", "image_centre", "random"]
    define("enum", "train_crop", None, "crop of training views (default: the protocol's)", enum_values=crops)
    define("enum", "test_crop", None, "crop of test and validation views (default: the protocol's)",
           enum_values=crops)
    define("enum", "representation", "xya", "grasp text", enum_values=list(grasp_text.REPRESENTATIONS))
    define("bool", "angle_code", True, "angles as the 256-bin code (--noangle_code: in radians)")
    define("bool", "joint", False, "one example with the whole grasp (default: centre and angle apart)")
    define("enum", "loss_on", "target", "tokens the loss is on", enum_values=list(LOSS_MODES))
    define("enum", "target_grasp", "random", "which ground-truth grasp a sample answers with",
           enum_values=list(TARGET_CHOICES))
    define("enum", "numbers", "digits", "how coordinates are written", enum_values=["digits", "values"])
    define("integer", "max_length", 192, "tokens per example, image slots included")
    define("enum", "overflow", "error", "an example longer than --max_length", enum_values=list(OVERFLOW_MODES))
    define("string", "tokenizer", None, "an existing SentencePiece model (KOSMOS-2's), ids in fairseq's scheme")
    define("enum", "tokenizer_scheme", "fairseq", "ids of --tokenizer: fairseq (KOSMOS-2's) or native (a "
           "tokenizer.model a build or run wrote)", enum_values=["fairseq", "native"])
    define("integer", "text_pieces", 1000, "pieces of a trained tokenizer besides the symbols")
    define("float", "validation_fraction", 0.0, "share of the training photos (object-wise: whole objects) held out "
           "as split 'validation', built as the test split is; honest protocol only (0: none)")
    define("bool", "ambiguous_mosaics", False, "draw distractors at random, as the paper did")
    define("bool", "overwrite", False, "rebuild the dataset if its folder exists (default: reuse it and say so)")
    flags.mark_flags_as_required(["source", "out"], flag_values=flag_values)


def build_config(args) -> BuildConfig:
    """The BuildConfig of parsed flags."""
    return BuildConfig(
        source=args.source, out=args.out, protocol=args.protocol, split=args.split, fold=args.fold, folds=args.folds,
        annotations=args.annotations, augmentations=args.augmentations, recipe=args.recipe,
        kinds=tuple(args.kinds) if args.kinds else None, seed=args.seed, fold_seed=args.fold_seed,
        train_crop=args.train_crop,
        test_crop=args.test_crop, representation=args.representation, angle_code=args.angle_code,
        individual=not args.joint, loss_on=args.loss_on, target_grasp=args.target_grasp, numbers=args.numbers,
        max_length=args.max_length, overflow=args.overflow, tokenizer=args.tokenizer,
        tokenizer_scheme=args.tokenizer_scheme, text_pieces=args.text_pieces,
        unambiguous=not args.ambiguous_mosaics, validation_fraction=args.validation_fraction,
        overwrite=args.overwrite)


def main(argv: Sequence[str] | None = None) -> int:
    return commands.run_command(define_flags, build_command, argv, prog=PROG, doc=__doc__)


def build_command(args) -> int:
    config = build_config(args)
    try:
        stats = build(config)
    except (ValueError, FileNotFoundError, FileExistsError, KeyError) as error:
        print(f"build failed: {error}", file=sys.stderr)
        return 2
    except BuildCheckError as error:  # a must-hold property broke: a bug upstream, not bad input
        print(f"build failed a check: {error}", file=sys.stderr)
        return 3
    print(json.dumps(stats, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
