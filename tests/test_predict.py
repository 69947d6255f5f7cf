"""GraspPredictor on a tiny run the real trainer wrote (two steps of `configs/kosmos_e.py:tiny`):
a Grasp from a path or an array, in the photo's pixels; batches padded to fixed sizes (compiled
once each); angle and NON instructions; the run exported as a pretrained folder (workdir.export)
predicts the same; the photo <-> view mapping under a known transform (model-free); every bad
input's one clear error; the overlay's red rectangle; `python -m kosmos_jax.predict --json` and
`evaluate --overlays`."""

import json
import math
import shutil

import cv2
import jax
import numpy as np
import pytest

from kosmos_jax import geometry
from kosmos_jax.sources.photo import Photo
from kosmos_jax.dataset.views import evaluation_views
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.predict import (GraspPredictor, ImageError, ImageWarning, InstructionError, PredictError,
                                RunFolderError)
from kosmos_jax.predict.framing import frame
from kosmos_jax.predict.images import load_image
from kosmos_jax.scoring.drawing import overlay, write_png
from kosmos_jax.workdir.export import export_pretrained
from kosmos_jax.workdir.run import open_run
from user_commands import run_module, train_tiny

# one worker: the tests share one trained run, which each worker would otherwise train again
pytestmark = pytest.mark.xdist_group("predict")


def one_device():
    return make_mesh(1, 1, 1, devices=jax.devices()[:1])


@pytest.fixture(scope="session")
def workdir(tmp_path_factory):
    """A tiny run of two steps, written by the trainer."""
    return train_tiny(tmp_path_factory.mktemp("run"), tmp_path_factory.mktemp("datasets"))


@pytest.fixture(scope="module")
def predictor(workdir):
    return GraspPredictor.from_workdir(workdir, mesh=one_device())


@pytest.fixture(scope="module")
def photo(tmp_path_factory):
    """A 900 x 600 photo file (not the model's 640 x 480) and its pixels."""
    pixels = np.random.default_rng(0).integers(0, 256, (600, 900, 3), dtype=np.uint8)
    path = tmp_path_factory.mktemp("photos") / "photo.png"
    cv2.imwrite(str(path), cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR))
    return path, pixels


def test_predict_gives_a_grasp_in_the_photos_pixels(predictor, photo):
    path, pixels = photo
    grasp = predictor.predict(path, "Grasp the red mug.")
    assert set(grasp.parts) == {"location", "angle"} and grasp.answer == " ".join(grasp.parts.values())
    assert -math.pi / 2 <= grasp.theta < math.pi / 2 and np.isfinite(grasp.rectangle()).all()
    assert (grasp.width, grasp.jaw) == pytest.approx(np.array(predictor.grasp_size) * 600 / 480)  # photo scale
    # the answer's centre (view pixels) is where the grasp sits once mapped back to the view
    _, framing = predictor.view(pixels)
    x, y = (int(v) for v in grasp.parts["location"].split("x_")[1].split(",y_"))
    assert framing.to_view(grasp.rectangle())[:2] == pytest.approx([x, y], abs=1e-6)
    assert predictor.predict(pixels, "Grasp the red mug.") == grasp  # an array or its file


def test_the_grasp_size_is_the_protocols_borrowed_size_of_the_training_views(predictor, workdir):
    run = open_run(workdir)
    answers = [np.asarray(r["answers"]).reshape(-1, 5) for r in run.split("train").examples]
    widths, jaws = zip(*((a[:, 2].mean(), a[:, 3].mean()) for a in answers))  # honest: each view's mean
    assert predictor.protocol == "honest"
    assert predictor.grasp_size == pytest.approx((np.mean(widths), np.mean(jaws)))


@pytest.mark.slow  # 21 s (make test's --durations, 2026-12-02, 2 cores)
def test_batches_are_padded_to_fixed_sizes_and_compiled_once_each(workdir, photo):
    predictor = GraspPredictor.from_workdir(workdir, mesh=one_device(), batch_sizes=(1, 4, 16))
    compiled = predictor._decoder._jitted._cache_size
    _, pixels = photo
    images = [pixels, pixels[::-1], pixels[:, ::-1]]
    three = predictor.predict_batch(images, "Grasp the red mug.")
    assert len(three) == 3 and compiled() == 2  # location and angle, at batch 4
    five = predictor.predict_batch(images + [pixels, pixels[::-1]], ["Grasp the red mug.", "Grasp the mug.",
                                                                     "Grasp the blue ball.", None, "Grasp it."])
    assert len(five) == 5 and compiled() == 4  # the same two at batch 16
    again = predictor.predict_batch(images[::-1], ["Grasp the pen.", "Grasp the cup.", "Grasp the bottle."])
    assert compiled() == 4 and len(again) == 3
    same = predictor.predict_batch([pixels] * 3, "Grasp the red mug.")
    assert same[0] == same[1] == same[2]


def test_an_angle_instruction_asks_the_centre_and_keeps_its_angle(predictor, photo):
    grasp = predictor.predict(photo[1], "Grasp the object with a rotation angle of a_156 radians.")
    assert list(grasp.parts) == ["location"]
    assert grasp.theta == pytest.approx(float(geometry.decode_angle(np.int64(156))))


def test_no_instruction_is_non_and_an_empty_one_is_an_error(predictor, photo):
    assert np.isfinite(predictor.predict(photo[1]).rectangle()).all()
    for empty in ("", "   \n\t"):
        with pytest.raises(InstructionError, match="empty"):
            predictor.predict(photo[1], empty)
    with pytest.raises(InstructionError, match="text"):
        predictor.predict(photo[1], 42)


def test_an_instruction_longer_than_the_context_is_refused(predictor, photo):
    with pytest.raises(InstructionError, match=f"too long.*context of {predictor.context}"):
        predictor.predict(photo[1], "Grasp the " + "very " * predictor.context + "red mug.")
    with pytest.raises(InstructionError, match="2 images but 1 instructions"):
        predictor.predict_batch([photo[1], photo[1]], ["Grasp it."])


def test_bad_image_files_are_named(predictor, tmp_path):
    text = tmp_path / "notes.png"
    text.write_text("not a picture")
    with pytest.raises(ImageError, match="notes.png: not an image"):
        predictor.predict(text, "Grasp the mug.")
    with pytest.raises(PredictError, match="no such image file"):  # every bad input is a PredictError
        predictor.predict(tmp_path / "missing.png", "Grasp the mug.")
    with pytest.raises(ImageError, match="float64"):
        predictor.predict(np.zeros((10, 10, 3)), "Grasp the mug.")
    with pytest.raises(ImageError, match="shape"):
        predictor.predict(np.zeros((10, 10, 2), np.uint8), "Grasp the mug.")


def test_grey_rgba_and_16_bit_pngs_are_converted_with_a_warning(predictor, tmp_path):
    rng = np.random.default_rng(1)
    grey = rng.integers(0, 256, (60, 80), dtype=np.uint8)
    rgba = rng.integers(0, 256, (60, 80, 4), dtype=np.uint8)
    deep = rng.integers(0, 65536, (60, 80, 3), dtype=np.uint16)
    for name, pixels in (("grey", grey), ("rgba", cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA)),
                         ("deep", cv2.cvtColor(deep, cv2.COLOR_RGB2BGR))):
        cv2.imwrite(str(tmp_path / f"{name}.png"), pixels)
    with pytest.warns(ImageWarning, match="grey image converted"):
        assert (load_image(tmp_path / "grey.png") == grey[..., None]).all()
    with pytest.warns(ImageWarning, match="alpha channel dropped"):
        assert (load_image(tmp_path / "rgba.png") == rgba[..., :3]).all()
    with pytest.warns(ImageWarning, match="16-bit image scaled"):
        assert (load_image(tmp_path / "deep.png") == np.round(deep / 257)).all()
    with pytest.warns(ImageWarning, match="grey"):
        assert np.isfinite(predictor.predict(tmp_path / "grey.png", "Grasp the mug.").rectangle()).all()


def test_a_workdir_without_checkpoint_or_tokenizer_is_named(workdir, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    for name in ("run.json", "tokenizer.model"):
        shutil.copy(workdir / name, empty / name)
    with pytest.raises(RunFolderError, match="no checkpoint"):
        GraspPredictor.from_workdir(empty)
    no_tokenizer = tmp_path / "no_tokenizer"
    shutil.copytree(workdir, no_tokenizer, ignore=shutil.ignore_patterns("tokenizer.model", "eval"))
    with pytest.raises(RunFolderError, match="tokenizer.model is missing"):
        GraspPredictor.from_workdir(no_tokenizer)
    with pytest.raises(RunFolderError, match="not a training run's workdir"):
        GraspPredictor.from_workdir(tmp_path / "nowhere")
    with pytest.raises(RunFolderError, match="no checkpoint of step 7"):
        GraspPredictor.from_workdir(workdir, step=7, mesh=one_device())


def test_a_pretrained_folder_of_the_same_weights_predicts_the_same(predictor, workdir, tmp_path, photo):
    run = open_run(workdir)
    assert export_pretrained(workdir, tmp_path / "exported") == 2  # the run layer's export: params alone, newest step
    pretrained = GraspPredictor.from_pretrained(tmp_path / "exported", tmp_path / "exported" / "tokenizer.model",
                                                scheme="native", format_config=run.format_config,
                                                grasp_size=predictor.grasp_size, mesh=one_device())
    assert pretrained.predict(photo[1], "Grasp the red mug.") == predictor.predict(photo[1], "Grasp the red mug.")
    alone = GraspPredictor.from_pretrained(tmp_path / "exported", mesh=one_device())  # its kosmos_e.json, tokenizer
    assert (alone.format_config, alone.protocol) == (run.format_config, "honest")
    assert alone.grasp_size == predictor.grasp_size
    assert alone.predict(photo[1], "Grasp the red mug.") == predictor.predict(photo[1], "Grasp the red mug.")
    with pytest.raises(FileExistsError, match="not an empty folder"):  # an older export's files would mix in
        export_pretrained(workdir, tmp_path / "exported")
    (tmp_path / "exported" / "kosmos_e.json").unlink()
    with pytest.raises(RunFolderError, match="holds no kosmos_e.json"):
        GraspPredictor.from_pretrained(tmp_path / "exported")
    with pytest.raises(RunFolderError, match="scheme='native'"):  # the project's tokenizer read as KOSMOS-2's
        GraspPredictor.from_pretrained(tmp_path / "exported", workdir / "tokenizer.model", scheme="fairseq")
    (tmp_path / "exported" / "model.safetensors").unlink()
    with pytest.raises(RunFolderError, match="neither model.safetensors"):
        GraspPredictor.from_pretrained(tmp_path / "exported", workdir / "tokenizer.model", scheme="native")
    with pytest.raises(RunFolderError, match="tokenizer file is missing"):
        GraspPredictor.from_pretrained(tmp_path / "exported", tmp_path / "sentencepiece.bpe.model")
    with pytest.raises(RunFolderError, match="no config.json"):
        GraspPredictor.from_pretrained(tmp_path, workdir / "tokenizer.model")


# -- the photo <-> view mapping, model-free --------------------------------------------------------

def test_a_grasp_drawn_on_an_upscaled_padded_image_comes_back_where_it_was_drawn():
    drawn = np.array([90.0, 130.0, 40.0, 16.0, 0.6])  # on a 224 picture
    picture = np.full((224, 224, 3), 90, np.uint8)
    corners = np.asarray(geometry.grasps_to_corners(drawn[None]))[0]
    cv2.fillPoly(picture, [np.round((corners - 0.5) * 16).astype(np.int32)], (250, 20, 20), cv2.LINE_8, shift=4)
    zoom, left, top = 3, 80, 50  # known transform: upscale, then pad
    photo = cv2.copyMakeBorder(cv2.resize(picture, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST),
                               top, 20, left, 10, cv2.BORDER_CONSTANT, value=(90, 90, 90))
    in_photo = np.array([drawn[0] * zoom + left, drawn[1] * zoom + top, drawn[2] * zoom, drawn[3] * zoom, drawn[4]])
    view, framing = frame(photo)
    # where the rectangle's pixels landed in the view, mapped back to the photo
    rows, cols = np.nonzero((view[..., 0] > 170) & (view[..., 1] < 100))
    seen = np.array([cols.mean() + 0.5, rows.mean() + 0.5, 10.0, 10.0, 0.0])
    assert framing.to_photo(seen)[:2] == pytest.approx(in_photo[:2], abs=1.5)
    assert framing.to_view(in_photo)[:2] == pytest.approx(seen[:2], abs=1.0)
    back = framing.to_photo(framing.to_view(in_photo))
    assert back == pytest.approx(in_photo, abs=1e-6)


def test_a_640_by_480_photo_gets_exactly_its_honest_test_view():
    pixels = np.random.default_rng(2).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    truths = np.array([[300.0, 250.0, 40.0, 20.0, 0.3], [350.0, 200.0, 30.0, 10.0, -1.0]])
    test_view = evaluation_views([Photo("p", pixels, None, truths)], "honest")
    view, framing = frame(pixels)
    assert (view == test_view.images[0]).all()
    assert framing.to_view(truths) == pytest.approx(test_view.grasps[0], abs=1e-3)


# -- overlays and the command ----------------------------------------------------------------------

def test_the_overlay_has_red_pixels_on_the_predicted_rectangle(predictor, tmp_path):
    photo = np.full((480, 640, 3), 128, np.uint8)
    grasp = predictor.predict(photo, "Grasp the red mug.")
    path = write_png(tmp_path / "overlay.png", overlay(photo, grasp.rectangle(), (), "Grasp the red mug."))
    drawn = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    assert drawn.shape[1] == 640 and drawn.shape[0] > 480  # the caption band beneath
    corners = np.asarray(geometry.grasps_to_corners(grasp.rectangle()[None]))[0]
    for a, b in zip(corners, np.roll(corners, -1, axis=0)):
        x, y = ((a + b) / 2).astype(int)  # the middle of each edge
        red = drawn[y - 1:y + 2, x - 1:x + 2].reshape(-1, 3)
        assert ((red[:, 0] > 200) & (red[:, 1] < 80) & (red[:, 2] < 80)).any(), (x, y)
    assert (drawn[5, 5] == 128).all()  # away from the rectangle the photo is untouched


def test_the_predict_command_prints_json_and_writes_the_overlay(workdir, photo, tmp_path):
    out = tmp_path / "overlay.png"
    done = run_module("kosmos_jax.predict", f"--workdir={workdir}", f"--image={photo[0]}",
                      "--instruction=Grasp the red mug.", f"--out={out}", "--json")
    assert done.returncode == 0, done.stderr[-3000:]
    record = json.loads(done.stdout)
    assert set(record) >= {"x", "y", "theta", "width", "jaw", "answer", "parts"} and out.is_file()
    assert cv2.imread(str(out)).shape[1] == 900


def test_the_predict_command_prints_one_error_line(workdir, tmp_path):
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), np.zeros((40, 40), np.uint8))
    (tmp_path / "notes.png").write_text("not a picture")
    done = run_module("kosmos_jax.predict", f"--workdir={workdir}", f"--image={tmp_path / 'notes.png'}")
    assert done.returncode == 1 and "error: " in done.stderr and "Traceback" not in done.stderr
    done = run_module("kosmos_jax.predict", f"--workdir={workdir}", f"--image={grey}", "--instruction= ")
    assert done.returncode == 1 and "warning: " in done.stderr and "error: the instruction is empty" in done.stderr


@pytest.mark.slow  # 42 s (make test's --durations, 2026-11-28, 2 cores)
def test_evaluate_draws_a_grid_per_instruction_kind(workdir):
    done = run_module("kosmos_jax.evaluate", f"--workdir={workdir}", "--overlays=2")
    assert done.returncode == 0, done.stderr[-3000:]
    grid = cv2.cvtColor(cv2.imread(str(workdir / "eval" / "2" / "overlays" / "non.png")), cv2.COLOR_BGR2RGB)
    red = (grid[..., 0] > 200) & (grid[..., 1] < 80) & (grid[..., 2] < 80)
    blue = (grid[..., 2] > 200) & (grid[..., 0] < 80) & (grid[..., 1] < 80)
    assert red.sum() > 50 and blue.sum() > 50
    assert grid.shape[1] > 2 * 448  # two 448 tiles side by side
