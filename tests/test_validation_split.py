"""The validation split (`--validation-fraction`): held out of the training photos only (by photo
image-wise, by object object-wise), the fraction's rounding, views made as test views are, the
separation checks, the identity left as it was at the default 0, the errors for bad values; and a
tiny run whose periodic evaluation reads it, evaluated with `--split=validation`."""

import json
import pathlib
import sys

import numpy as np
import pytest

from kosmos_jax.sources import cornell, splits
from kosmos_jax.dataset import build as build_module
from kosmos_jax.dataset import identity as identity_lib
from kosmos_jax.dataset import inputs
from kosmos_jax.dataset import samples as sample_stage
from kosmos_jax.dataset.build import BuildConfig, build, build_settings, main
from kosmos_jax.dataset.checks import BuildCheckError, check_separation
from kosmos_jax.dataset.tfds_builders import open_splits
from user_commands import REPO, run_module, train_tiny


@pytest.fixture(scope="session")
def validation_source(synthetic_15):
    return synthetic_15


@pytest.fixture(scope="session")
def validation_photos(validation_source):
    return cornell.load_photos(validation_source)


def _config(source, **fields):
    return BuildConfig(source=str(source), kinds=("non", "multi-colour"), **fields)


# -- which photos ------------------------------------------------------------------------------

@pytest.mark.parametrize("fraction, photos, expected", [
    (0.0, 12, 0), (0.1, 12, 1), (0.25, 12, 3), (0.25, 10, 3),  # 2.5 rounds half up
    (0.05, 10, 1),  # 0.5 rounds up
    (0.01, 10, 1),  # at least one photo once the fraction is above 0
    (0.3, 11, 3), (0.5, 11, 6), (0.9, 11, 10),
])
def test_the_target_is_the_fraction_of_the_training_photos_rounded_half_up(fraction, photos, expected):
    assert splits.validation_target(fraction, photos) == expected


@pytest.mark.parametrize("split", ["image", "object"])
@pytest.mark.parametrize("fold", [0, 3])
@pytest.mark.parametrize("fraction", [0.1, 0.25, 0.4])
def test_validation_photos_come_only_from_the_training_photos(validation_source, validation_photos, split, fold, fraction):
    before = build_module.photo_split(_config(validation_source, split=split, fold=fold), validation_photos)
    after = build_module.photo_split(_config(validation_source, split=split, fold=fold, validation_fraction=fraction),
                                     validation_photos)
    assert set(before) == {"train", "test"} and set(after) == {"train", "test", "validation"}
    train, validation, test = set(after["train"]), set(after["validation"]), set(after["test"])
    assert after["test"] == before["test"]  # the test fold is untouched
    assert train | validation == set(before["train"]) and not train & validation  # the training photos, split
    assert not validation & test and train and validation
    target = splits.validation_target(fraction, len(before["train"]))
    object_of = {p.id: p.object_id for p in validation_photos}
    if split == "image":
        assert len(validation) == target
    else:  # whole objects, until their photos reach the target: at most one object's photos more
        held_objects = {object_of[i] for i in validation}
        assert not held_objects & {object_of[i] for i in train | test}
        assert {i for i in before["train"] if object_of[i] in held_objects} == validation
        largest = max(sum(object_of[i] == o for i in before["train"]) for o in held_objects)
        assert target <= len(validation) < target + largest


def test_the_draw_uses_the_fold_seed_alone(validation_source, validation_photos):
    chosen = lambda **fields: build_module.photo_split(
        _config(validation_source, validation_fraction=0.3, **fields), validation_photos)["validation"]
    assert chosen(seed=0) == chosen(seed=7) == chosen(seed=0, fold_seed=0)  # the augmentation seed plays no part
    ids = [f"pcd{i:04d}" for i in range(100, 140)]
    assert splits.validation_split(ids, 0.2, seed=1) == splits.validation_split(list(reversed(ids)), 0.2, seed=1)
    assert splits.validation_split(ids, 0.2, seed=1) != splits.validation_split(ids, 0.2, seed=2)


# -- the build ---------------------------------------------------------------------------------

@pytest.mark.parametrize("split", ["image", "object"])
def test_the_build_keeps_validation_apart_from_train_and_test(validation_source, split):
    stats = build(_config(validation_source, split=split, fold=2, validation_fraction=0.25), write=False, tokenize=False)
    parts = stats["splits"]
    assert set(parts) == {"train", "test", "validation"}
    ids = {name: (set(part["photo_ids"]), set(part["object_ids"])) for name, part in parts.items()}
    for a, b in (("train", "validation"), ("test", "validation"), ("train", "test")):
        assert not ids[a][0] & ids[b][0]
        if split == "object":
            assert not ids[a][1] & ids[b][1]
    validation = parts["validation"]
    # one view per photo, as the test split; mosaics drawn within the split only
    assert validation["views"] == validation["views_used"] + validation["views_without_grasps"]
    assert validation["samples_by_kind"]["non"] == validation["views_used"] > 0
    assert stats["separation"]["shared_photos"] == 0
    assert {k: v["shared_photos"] for k, v in stats["separation"]["validation"].items()} == {"train": 0, "test": 0}
    if split == "object":
        assert stats["separation"]["validation"]["train"]["shared_objects"] == 0
    assert stats["identity"]["build"]["validation_fraction"] == 0.25


def test_validation_views_are_the_test_views_of_the_same_photos(validation_source, validation_photos):
    """A validation photo's view is the view it gets in the fold where it is a test photo."""
    source = validation_source
    photos, image_files = inputs.read_photos(source)
    words = inputs.object_words(inputs.word_source(source, None), photos, image_files)
    views, counts = build_module.split_views(_config(source, fold=0, validation_fraction=0.3), photos, words)
    held = {view.photo_id: view for view in views["validation"]}
    assert held and counts["validation"].views == len(held) + counts["validation"].views_without_grasps
    tested = {}
    for fold in range(1, 5):
        fold_views, _ = build_module.split_views(_config(source, fold=fold), photos, words)
        tested.update({view.photo_id: view for view in fold_views["test"]})
    for photo_id, view in held.items():
        assert np.array_equal(view.image, tested[photo_id].image)
        assert np.array_equal(view.grasps, tested[photo_id].grasps)


def test_the_separation_check_covers_validation():
    ids = {"train": {"photos": {"a"}, "objects": {1}}, "test": {"photos": {"b"}, "objects": {2}},
           "validation": {"photos": {"a", "c"}, "objects": {3}}}
    with pytest.raises(BuildCheckError, match=r"validation photos \['a'\] reach training samples"):
        check_separation(ids, "honest", "image")
    ids["validation"]["photos"] = {"b", "c"}
    with pytest.raises(BuildCheckError, match=r"validation photos \['b'\] reach test samples"):
        check_separation(ids, "honest", "image")
    ids["validation"] = {"photos": {"c"}, "objects": {1}}
    assert check_separation(ids, "honest", "image")["validation"]["train"] == {"shared_photos": 0, "shared_objects": 1}
    with pytest.raises(BuildCheckError, match=r"validation objects \[1\] reach training samples"):
        check_separation(ids, "honest", "object")
    assert sample_stage.SPLIT_TAGS["validation"] not in (sample_stage.SPLIT_TAGS["train"], sample_stage.SPLIT_TAGS["test"])


def test_the_cli_writes_a_validation_split(validation_source, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["--source", str(validation_source), "--out", str(out), "--kinds", "non", "--split", "object", "--fold", "1",
            "--validation-fraction", "0.2"]
    assert main(argv) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["identity"]["build"]["validation_fraction"] == 0.2
    on_disk = open_splits(stats["dataset_dir"])
    assert set(on_disk) == {"train", "test", "validation"}
    validation = stats["splits"]["validation"]
    assert len(on_disk["validation"]) == validation["examples"] > 0
    assert validation["images"] > 0 and validation["bytes_on_disk"]["images"] > 0
    assert validation["token_length"]["max"] > 0 and "truncated" in validation
    stored = {bytes(on_disk["validation"][i]["photo_ids"][0]).decode() for i in range(len(on_disk["validation"]))}
    assert sorted(stored) == validation["photo_ids"]
    written = json.loads((pathlib.Path(stats["dataset_dir"]) / "build_stats.json").read_text())
    assert written["splits"]["validation"] == validation
    # without the flag: another dataset, of two splits
    assert main(argv[:-2]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert plain["dataset_dir"] != stats["dataset_dir"] and set(open_splits(plain["dataset_dir"])) == {"train", "test"}
    assert "validation_fraction" not in plain["identity"]["build"]


# -- identity at the default, and bad values ---------------------------------------------------

def test_the_default_leaves_the_identity_and_the_folder_name_as_they_were():
    """The hashes below are those of main before the validation split existed (git archive of 30cbcad)."""
    cases = [(BuildConfig(source="/nonexistent/cornell"), "9a91f33ed645",
              "honest-image-fold0-all-aug1-xya-code-individual-target-digits-len192-seed0-foldseed0-cfcc7ce12e31"),
             (BuildConfig(source="/nonexistent/cornell", split="object", fold=2, kinds=("non",), augmentations=16),
              "aacded18a565",
              "honest-object-fold2-non-aug16-xya-code-individual-target-digits-len192-seed0-foldseed0-8a54920bf172")]
    for config, identity_hash, name in cases:
        for same in (config, build_module.dataclasses.replace(config, validation_fraction=0.0),
                     build_module.dataclasses.replace(config, validation_fraction=0)):
            settings = build_settings(same)
            assert "validation_fraction" not in settings["build"]
            assert identity_lib.short_hash(settings) == identity_hash
            single, multi = sample_stage.parse_kinds(same.kinds or ("all",))
            assert build_module.dataset_config(same, single, multi, settings).name == name
        other = build_settings(build_module.dataclasses.replace(config, validation_fraction=0.1))
        assert other["build"]["validation_fraction"] == 0.1 and identity_lib.short_hash(other) != identity_hash


@pytest.mark.parametrize("fraction", [-0.1, 1.0, 1.5, float("nan"), "a tenth"])
def test_a_fraction_outside_zero_to_one_is_refused(validation_source, fraction):
    with pytest.raises(ValueError, match=r"validation_fraction=.*expected a number in \[0, 1\)"):
        build(_config(validation_source, validation_fraction=fraction), write=False, tokenize=False)


@pytest.mark.parametrize("split, fraction", [("image", 0.97), ("object", 0.99)])
def test_a_fraction_that_leaves_no_training_photo_is_refused(validation_source, split, fraction):
    with pytest.raises(ValueError, match=r"validation_fraction=.*(leaves no training photo|takes every training object)"):
        build(_config(validation_source, split=split, validation_fraction=fraction), write=False, tokenize=False)


def test_the_paper_protocol_refuses_a_validation_split(validation_source, tmp_path, capsys):
    with pytest.raises(ValueError, match="validation split needs the honest protocol"):
        build(_config(validation_source, protocol="paper", validation_fraction=0.2), write=False, tokenize=False)
    assert main(["--source", str(validation_source), "--out", str(tmp_path), "--protocol", "paper",
                 "--validation-fraction", "0.2"]) == 2
    assert "honest protocol" in capsys.readouterr().err
    assert main(["--source", str(validation_source), "--out", str(tmp_path), "--validation-fraction", "1"]) == 2
    assert "expected a number in [0, 1)" in capsys.readouterr().err


def test_the_experiment_check_refuses_a_bad_fraction():
    sys.path.insert(0, str(REPO / "configs"))
    try:
        import kosmos_e
    finally:
        sys.path.pop(0)
    from kosmos_jax.experiments import checks
    from kosmos_jax.experiments.spec import ExperimentError

    data = kosmos_e.get_config("tiny").data
    assert data.build.validation_fraction == 0.0
    data.build.validation_fraction = 0.2
    assert checks.build_settings(data, "arm").validation_fraction == 0.2
    data.build.protocol = "paper"
    with pytest.raises(ExperimentError, match="arm: data.build: .*honest protocol"):
        checks.build_settings(data, "arm")


def test_a_fold_record_carries_the_last_validation_figures_when_there_are_any(tmp_path):
    from kosmos_jax.experiments import records

    lines = [{"step": 1, "loss": 2.0}, {"step": 1, "split": "validation", "loss": 1.5, "accuracy": 0.1},
             {"step": 2, "split": "validation", "loss": 1.2, "accuracy": 0.2, "grasp_accuracy": 5.0},
             {"step": 2, "split": "test", "loss": 1.3, "accuracy": 0.15, "grasp_accuracy": 4.0}]
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    assert records.validation_evaluation(tmp_path) == {"step": 2, "loss": 1.2, "accuracy": 0.2, "grasp_accuracy": 5.0}
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines if line.get("split") != "validation"))
    assert records.validation_evaluation(tmp_path) is None


# -- the trainer and the evaluate command ------------------------------------------------------

@pytest.mark.slow
def test_a_run_watches_validation_and_records_test_at_the_end(tmp_path_factory):
    workdir = train_tiny(tmp_path_factory.mktemp("validation_run"), tmp_path_factory.mktemp("validation_datasets"),
                         "--config.data.build.validation_fraction=0.25", "--config.train.eval_every=1",
                         "--config.train.grasp_eval_every=1")
    evals = [(r["step"], r["split"], "grasp_accuracy" in r)
             for r in map(json.loads, (workdir / "metrics.jsonl").read_text().splitlines()) if "split" in r]
    assert evals == [(1, "validation", True), (2, "validation", True), (2, "test", True)]
    done = run_module("kosmos_jax.evaluate", f"--workdir={workdir}", "--split=validation", "--json")
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads(done.stdout)
    assert results["split"] == "validation" and results["step"] == 2 and results["instructions"] > 0
    assert (workdir / "eval" / "2" / "validation" / "results.json").is_file()
