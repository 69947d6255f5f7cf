"""Test views, baselines and fold scoring of the two protocols, and the demo end to end."""

import json
import math

import numpy as np
import pytest

from kosmos_jax import demo
from kosmos_jax.sources import cornell
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.sources.photo import Photo
from kosmos_jax.dataset import views
from kosmos_jax.scoring import fold_scores, no_learning
from kosmos_jax.experiments import spec
from kosmos_jax.train import trainer
from kosmos_jax.train.metrics_log import read_metrics



def make_photo(index, grasps, rng):
    rgb = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    return Photo(id=f"pcd{index:04d}", rgb=rgb, depth=None, grasps=np.asarray(grasps, np.float64), object_id=index % 5)


@pytest.fixture
def photos():
    rng = np.random.default_rng(0)
    out = []
    for i in range(10):
        centre = rng.uniform(250, 390), rng.uniform(180, 300)
        out.append(make_photo(100 + i, [[*centre, 40, 12, 0.3], [centre[0] + 10, centre[1] - 5, 30, 10, -0.2]], rng))
    return out


def test_honest_views_are_photo_centre_crops_with_grasps_moved(photos):
    v = views.evaluation_views(photos, "honest")
    assert v.images.shape == (10, 224, 224, 3) and list(v.copy) == [0] * 10
    # 351 crop at the photo centre: corner (144.5, 64.5) rounded to (145, 65); then the central 224
    # starts 63 px further in: a pure shift by (208, 128), pixels copied exactly.
    left, top = 145 + 63, 65 + 63
    for i, photo in enumerate(photos):
        np.testing.assert_array_equal(v.images[i], photo.rgb[top:top + 224, left:left + 224])
        np.testing.assert_allclose(v.grasps[i, :2, :2], photo.grasps[:, :2] - [left, top], atol=1e-3)
        np.testing.assert_allclose(v.grasps[i, :2, 2:], photo.grasps[:, 2:], atol=1e-3)


def test_paper_views_are_centred_on_the_labels(photos):
    v = views.evaluation_views(photos, "paper", seed=3)
    assert len(v.photo_id) == 90 and sorted(set(v.copy)) == list(range(9))
    # rotation about the crop centre (the label centroid) keeps it there; the shift moves it <= 40 px
    for row in range(90):
        kept = v.mask[row]
        if kept.all():
            offset = v.grasps[row, :, :2].mean(axis=0) - 112
            assert np.abs(offset).max() <= 41.5
    again = views.evaluation_views(photos, "paper", seed=3)
    np.testing.assert_array_equal(again.grasps, v.grasps)


def test_views_reject_bad_input(photos):
    with pytest.raises(ValueError, match="protocol"):
        views.evaluation_views(photos, "leaky")
    photos[0].rgb = None
    with pytest.raises(ValueError, match="pcd0100"):
        views.evaluation_views(photos, "honest")


def test_ground_truth_mean_treats_angles_as_axes():
    grasps = np.array([[[10.0, 20.0, 30.0, 10.0, math.radians(89)], [30.0, 40.0, 30.0, 10.0, math.radians(-89)]]])
    mean = no_learning.ground_truth_mean(grasps, np.array([[True, True]]))[0]
    assert mean[:2] == pytest.approx([20.0, 30.0])
    assert abs(abs(mean[2]) - math.pi / 2) < 1e-5  # not 0, which the plain mean gives
    empty = no_learning.ground_truth_mean(grasps, np.array([[False, False]]))
    assert np.isnan(empty).all()
    assert no_learning.image_centre(grasps, None).tolist() == [[112.0, 112.0, 0.0]]


def crafted_views(count=10):
    grasps = np.zeros((count, 2, 5), np.float32)
    grasps[:, 0] = [100.0, 100.0, 40.0, 10.0, 0.0]
    mask = np.zeros((count, 2), bool)
    mask[:, 0] = True
    return views.Views(np.zeros((count, 1, 1, 3), np.uint8), grasps, mask, [f"p{i}" for i in range(count)], np.zeros(count, int), 0)


def test_score_counts_per_fold_and_failures_by_protocol():
    v = crafted_views()
    pred = np.tile([[100.0, 100.0, 0.0]], (10, 1))
    pred[:3] = np.nan  # three unparseable answers
    folds = np.arange(10) % 5
    honest = fold_scores.score(pred, v, folds, "honest")
    assert honest.failures == pytest.approx(0.3)
    assert honest.per_fold == [50.0, 50.0, 50.0, 100.0, 100.0]  # views 0, 1, 2 sit in folds 0, 1, 2
    paper = fold_scores.score(pred, v, folds, "paper")  # the ground-truth mean stands in for failures
    assert paper.per_fold == [100.0] * 5 and paper.mean == 100.0 and paper.std == 0.0


def test_views_without_ground_truth_and_empty_folds_are_counted():
    v = crafted_views()
    v.mask[[1, 4, 9]] = False  # views 4 and 9 are all of fold 4; view 1 is half of fold 1
    pred = np.tile([[100.0, 100.0, 0.0]], (10, 1))
    pred[6] = [150.0, 100.0, 0.0]  # a miss in fold 1
    result = fold_scores.score(pred, v, np.arange(10) % 5, "honest")
    assert result.per_fold == [100.0, 0.0, 100.0, 100.0]  # fold 1 is view 6 alone; fold 4 has nothing
    assert (result.views, result.skipped_views, result.empty_folds) == (7, 3, 1)
    assert result.mean == 75.0
    full = fold_scores.score(pred, crafted_views(), np.arange(10) % 5, "honest")
    assert (full.views, full.skipped_views, full.empty_folds) == (10, 0, 0)
    v.mask[:] = False
    nothing = fold_scores.score(pred, v, np.arange(10) % 5, "honest")
    assert nothing.per_fold == [] and nothing.empty_folds == 5 and math.isnan(nothing.mean)


def test_demo_footnote_names_skipped_views_and_empty_folds():
    row = dict(data="cornell", protocol="paper", split="object", views=7, skipped_views=3, empty_folds=1)
    clean = dict(row, data="synthetic", skipped_views=0, empty_folds=0)
    note = demo.skipped_note([row, dict(row, backend="reference"), clean])
    assert "cornell paper object-wise: 3 of 10 views skipped, 1 empty folds" in note
    assert "synthetic" not in note
    assert "no fold was empty" in demo.skipped_note([clean])


def test_honest_folds_keep_photos_and_objects_together():
    v = crafted_views()
    v.photo_id = [f"p{i // 2}" for i in range(10)]  # two views per photo
    folds = fold_scores.view_folds(v, "image", "honest")
    assert all(folds[i] == folds[i + 1] for i in range(0, 10, 2))
    object_of = {f"p{i}": i % 5 for i in range(5)}
    assert len(set(fold_scores.view_folds(v, "object", "honest", object_of).tolist())) == 5
    with pytest.raises(ValueError, match="object"):
        fold_scores.view_folds(v, "object", "honest")


def demo_config(tmp_path, **overrides):
    config = spec.load_config("configs/demo.py:tiny")
    config.out = str(tmp_path)  # an absolute path wins over the repository root
    config.update(overrides)
    return config


def test_demo_runs_on_its_own_synthetic_data(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(demo, "DEFAULT_CORNELL", tmp_path / "absent")
    demo.run(demo_config(tmp_path, train_config=""))
    rows = json.loads((tmp_path / "results.json").read_text())
    assert {r["data"] for r in rows} == {"synthetic"}
    assert not (tmp_path / "run").exists()  # train_config "" trains nothing
    combos = {(r["protocol"], r["split"], r["backend"], r["predictor"]) for r in rows}
    assert len(combos) == 2 * 2 * 2 * 2
    oracle = [r for r in rows if r["predictor"] == "gt_mean_oracle" and r["protocol"] == "honest"]
    centre = [r for r in rows if r["predictor"] == "image_centre" and r["protocol"] == "honest"]
    assert min(r["mean"] for r in oracle) > max(r["mean"] for r in centre)
    assert all({"skipped_views", "empty_folds"} <= set(r) for r in rows)
    made = {"honest": 1, "paper": 3 * 3}  # views a photo gives: its centre crop; 3 rotations x 3 shifts
    assert all(r["views"] + r["skipped_views"] == r["photos"] * made[r["protocol"]] for r in rows)
    assert all(r["empty_folds"] == 0 for r in rows if r["skipped_views"] == 0)  # every fold holds views
    out = capsys.readouterr().out
    assert "image-wise" in out and demo.skipped_note(rows) in out


def test_demo_rewrites_a_stale_partial_set_from_older_versions(tmp_path, capsys):
    root = tmp_path / "synthetic_2_seed0"
    scenes.write_dataset(root, 2, 0)
    (root / "synthetic_meta.json").unlink()  # an older version was stopped before writing it
    (root / "01" / "pcd0101r.png").unlink()
    assert demo.synthetic_source(tmp_path, 2, 0) == root
    assert "writing 2 synthetic photos" in capsys.readouterr().err
    assert scenes.read_meta(root).keys() == {"pcd0100", "pcd0101"}
    assert len(cornell.load_photos(root, load_images=False)) == 2
    assert demo.synthetic_source(tmp_path, 2, 0) == root  # complete now: reused, not written again
    assert "writing" not in capsys.readouterr().err


def test_demo_never_deletes_a_foreign_folder_in_its_way(tmp_path):
    root = tmp_path / "synthetic_2_seed0"
    (root / "01").mkdir(parents=True)
    (root / "01" / "notes.txt").write_text("keep me")
    with pytest.raises(ValueError, match="refusing to overwrite .*synthetic_2_seed0"):
        demo.synthetic_source(tmp_path, 2, 0)
    assert (root / "01" / "notes.txt").read_text() == "keep me"


def test_demo_refuses_a_missing_cornell_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        demo.run(demo_config(tmp_path, cornell=str(tmp_path / "nowhere")))


def test_the_scene_table_puts_the_model_s_angle_fit_under_its_accuracy(capsys):
    fields = dict(data="synthetic-40-seed1", protocol="honest", split="fresh", step=8, workdir="run")
    model = {"accuracy": 50.0, "instructions": 4, "angle_at_centre": {"within_30_deg": 75.0},
             "by_scene": {"single": {"accuracy": 50.0, "instructions": 4, "angle_at_centre": {"within_30_deg": 75.0}}}}
    centre = {"accuracy": 0.0, "instructions": 4, "by_scene": {"single": {"accuracy": 0.0, "instructions": 4}}}
    rows = demo.scored_rows(fields, [("kosmos_e", model), ("image_centre", centre)])
    assert [r.get("angle_at_centre") for r in rows] == [75.0, 75.0, None, None]
    demo.print_scenes(rows, "fresh")
    lines = capsys.readouterr().out.splitlines()
    assert lines[-2].split() == ["(angle", "fit)", "75.00", "(4)", "75.00", "(4)"]
    demo.print_scenes(rows[2:], "fresh")  # a table with no decoded model has no angle line
    assert "angle fit" not in capsys.readouterr().out


def test_the_scene_table_puts_the_mosaic_zoom_beside_the_one_pass_answers(capsys):
    fields = dict(data="synthetic-40-seed1", protocol="honest", split="fresh", step=8, workdir="run")
    single, multi = {"accuracy": 50.0, "instructions": 2}, {"accuracy": 25.0, "instructions": 8}
    model = {"accuracy": 30.0, "instructions": 10, "by_scene": {"multi": multi, "single": single},
             "mosaic_zoom": {"accuracy": 60.0, "instructions": 10,
                             "by_scene": {"multi": {"accuracy": 62.5, "instructions": 8}, "single": single}}}
    centre = {"accuracy": 0.0, "instructions": 10, "by_scene": {"multi": {"accuracy": 0.0, "instructions": 8},
                                                                "single": {"accuracy": 0.0, "instructions": 2}}}
    rows = demo.scored_rows(fields, [("kosmos_e", model), ("image_centre", centre)])
    zoomed = {r["scene"]: r["mean"] for r in rows if r["predictor"] == demo.ZOOMED}
    assert zoomed == {"all": 60.0, "multi": 62.5}  # single photos are not zoomed: no row of their own
    demo.print_scenes(rows, "fresh")
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines[3:6]] == ["kosmos_e", demo.ZOOMED, "image_centre"]
    assert lines[4].split() == [demo.ZOOMED, "60.00", "(10)", "62.50", "(8)", "-"]
    assert lines[-1].startswith(f"{demo.ZOOMED}: kosmos_e with each mosaic instruction answered again")


def test_a_demo_run_of_another_schedule_is_refused_before_it_trains(tmp_path):
    """A demo_out of make demo's earlier 400 steps would be lengthened under another schedule: refused, saying how."""
    config = spec.load_config("configs/kosmos_e.py:tiny")
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "run.json").write_text(json.dumps({"config": json.loads(config.to_json_best_effort())}))
    demo.check_schedule(tmp_path / "run", config, tmp_path)  # the same schedule: resumed or reused
    demo.check_schedule(tmp_path / "elsewhere", config, tmp_path)  # no run yet
    steps = config.train.steps
    for field, value, named in (("train.steps", 2 * steps, rf"the rate decaying until step {steps} \(this config: {2 * steps}\)"),
                                ("optimizer.peak_lr", 1e-4, r"optimizer.peak_lr=.* \(this config: 0.0001\)")):
        changed = spec.load_config("configs/kosmos_e.py:tiny")
        group, name = field.split(".")
        changed[group][name] = value
        with pytest.raises(SystemExit, match=rf"run holds a run made with {named}, another "
                                             rf"make demo's schedule \(for the demo: remove {tmp_path}"):
            demo.check_schedule(tmp_path / "run", changed, tmp_path)
    lengthened = spec.load_config("configs/kosmos_e.py:tiny")  # a decay that ends at a fixed step: the same schedule
    fixed = spec.load_config("configs/kosmos_e.py:tiny")
    fixed.optimizer.decay_steps = lengthened.optimizer.decay_steps = steps
    lengthened.train.steps = 2 * steps
    assert trainer.schedule_change({"config": fixed.to_dict()}, {"config": lengthened.to_dict()}) is None


@pytest.mark.slow  # a tiny training run, its build and decoding: about 90 s on 2 loaded cores
def test_demo_trains_and_scores_its_model_beside_the_baselines_on_the_same_instructions(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(demo, "DEFAULT_CORNELL", tmp_path / "absent")
    demo.run(demo_config(tmp_path, steps=6))
    rows = json.loads((tmp_path / "results.json").read_text())
    trained = [r for r in rows if r["split"].endswith("-fold0")]
    # the tiny config's held-out fold is NON alone: no mosaics, so no zoom row (the fresh scenes below have both)
    assert {r["scene"] for r in trained} == {"all", "single"}
    assert {r["predictor"] for r in trained} == {"kosmos_e", "image_centre", "gt_mean_oracle"}
    for scene in {r["scene"] for r in trained}:
        counts = {r["instructions"] for r in trained if r["scene"] == scene}
        assert len(counts) == 1, f"scene {scene}: the predictors were scored on different instructions"
    model = {r["scene"]: r for r in trained if r["predictor"] == "kosmos_e"}
    assert "all" in model and model["all"]["step"] == 6
    results = json.loads((tmp_path / "run" / "eval" / "6" / "results.json").read_text())
    assert results["accuracy"] == pytest.approx(model["all"]["mean"], abs=0.01)
    # the test answers are decoded once, by the evaluate command's code: the trainer's last line has no grasps
    last_test = [r for r in read_metrics(tmp_path / "run") if r.get("split") == "test"][-1]
    assert last_test["step"] == 6 and "grasp_accuracy" not in last_test and "loss" in last_test
    out = capsys.readouterr().out
    assert "goal (kosmos_e >= image_centre + 50" in out
    # the same model on another seed's scenes: NON on each photo, the multi-object kinds on mosaics
    fresh = [r for r in rows if r["split"] == demo.FRESH_SPLIT]
    assert {r["scene"] for r in fresh} == {"all", "single", "multi"}
    assert {r["predictor"] for r in fresh} == {"kosmos_e", demo.ZOOMED, "image_centre", "gt_mean_oracle"}
    for scene in ("single", "multi"):
        assert len({r["instructions"] for r in fresh if r["scene"] == scene}) == 1
    assert all(r["data"] == "synthetic-20-seed1" for r in fresh)
    written = json.loads((tmp_path / "run" / "eval" / "6" / "cornell-synthetic_20_seed1" / "results.json").read_text())
    assert written["kinds"] == ["non", "multi"] and set(written["by_scene"]) == {"single", "multi"}
    model = {r["scene"]: r["mean"] for r in fresh if r["predictor"] == "kosmos_e"}
    assert model["multi"] == pytest.approx(written["by_scene"]["multi"]["accuracy"], abs=0.01)
    zoomed = {r["scene"]: r["mean"] for r in fresh if r["predictor"] == demo.ZOOMED}
    assert zoomed == pytest.approx({scene: written["mosaic_zoom"]["by_scene"]["multi"]["accuracy"] if scene == "multi"
                                    else written["mosaic_zoom"]["accuracy"] for scene in ("all", "multi")}, abs=0.01)
    assert "scene multi" in out and "never trained on" in out
    # the model's rows, and only its, carry its angle fit, as the evaluate command wrote it
    assert {r["predictor"] for r in rows if "angle_at_centre" in r} == {"kosmos_e"}
    fit = {r["scene"]: r["angle_at_centre"] for r in fresh if r["predictor"] == "kosmos_e"}
    assert fit["multi"] == written["by_scene"]["multi"]["angle_at_centre"]["within_30_deg"]
    assert "(angle fit)" in out
    demo.run(demo_config(tmp_path, steps=6))  # a finished run is reused, not trained again
    assert json.loads((tmp_path / "results.json").read_text())[: len(trained)] == trained
    with pytest.raises(SystemExit, match=r"holds a run made with the rate decaying until step 6 \(this config: 12\)"):
        demo.run(demo_config(tmp_path, steps=12))
    # another demo that starts from this one's run: its config names the start, its tokenizer is the start's
    second = tmp_path / "second"
    demo.run(demo_config(second, steps=6, fresh_photos=0, init_from=str(tmp_path / "run")))
    started = json.loads((second / "run" / "run.json").read_text())["config"]
    assert started["init_from"] == str(tmp_path / "run")
    assert (second / "run" / "tokenizer.model").read_bytes() == (tmp_path / "run" / "tokenizer.model").read_bytes()


def test_demo_refuses_a_missing_start_before_training(tmp_path):
    with pytest.raises(FileNotFoundError, match="config.init_from=.*nowhere.* does not exist"):
        demo.trained_rows(demo_config(tmp_path, init_from=str(tmp_path / "nowhere")), tmp_path)
    assert not list(tmp_path.iterdir())


def test_demo_refuses_fresh_photos_of_the_training_seed(tmp_path):
    config = demo_config(tmp_path, fresh_seed=0)
    with pytest.raises(ValueError, match="fresh_seed=0 is the training scenes' seed"):
        demo.fresh_rows(config, spec.load_config(config.train_config), tmp_path, tmp_path / "run", 1)
    assert not list(tmp_path.iterdir())  # refused before writing anything


# configs/kosmos_e.py:tiny's own seed is 0 and its own peak rate 3e-3
@pytest.mark.parametrize("override,expected", [(dict(train_seed=-1), (0, 3e-3)), (dict(train_seed=3), (3, 3e-3)),
                                               (dict(peak_lr=0.0), (0, 3e-3)), (dict(peak_lr=1.5e-4), (0, 1.5e-4))])
def test_demo_trains_with_its_seed_and_rate_or_the_training_config_s_own(tmp_path, monkeypatch, override, expected):
    trained = []

    def stopped_train(train_config, workdir):
        trained.append((train_config.train.seed, train_config.optimizer.peak_lr))
        return {"finished": False, "step": 0}

    monkeypatch.setattr(demo.runner, "default_train", stopped_train)
    with pytest.raises(SystemExit, match="training stopped at step 0"):
        demo.trained_rows(demo_config(tmp_path, **override), tmp_path)
    assert trained == [expected]


def test_demo_refuses_a_negative_peak_lr_before_training(tmp_path):
    with pytest.raises(ValueError, match=r"optimizer.peak_lr=-0.001: a learning rate must be a positive number"):
        demo.trained_rows(demo_config(tmp_path, peak_lr=-1e-3), tmp_path)
    assert not list(tmp_path.iterdir())
