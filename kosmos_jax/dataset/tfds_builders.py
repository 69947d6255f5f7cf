"""TFDS builders that write `array_record` files without TensorFlow.

Checked on tensorflow-datasets 4.9.10 with TensorFlow absent: `GeneratorBasedBuilder` with
`file_format="array_record"` writes and `tfds.builder_from_directory(...).as_data_source()` reads
(`as_dataset()` and tfrecord need TensorFlow). `tfds.features.Image(encoding_format="png")`
works as long as examples hand it encoded PNG bytes (we encode with OpenCV); reading decodes them
back to uint8 arrays without TensorFlow (the Cornell photos; INSTRUCT-GRASP images go to their
own tables). Strings come back as bytes. `DatasetInfo` is built
directly: `dataset_info_from_configs` looks for metadata files beside the builder's module.
tfds' split writer needs TensorFlow once a split passes 1 GB, so the builders write their shards
themselves (`_LocalBuilder`), in tfds' layout.

Two builders:
- `CornellFolder`: every photo of a Cornell-format folder, given as `manual_dir`, in one split
  "full" (folds are decided later, by `kosmos_jax.sources.splits`).
- `InstructGrasp`: formatted and tokenized INSTRUCT-GRASP examples, one config per dataset
  identity (`InstructGraspConfig`: a readable name of the main settings plus a hash of the
  build's full identity, `kosmos_jax.dataset.identity`). The examples are made by
  `kosmos_jax.dataset.build` and handed to the builder (`records=`), since they depend on the other
  pipeline stages; the builder owns the layout on disk and the feature spec. Version 2.0.0 stores
  each distinct image once per split (`kosmos_jax.dataset.images`): an example holds
  `image_index`, and `open_splits` gives splits that join the image back.

`write_instruct_grasp` never reuses a folder silently: it refuses an existing one unless told to
overwrite, and writes through a staging folder renamed into place at the end
(`kosmos_jax.publish`), so a folder under the final name is always complete.
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import pathlib
import re
import sys
from typing import Callable, Iterable, Mapping

import numpy as np
import tensorflow_datasets as tfds
from etils import epath
from tensorflow_datasets.core import example_serializer

from kosmos_jax.sources import cornell
from kosmos_jax.dataset import identity as identity_lib
from kosmos_jax import publish
from kosmos_jax.dataset.images import ImageTable, ImageTableWriter, StoredSplit, png_bytes
from kosmos_jax.dataset.samples import ALL_BUILD_KINDS
from kosmos_jax.dataset.shards import ShardWriter

ARRAY_RECORD = "array_record"
CORNELL_SPLIT = "full"


def _quietly(function, *args, **kwargs):
    """Run a tfds step with its progress bars off and its stdout notes sent to stderr (a build
    prints its statistics as JSON on stdout)."""
    tfds.disable_progress_bar()
    with contextlib.redirect_stdout(sys.stderr):
        return function(*args, **kwargs)


def _id_or_unknown(value) -> int:
    return -1 if value is None else int(value)


class _LocalBuilder(tfds.core.GeneratorBasedBuilder):
    """A builder that streams its examples straight into array_record shards, in generation order.

    tfds' own split writer keeps every serialized example of a split in memory and, past 1 GB,
    spills them to disk through `tf.io.gfile`, which needs TensorFlow (a paper-density build of the
    101 real photos failed there). This writer serializes each example with the features' own
    encoder, as tfds does, and appends it to the current shard (`SHARD_EXAMPLES` a shard); file
    names, split infos and metadata are tfds', so `builder_from_directory` reads the result. There
    is no hash shuffle at write time: the order is the generation order, and readers shuffle.

    Also: tfds' `code_path` probes package resources through `importlib_resources`, a backport not
    installed here (nor needed on Python >= 3.9); the file path is what it computes.
    """

    SHARD_EXAMPLES = 4096

    @tfds.core.utils.classproperty
    @classmethod
    def code_path(cls) -> epath.Path:
        return epath.Path(inspect.getfile(cls))

    def _generate_splits(self, dl_manager, download_config):
        return [
            _write_split(self.info.features, self._get_filename_template(split_name=split), examples, self.SHARD_EXAMPLES)
            for split, examples in self._split_generators(dl_manager).items()
        ]


def _write_split(features, template, examples, shard_examples: int) -> tfds.core.SplitInfo:
    """Write (key, example) pairs into array_record shards named by `template`; its SplitInfo."""
    serializer = example_serializer.ExampleSerializer(features.get_serialized_info())
    shards = ShardWriter(template.data_dir, template.split,
                         lambda i, n: template.sharded_filepath(shard_index=i, num_shards=n), shard_examples)
    try:
        for _, example in examples:
            shards.write(serializer.serialize_example(features.encode_example(example)))
    except BaseException:
        shards.abandon()
        raise
    if not len(shards):
        raise ValueError(f"split {template.split!r} has no examples to write")
    shards.close()
    return tfds.core.SplitInfo(name=template.split, shard_lengths=shards.lengths, num_bytes=shards.num_bytes,
                               filename_template=template)


class CornellFolder(_LocalBuilder):
    """Photos of a Cornell-format folder (pcdNNNNr.png, d.tiff, cpos.txt, cneg.txt; z.txt optional)."""

    VERSION = tfds.core.Version("1.0.0")
    MANUAL_DOWNLOAD_INSTRUCTIONS = "Pass the Cornell-format folder as manual_dir (DownloadConfig(manual_dir=...))."

    def _info(self) -> tfds.core.DatasetInfo:
        return tfds.core.DatasetInfo(
            builder=self,
            description="Cornell grasping photos with their positive and negative rectangles.",
            features=tfds.features.FeaturesDict(
                {
                    "id": tfds.features.Text(),
                    "rgb": tfds.features.Image(shape=(None, None, 3), encoding_format="png"),
                    # [0, 0] when the photo has no depth file
                    "depth": tfds.features.Tensor(shape=(None, None), dtype=np.float32, encoding=tfds.features.Encoding.ZLIB),
                    "grasps": tfds.features.Tensor(shape=(None, 5), dtype=np.float64),
                    "negatives": tfds.features.Tensor(shape=(None, 5), dtype=np.float64),
                    "object_id": np.int64,  # -1: unknown
                    "category": tfds.features.Text(),
                    "nan_dropped": np.int32,
                }
            ),
        )

    def _split_generators(self, dl_manager):
        root = pathlib.Path(dl_manager.manual_dir)
        if not root.is_dir():
            raise FileNotFoundError(f"Cornell folder {root} does not exist")
        return {CORNELL_SPLIT: self._generate_examples(root)}

    def _generate_examples(self, root):
        count = 0
        for photo in cornell.iter_photos(root):
            count += 1
            depth = np.zeros((0, 0), np.float32) if photo.depth is None else photo.depth.astype(np.float32)
            yield photo.id, {
                "id": photo.id,
                "rgb": png_bytes(photo.rgb),
                "depth": depth,
                "grasps": np.asarray(photo.grasps, np.float64).reshape(-1, 5),
                "negatives": np.asarray(photo.negatives, np.float64).reshape(-1, 5),
                "object_id": _id_or_unknown(photo.object_id),
                "category": photo.category or "",
                "nan_dropped": int(photo.nan_dropped),
            }
        if count == 0:
            raise FileNotFoundError(f"no Cornell photos (pcdNNNNr.png / cpos.txt) under {root}")


def build_cornell(source, data_dir) -> pathlib.Path:
    """Write the Cornell-format folder `source` under `data_dir`; returns the dataset's folder.

    The config is named by the folder's content digest, so an existing folder of that name (which
    tfds reuses) holds exactly these files' photos, and an edited source gets a folder of its own."""
    if not pathlib.Path(source).is_dir():
        raise FileNotFoundError(f"Cornell folder {source} does not exist")
    digest = identity_lib.content_digest(source)[: identity_lib.HASH_LENGTH]
    config = tfds.core.BuilderConfig(name=f"content-{digest}", description=f"the photos of {source}")
    builder = CornellFolder(config=config, data_dir=str(data_dir), file_format=ARRAY_RECORD)
    _quietly(builder.download_and_prepare, download_config=tfds.download.DownloadConfig(manual_dir=str(source)))
    return pathlib.Path(builder.data_dir)


def open_cornell(dataset_dir):
    """The random-access source of a written Cornell folder's photos (split "full")."""
    return _tfds_splits(dataset_dir)[CORNELL_SPLIT]


@dataclasses.dataclass(eq=False)  # tfds.core.BuilderConfig is a mutable dataclass
class InstructGraspConfig(tfds.core.BuilderConfig):
    """One INSTRUCT-GRASP build. `identity`: everything that decides the data (see `make_config`)."""

    protocol: str = "honest"
    split_by: str = "image"
    fold: int = 0
    folds: int = 5
    kinds: tuple[str, ...] = ()
    augmentations: int = 1
    seed: int = 0
    fold_seed: int = 0
    representation: str = "xya"
    angle_code: bool = True
    individual: bool = True
    loss_on: str = "target"
    numbers: str = "digits"
    max_length: int = 128
    image_size: int = 224
    max_answers: int = 64
    identity: dict = dataclasses.field(default_factory=dict)


def readable_name(config: InstructGraspConfig) -> str:
    """The main settings, e.g.
    "honest-image-fold0-all-aug16-xya-code-individual-target-digits-len192-seed0-foldseed0"."""
    kinds = tuple(config.kinds)
    label = "all" if sorted(kinds) == sorted(ALL_BUILD_KINDS) or not kinds else "_".join(kinds)
    return "-".join([
        config.protocol, config.split_by, f"fold{config.fold}", label, f"aug{config.augmentations}",
        config.representation, "code" if config.angle_code else "radians",
        "individual" if config.individual else "joint", config.loss_on, config.numbers,
        f"len{config.max_length}", f"seed{config.seed}", f"foldseed{config.fold_seed}",
    ])


def make_config(identity: Mapping | None = None, **fields) -> InstructGraspConfig:
    """The config of one build: named `readable_name` + "-" + a hash of the fields, the layout
    version and `identity` (the caller's account of every other input that changes the data, e.g.
    the augmentation recipe, crops, source files), so two builds share a name only when all of
    these are equal."""
    fields["kinds"] = tuple(fields.get("kinds", ()))
    identity = identity_lib.normalised(dict(identity or {}))
    probe = InstructGraspConfig(name="probe", **fields)
    hashed = identity_lib.short_hash({"fields": fields, "identity": identity, "version": str(InstructGrasp.VERSION)})
    name = f"{readable_name(probe)}-{hashed}"
    return InstructGraspConfig(name=name, description=f"INSTRUCT-GRASP {name}", identity=identity, **fields)


def instruct_features(max_length: int) -> tfds.features.FeaturesDict:
    sequence = (max_length,)
    return tfds.features.FeaturesDict(
        {
            "image_index": np.int32,  # row of the split's image table
            "tokens": tfds.features.Tensor(shape=sequence, dtype=np.int32),
            "loss_mask": tfds.features.Tensor(shape=sequence, dtype=np.bool_),
            "image_mask": tfds.features.Tensor(shape=sequence, dtype=np.bool_),
            "length": np.int32,
            "truncated": np.bool_,
            "grasp": tfds.features.Tensor(shape=(5,), dtype=np.float32),
            "grasp_mask": tfds.features.Tensor(shape=(5,), dtype=np.bool_),
            "answers": tfds.features.Tensor(shape=(None, 5), dtype=np.float32),
            "kind": tfds.features.Text(),
            "scene": tfds.features.Text(),
            "part": tfds.features.Text(),
            "instruction": tfds.features.Text(),
            "target_text": tfds.features.Text(),
            "photo_ids": tfds.features.Sequence(tfds.features.Text()),
            "object_ids": tfds.features.Tensor(shape=(None,), dtype=np.int64),  # -1: unknown
            "target": np.int32,
        }
    )


class InstructGrasp(_LocalBuilder):
    """INSTRUCT-GRASP examples; `records` maps a split name to its examples (dicts of the features,
    with the image as a uint8 array under "image", which goes to the split's image table)."""

    VERSION = tfds.core.Version("2.0.0")
    RELEASE_NOTES = {"2.0.0": "each distinct image stored once per split; examples hold image_index"}
    # no predefined configs: every build passes its own (a predefined one of the same name but other
    # sizes would be refused by tfds)

    def __init__(self, *, records: Mapping[str, Iterable[dict]] | None = None, **kwargs):
        self._records = records
        super().__init__(**kwargs)

    def _info(self) -> tfds.core.DatasetInfo:
        config = self.builder_config
        return tfds.core.DatasetInfo(
            builder=self,
            description="INSTRUCT-GRASP samples (KOSMOS-E) in the KOSMOS-2 prompt layout.",
            features=instruct_features(config.max_length),
            # "images": {split: its image table's files}, filled in as the splits are written
            metadata=tfds.core.MetadataDict({"config": dataclasses.asdict(config), "images": {}}),
        )

    def _split_generators(self, dl_manager):
        if self._records is None:
            raise ValueError("InstructGrasp writes the examples it is given: pass records={split: examples}")
        return {split: self._generate_examples(split, examples) for split, examples in self._records.items()}

    def _generate_examples(self, split, examples):
        size = self.builder_config.image_size
        images = ImageTableWriter(self.data_dir, split, (size, size, 3))
        try:
            for index, example in enumerate(examples):
                example = dict(example)
                example["image_index"] = images.index(example.pop("image"))
                yield f"{split}-{index:08d}", example
        except BaseException:
            images.abandon()
            raise
        self.info.metadata["images"][split] = images.close()


def example_record(encoded: Mapping[str, np.ndarray], example) -> dict:
    """A `TextExample` and its `layout.encode_example` arrays as one InstructGrasp record."""
    return {
        "image": example.image,
        "tokens": np.asarray(encoded["tokens"], np.int32),
        "loss_mask": np.asarray(encoded["loss_mask"], bool),
        "image_mask": np.asarray(encoded["image_mask"], bool),
        "length": np.int32(encoded["length"]),
        "truncated": bool(encoded["truncated"]),
        "grasp": np.asarray(example.grasp, np.float32),
        "grasp_mask": np.asarray(example.grasp_mask, bool),
        "answers": np.asarray(example.answers, np.float32).reshape(-1, 5),
        "kind": example.kind,
        "scene": example.scene,
        "part": example.part,
        "instruction": example.instruction,
        "target_text": example.target_text,
        "photo_ids": list(example.photo_ids),
        "object_ids": np.asarray([_id_or_unknown(o) for o in example.object_ids], np.int64),
        "target": np.int32(example.target),
    }


def dataset_folder(data_dir, config: InstructGraspConfig) -> pathlib.Path:
    """Where the dataset of `config` lives under `data_dir` (tfds' layout: name/config/version)."""
    return pathlib.Path(data_dir) / InstructGrasp.name / config.name / str(InstructGrasp.VERSION)


def write_instruct_grasp(records: Mapping[str, Iterable[dict]], data_dir, config: InstructGraspConfig, *,
                         overwrite: bool = False, finish: Callable[[pathlib.Path], None] | None = None) -> pathlib.Path:
    """Write the records of each split under `data_dir`; returns the dataset's version folder.

    An existing folder of this config is an error unless `overwrite`. `finish(folder)` runs on the
    written folder before it is published (to add files that belong to the dataset); an exception
    anywhere leaves no folder under the final name."""
    final = dataset_folder(data_dir, config)
    if final.exists() and not overwrite:
        raise FileExistsError(f"{final} already holds this dataset; open it, or overwrite it")
    relative = final.relative_to(data_dir)
    with publish.staged(data_dir, relative, overwrite) as root:
        builder = InstructGrasp(records=records, config=config, data_dir=str(root), file_format=ARRAY_RECORD)
        _quietly(builder.download_and_prepare)
        if finish is not None:
            finish(root / relative)
    return final


def disk_usage(dataset_dir) -> dict:
    """Bytes of a written INSTRUCT-GRASP folder's files: {"splits": {split: {"examples": bytes of
    its example shards, "images": bytes of its image table}}, "total": every file}."""
    pattern = re.compile(rf"^(?:(?P<images>images)|{InstructGrasp.name})-(?P<split>\w+)\.{ARRAY_RECORD}-\d+-of-\d+$")
    splits: dict[str, dict[str, int]] = {}
    total = 0
    for file in pathlib.Path(dataset_dir).iterdir():
        if not file.is_file():
            continue
        size = file.stat().st_size
        total += size
        match = pattern.match(file.name)
        if match:
            usage = splits.setdefault(match["split"], {"examples": 0, "images": 0})
            usage["images" if match["images"] else "examples"] += size
    return {"splits": splits, "total": total}


def _read_builder(dataset_dir):
    dataset_dir = pathlib.Path(dataset_dir)
    if not (dataset_dir / "dataset_info.json").is_file():
        raise FileNotFoundError(f"{dataset_dir} is not a written TFDS dataset (no dataset_info.json)")
    return tfds.builder_from_directory(str(dataset_dir))


def _tfds_splits(dataset_dir) -> dict:
    return dict(_read_builder(dataset_dir).as_data_source())


def open_splits(dataset_dir) -> dict[str, StoredSplit]:
    """{split: StoredSplit} of a written INSTRUCT-GRASP folder: its examples and image table;
    no TensorFlow, no registration."""
    builder = _read_builder(dataset_dir)
    tables = dict(builder.info.metadata.items()).get("images")  # items(): the lazy dict loads on it
    if not tables:
        raise ValueError(f"{dataset_dir} has no image tables (written before images were stored once per split); "
                         "rebuild it")
    sources = builder.as_data_source()
    return {split: StoredSplit(source, ImageTable(dataset_dir, tables[split])) for split, source in sources.items()}
