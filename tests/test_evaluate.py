"""Evaluation from decoded answers, end to end on `configs/kosmos_e.py:tiny`: a run the real trainer
wrote (two steps), its checkpoint decoded, parsed and scored by `python -m kosmos_jax.evaluate`; the
unconstrained parse failures counted as the parser counts them; constrained answers of a random
model always parse; the centre and angle answers of one instruction combined into one grasp; the
targets scored as answers (the target ceiling) and the distinct answers; the errors a user meets;
a Cornell-format folder of synthetic photos, scored from the run and from its exported folder alike."""

import json
import shutil

import jax
import numpy as np
import pytest

from kosmos_jax import geometry
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.evaluate.__main__ import main
from kosmos_jax.evaluate.run_scores import evaluate
from kosmos_jax.grasp_text import ParsedGrasp, format_angle
from kosmos_jax.models.kosmos2 import abstract_model, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_embeddings import angle_token_ids
from kosmos_jax.scoring.instructions import combine, group_instructions
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.scoring.prompts import prompt, written_prompt
from kosmos_jax.scoring.zoom import from_zoomed, quadrant_corners, zoomed_view
from kosmos_jax.text.formatter import prompt_cues
from kosmos_jax.scoring.tally import angle_errors, angle_fit, distinct, markdown, successes
from kosmos_jax.text.formatter import parse_target
from kosmos_jax.train.metrics_log import read_metrics
from kosmos_jax.workdir.export import export_pretrained
from kosmos_jax.workdir.run import open_run
from user_commands import run_module, train_tiny

# one worker: the tests share one trained run, which each worker would otherwise train again
pytestmark = pytest.mark.xdist_group("evaluate")


@pytest.fixture(scope="session")
def workdir(tmp_path_factory):
    """A tiny run of two steps, written by the trainer."""
    return train_tiny(tmp_path_factory.mktemp("run"), tmp_path_factory.mktemp("datasets"))


@pytest.fixture(scope="session")
def values_workdir(tmp_path_factory):
    """A tiny run of two steps whose vocabulary has value tokens (numbers=values), as the demo's has."""
    return train_tiny(tmp_path_factory.mktemp("values_run"), tmp_path_factory.mktemp("values_datasets"),
                      "--config.data.build.numbers=values")


@pytest.fixture(scope="session")
def mosaic_workdir(tmp_path_factory):
    """A tiny run of two steps whose dataset holds mosaics (NON and the multi-object kinds), as make demo's does."""
    return train_tiny(tmp_path_factory.mktemp("mosaic_run"), tmp_path_factory.mktemp("mosaic_datasets"),
                      "--config.data.build.kinds=non,multi", "--config.data.build.max_length=160")


@pytest.fixture(scope="session")
def evaluated(workdir):
    """`python -m kosmos_jax.evaluate --workdir=W --json`: (stdout, results folder)."""
    done = run_module("kosmos_jax.evaluate", f"--workdir={workdir}", "--json")
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout, workdir / "eval" / "2"


def test_the_trainer_logs_the_grasp_accuracy_of_its_decoded_answers_at_the_end(workdir):
    last = [r for r in read_metrics(workdir) if r.get("split") == "test"][-1]
    assert last["step"] == 2 and 0 <= last["grasp_accuracy"] <= 100


def test_a_checkpoint_is_decoded_parsed_and_scored_end_to_end(evaluated):
    stdout, folder = evaluated
    assert len(stdout.splitlines()) == 1
    results = json.loads(stdout)
    assert results == json.loads((folder / "results.json").read_text())
    assert 0 <= results["accuracy"] <= 100 and results["accuracy"] == results["constrained"]["accuracy"]
    assert results["step"] == 2 and results["split"] == "test" and results["protocol"] == "honest"
    assert results["individual"] and results["examples"] == 2 * results["instructions"] > 0  # location + angle
    for groups in (results["by_kind"], results["by_scene"]):
        assert sum(g["examples"] for g in groups.values()) == results["examples"]
        assert sum(g["instructions"] for g in groups.values()) == results["instructions"]
    assert set(results["by_scene"]) == {"single"}  # kind NON only: no mosaics
    # the targets, read back from their tokens and scored as answers, all hit: nothing lost between
    # the targets, their parse, the combining of location and angle and the metric
    assert results["target_ceiling"] == 100.0
    assert all(g["target_ceiling"] == 100.0 for groups in (results["by_kind"], results["by_scene"])
               for g in groups.values())
    for who in ("answers", "targets"):
        spread = results["distinct"][who]
        assert set(spread) == {"texts", "centres", "angles", "grasps"}
        assert 1 <= spread["centres"] <= results["instructions"] and 1 <= spread["angles"] <= results["instructions"]
        assert spread["texts"] <= results["examples"] and spread["grasps"] <= results["instructions"]
    fit = results["angle_at_centre"]
    assert fit["instructions"] == results["instructions"] and 0 <= fit["within_30_deg"] <= 100
    assert results["by_scene"]["single"]["angle_at_centre"] == fit
    table = (folder / "results.md").read_text()
    assert "| all |" in table and "target ceiling |" in table and "| 100.00 |" in table
    assert "Distinct (constrained) answers:" in table and "Angle at the answered centre:" in table
    rows = [json.loads(line) for line in (folder / "answers.jsonl").read_text().splitlines()]
    assert all(row["target_correct"] for row in rows)


def test_the_unconstrained_failures_are_the_answers_the_parser_refuses(evaluated, workdir):
    stdout, folder = evaluated
    results = json.loads(stdout)
    rows = [json.loads(line) for line in (folder / "answers.jsonl").read_text().splitlines()]
    assert len(rows) == results["examples"]
    config = open_run(workdir).format_config
    refused = sum(not parse_target(r["unconstrained_answer"], r["part"], config).ok for r in rows)
    assert refused == results["unconstrained"]["parse_failures"] == sum(not r["unconstrained_parses"] for r in rows)
    assert results["unconstrained"]["parse_failure_rate"] == pytest.approx(100 * refused / len(rows), abs=1e-3)
    assert all(parse_target(r["answer"], r["part"], config).ok for r in rows)
    assert results["constrained"]["parse_failures"] == 0


def redrawn(shapes, seed):
    """Parameters of these shapes drawn from N(0, 1): logits far larger than trained ones, favouring any token."""
    rng = np.random.default_rng(seed)
    return jax.tree.map(lambda x: rng.standard_normal(x.shape).astype(x.dtype), shapes)


def test_part_oracles_score_the_answers_as_the_evaluation_does_and_only_raise_them(evaluated, workdir):
    stdout, folder = evaluated
    done = run_module("kosmos_jax.diagnostics.part_oracles", f"--workdir={workdir}", "--json")
    assert done.returncode == 0, done.stderr[-3000:]
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    results = json.loads(stdout.strip().splitlines()[-1])
    assert figures["accuracy"]["model"] == pytest.approx(results["accuracy"])
    assert figures["instructions"] == results["instructions"] and figures["step"] == 2
    assert set(figures["by_kind"]) == set(results["by_kind"])


def test_an_answer_the_grammar_forbids_is_impossible_even_for_a_random_model(workdir):
    run = open_run(workdir)
    one_device = make_mesh(1, 1, 1, devices=jax.devices()[:1])
    evaluation = GraspEvaluation(run.model_config, one_device, run.split("test"), run.tokenizer, run.format_config,
                                 run.protocol, batch_size=4)
    shapes = split_model(abstract_model(run.model_config))[1]
    for seed in (1, 2, 3):
        answers = evaluation.answers(redrawn(shapes, seed), constrained=True)
        assert len(answers) == evaluation.examples
        for index, (text, parsed) in answers.items():
            assert parsed.ok and parse_target(text, evaluation.question_of[index].part, run.format_config).ok, text
        assert np.isfinite(evaluation.grasps(answers)).all()


def record(part, kind="non", scene="non", instruction="", photo="pcd0100", target_text=""):
    return {"photo_ids": [photo.encode()], "kind": kind.encode(), "scene": scene.encode(), "part": part.encode(),
            "instruction": instruction.encode(), "target": 0, "target_text": target_text.encode(),
            "answers": np.array([[100, 50, 40, 20, 0.3]], np.float32)}


def parsed(x=np.nan, y=np.nan, theta=np.nan, ok=True):
    return ParsedGrasp(ok, np.array([x, y, np.nan, np.nan, theta]), "" if ok else "no answer")


def test_the_centre_and_angle_answers_of_one_instruction_make_one_grasp():
    records = [record("location"), record("angle"),
               record("location", photo="pcd0101"), record("angle", photo="pcd0101")]
    first, second = group_instructions(records)
    assert dict(first.examples) == {"location": 0, "angle": 1} and dict(second.examples) == {"location": 2, "angle": 3}
    grasp = combine(first, {"location": parsed(100, 50), "angle": parsed(theta=0.3)})
    np.testing.assert_allclose(grasp, [100, 50, 0.3])
    assert np.isnan(combine(first, {"location": parsed(100, 50), "angle": parsed(ok=False)})).all()
    assert np.isnan(combine(first, {"location": parsed(ok=False), "angle": parsed(theta=0.3)})).all()
    found = successes([first, first], np.array([grasp, [100, 50, 0.3 + np.pi / 2]]), "honest")
    assert found.tolist() == [True, False]  # the angle of the angle answer decides


def test_grouping_follows_the_build_order_and_each_kind_s_answer():
    # target_grasp="each": the same sample's pairs repeat; an angle instruction has a location only
    sentence = "Grasp the object with a rotation angle of a_160 radians."
    records = [record("location"), record("angle"), record("location"), record("angle"),
               record("location", "angle", "single", sentence),
               record("grasp", "colour", "multi", "Grasp the red object.")]
    groups = group_instructions(records)
    assert [dict(g.examples) for g in groups] == [{"location": 0, "angle": 1}, {"location": 2, "angle": 3},
                                                 {"location": 4}, {"grasp": 5}]
    assert [(g.kind, g.scene) for g in groups] == [("non", "single"), ("non", "single"), ("angle", "single"),
                                                 ("multi-colour", "multi")]
    np.testing.assert_allclose(combine(groups[2], {"location": parsed(10, 20)}), [10, 20, geometry.decode_angle(160)])
    np.testing.assert_allclose(combine(groups[3], {"grasp": parsed(10, 20, theta=-0.5)}), [10, 20, -0.5])
    with pytest.raises(ValueError, match="location"):
        group_instructions([record("angle")])


def test_distinct_counts_each_part_of_hand_made_answers():
    records = [record(part, photo=f"pcd010{i}") for i in range(4) for part in ("location", "angle")]
    instructions = group_instructions(records)
    assert len(instructions) == 4
    answers = {0: ("x_10 y_20", parsed(10, 20)), 1: ("a_3", parsed(theta=0.3)),
               2: ("x_10 y_20", parsed(10, 20)), 3: ("a_3", parsed(theta=0.3)),
               4: ("x_50 y_20", parsed(50, 20)), 5: ("a_3", parsed(theta=0.3)),
               6: ("x_9", parsed(ok=False)), 7: ("a_3", parsed(theta=0.3))}
    # four answers with the same angle code: one angle; the unparsed location is a text but no centre
    assert distinct(instructions, answers) == {"texts": 4, "centres": 2, "angles": 1, "grasps": 2}
    # an angle instruction states its angle: its location answer is a centre, no angle is answered
    sentence = "Grasp the object with a rotation angle of a_160 radians."
    stated = group_instructions([record("location", "angle", "single", sentence),
                                 record("location", "angle", "single", sentence, photo="pcd0101")])
    assert distinct(stated, {0: ("x_1 y_2", parsed(1, 2)), 1: ("x_1 y_3", parsed(1, 3))}) == \
        {"texts": 2, "centres": 2, "angles": 0, "grasps": 2}


def test_the_angle_is_judged_against_the_ground_truth_nearest_the_answered_centre():
    two = record("location")
    # two ground truths: at (100, 50) turned 0, at (20, 50) turned 80 degrees
    two["answers"] = np.array([[100, 50, 40, 20, 0.0], [20, 50, 40, 20, np.radians(80)]], np.float32)
    instructions = group_instructions([two, record("angle")]) * 5
    grasps = np.array([[95, 50, np.radians(29)],     # near the first, 29 degrees off: fits
                       [95, 50, np.radians(80)],     # near the first, the second's angle: no fit
                       [30, 60, np.radians(60)],     # near the second, 20 degrees off: fits
                       [30, 60, np.radians(-100)],   # -100 is 80 modulo 180: fits
                       [np.nan, np.nan, np.nan]])    # an unparsed answer: a miss, out of the median
    errors = angle_errors(instructions, grasps)
    np.testing.assert_allclose(errors, [29, 80, 20, 0, np.inf], atol=1e-4)  # float32 ground-truth angles
    assert angle_fit(errors) == {"within_30_deg": 60.0, "instructions": 5, "median_deg": 24.5}
    # the metric needs the IoU as well; this figure judges the angle alone, wherever the centre fell
    far = np.array([[400, 400, 0.0]])
    assert angle_fit(angle_errors(instructions[:1], far))["within_30_deg"] == 100.0
    assert not successes(instructions[:1], far, "honest")[0]
    empty = angle_fit(angle_errors([], np.zeros((0, 3))))
    assert empty["instructions"] == 0 and np.isnan(empty["within_30_deg"]) and empty["median_deg"] is None


def test_the_table_puts_the_target_ceiling_beside_the_accuracy_and_reads_older_results():
    group = {"accuracy": 25.0, "instructions": 4, "examples": 8, "unconstrained_accuracy": 0.0,
             "unconstrained_parse_failures": 3}
    older = {"step": 2, "split": "test", "examples": 8, "instructions": 4, "protocol": "honest", "backend": "exact",
             "accuracy": 25.0, "unconstrained": {"accuracy": 0.0, "parse_failures": 3},
             "by_scene": {"single": group}, "by_kind": {"non": group}}
    table = markdown(older)
    assert "| all | 4 | 8 | 25.00 | 0.00 | 3 |" in table and "ceiling" not in table and "Distinct" not in table
    spread = {"texts": 3, "centres": 2, "angles": 1, "grasps": 2}
    newer = {**older, "target_ceiling": 75.0, "distinct": {"answers": spread, "targets": dict(spread, angles=4)},
             "by_kind": {"non": {**group, "target_ceiling": 75.0}},
             "by_scene": {"single": {**group, "target_ceiling": 75.0}}}
    table = markdown(newer)
    assert "| accuracy (constrained) | target ceiling | accuracy (unconstrained) |" in table
    assert "| all | 4 | 8 | 25.00 | 75.00 | 0.00 | 3 |" in table
    assert "| kind non | 4 | 8 | 25.00 | 75.00 | 0.00 | 3 |" in table
    assert ("Distinct (constrained) answers: 3 texts, 2 centres, 1 angles, 2 grasps; "
            "targets: 3 texts, 2 centres, 4 angles, 2 grasps.") in table


def test_without_the_unconstrained_decoding_the_constrained_figures_and_answers_stay(evaluated, workdir):
    """What make demo asks for (half the decoding): the same constrained answers and figures, no
    unconstrained ones, and a table without their columns."""
    stdout, folder = evaluated
    both = json.loads(stdout)
    results, rows, _ = evaluate(workdir, unconstrained=False)
    assert "unconstrained" not in results and results["constrained"] == both["constrained"]
    for key in ("accuracy", "target_ceiling", "distinct", "angle_at_centre"):
        assert results[key] == both[key], key
    free_keys = {"unconstrained_accuracy", "unconstrained_parse_failures"}
    for groups in ("by_kind", "by_scene"):
        assert results[groups] == {name: {k: v for k, v in group.items() if k not in free_keys}
                                   for name, group in both[groups].items()}
    free_rows = {"unconstrained_answer", "unconstrained_parses", "unconstrained_correct"}
    written = [json.loads(line) for line in (folder / "answers.jsonl").read_text().splitlines()]
    assert rows == [{k: v for k, v in row.items() if k not in free_rows} for row in written]
    table = markdown(results)
    assert "unconstrained" not in table and f"| all | {results['instructions']} | {results['examples']} |" in table


def with_value(record_, evaluation, index, tokenizer, value):
    """Example `index`'s record with its target value replaced by `value`, its stored tokens and text made to match."""
    cue = evaluation.question_of[index].prompt.cue
    prompt_length = int(record_["length"]) - len(evaluation.target_ids[index])
    tokens = list(np.asarray(record_["tokens"])[:prompt_length]) + tokenizer.encode(value) + [tokenizer.eos_id]
    return {**record_, "tokens": np.asarray(tokens, np.int32), "length": len(tokens),
            "target_text": f"{cue} {value}".encode()}


def test_the_targets_scored_as_answers_make_the_ceiling_and_a_corrupted_target_lowers_it(workdir):
    run = open_run(workdir)
    one_device = make_mesh(1, 1, 1, devices=jax.devices()[:1])
    records = [dict(r) for r in run.split("test").examples]

    evaluation_of = lambda records_: GraspEvaluation(run.model_config, one_device, records_, run.tokenizer,
                                                     run.format_config, run.protocol, batch_size=4)
    evaluation = evaluation_of(records)
    count = len(evaluation.instructions)
    assert count >= 2 and evaluation.target_ceiling() == 100.0
    targets = evaluation.targets()
    # the stored tokens read back as the answers are read give the stored target texts
    assert {i: text for i, (text, _) in targets.items()} == {i: records[i]["target_text"].decode() for i in targets}
    first, second = evaluation.instructions[:2]
    # a target a quarter turn off its grasp: it parses, combines and misses
    angle = first.examples["angle"]
    turned = targets[angle][1].grasp[4] + np.pi / 2
    code = format_angle(turned, run.format_config.angle_code).rsplit(" ", 1)[-1]  # "a_<k>", the cue's value
    records[angle] = with_value(records[angle], evaluation, angle, run.tokenizer, code)
    corrupted = evaluation_of(records)
    assert corrupted.targets()[angle][1].ok
    assert corrupted.target_ceiling() == pytest.approx(100.0 * (count - 1) / count, abs=1e-3)
    # a location that does not parse: a miss too, never a ground truth in its place
    location = second.examples["location"]
    records[location] = with_value(records[location], evaluation, location, run.tokenizer, "a_3")
    corrupted = evaluation_of(records)
    assert not corrupted.targets()[location][1].ok
    assert corrupted.target_ceiling() == pytest.approx(100.0 * (count - 2) / count, abs=1e-3)


def run_cli(capsys, *args) -> tuple[int, str, str]:
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_workdir_without_checkpoints_or_tokenizer_is_an_error_that_says_so(workdir, tmp_path, capsys):
    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("run.json", "tokenizer.model"):
        shutil.copy(workdir / name, bare / name)
    code, out, err = run_cli(capsys, f"--workdir={bare}")
    assert code == 1 and "no checkpoint" in err and not out
    (bare / "tokenizer.model").unlink()
    code, _, err = run_cli(capsys, f"--workdir={bare}")
    assert code == 1 and "tokenizer.model is missing" in err
    code, _, err = run_cli(capsys, f"--workdir={tmp_path / 'nothing'}")
    assert code == 1 and "not a training run" in err
    code, _, err = run_cli(capsys, f"--workdir={workdir}", "--step=7")
    assert code == 1 and "no checkpoint of step 7" in err
    code, _, err = run_cli(capsys, f"--workdir={workdir}", "--split=valid")
    assert code == 1 and "unknown split 'valid'" in err


@pytest.mark.slow  # 28 s (make test's --durations, 2026-12-02, 2 cores)
def test_every_photo_of_a_cornell_folder_is_scored(workdir, tmp_path):
    folder = tmp_path / "photos"
    scenes.write_dataset(folder, photos=3, seed=11)
    done = run_module("kosmos_jax.evaluate", f"--workdir={workdir}", f"--cornell={folder}", "--json")
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads(done.stdout)
    assert results["split"] == "cornell-photos" and results["protocol"] == "honest" and results["kinds"] == ["non"]
    assert results["photos"] == 3 and results["instructions"] == 3 - results["views_without_grasps"]
    assert sum(g["examples"] for g in results["by_kind"].values()) == results["examples"] == 2 * results["instructions"]
    assert results["target_ceiling"] == 100.0 and results["by_kind"]["non"]["target_ceiling"] == 100.0
    assert results["distinct"]["targets"]["grasps"] == results["instructions"]  # one photo, one target grasp
    assert (workdir / "eval" / "2" / "cornell-photos" / "results.json").is_file()
    # part_oracles remakes that folder's instructions from results.json and scores the same answers alike
    done = run_module("kosmos_jax.diagnostics.part_oracles", f"--workdir={workdir}", "--scored=cornell-photos", "--json")
    assert done.returncode == 0, done.stderr[-3000:]
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    assert figures["scored"] == "cornell-photos" and figures["protocol"] == "honest"
    assert figures["instructions"] == results["instructions"]
    assert figures["accuracy"]["model"] == pytest.approx(results["accuracy"])
    done = run_module("kosmos_jax.diagnostics.part_oracles", f"--workdir={workdir}", "--scored=cornell-elsewhere")
    assert done.returncode != 0 and "--cornell=" in done.stderr


def test_image_use_scores_each_example_with_its_own_another_and_a_blank_image(workdir, capsys):
    from kosmos_jax.diagnostics import image_use

    np.testing.assert_array_equal(image_use.other_images(np.arange(3)), [1, 2, 0])
    # rows of one photo side by side (its centre and angle parts) never get their own image back
    np.testing.assert_array_equal(image_use.other_images(np.asarray([7, 7, 8, 8, 9])), [8, 8, 9, 9, 7])
    with pytest.raises(ValueError, match="same image"):
        image_use.other_images(np.zeros((4, 2, 2, 3), np.uint8))
    # a batch of one photo's rows takes the first spare that is another photo
    np.testing.assert_array_equal(image_use.other_images(np.asarray([7, 7]), np.asarray([7, 8])), [8, 8])
    with pytest.raises(ValueError, match="same image"):
        image_use.other_images(np.asarray([7, 7]), np.asarray([7, 7]))
    batches = [{"image": np.asarray([5, 5, 0]), "example_index": np.asarray([0, 1, -1])},  # -1: a padding row
               {"image": np.asarray([5, 6]), "example_index": np.asarray([2, 3])}]
    np.testing.assert_array_equal(image_use.spare_images(batches), [5, 6])
    assert image_use.spare_images(batches[:1]) is None
    result = image_use.image_use(workdir, batches=4, batch_size=8)  # the tiny config's eval batches
    logged = [r for r in read_metrics(workdir) if r.get("split") == "test" and "loss" in r][-1]
    assert result["step"] == 2 and result["tokens"] == logged["tokens"] > 0
    np.testing.assert_allclose(result["loss"]["own"], logged["loss"], rtol=1e-5)  # the trainer's own eval
    assert result["loss"]["other"] != result["loss"]["own"] != result["loss"]["blank"]  # pixels reach the logits
    assert image_use.main([f"--workdir={workdir}", "--batch-size=8", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((workdir / "eval" / "2" / "image_use.json").read_text())
    np.testing.assert_allclose(printed["loss"]["own"], result["loss"]["own"], rtol=1e-6)
    assert image_use.main([f"--workdir={workdir}", "--batch-size=1"]) == 1
    assert "batch_size=1" in capsys.readouterr().err
    assert image_use.main([f"--workdir={workdir}", "--step=7"]) == 1
    assert "no checkpoint of step 7" in capsys.readouterr().err


@pytest.mark.slow  # 62 s (make test's --durations, 2026-11-27, 2 cores)
def test_the_vision_probe_fits_a_batch_and_scores_every_test_example(workdir, capsys):
    import jax.numpy as jnp
    import optax
    from flax import nnx

    from kosmos_jax.diagnostics import vision_probe as vp
    from kosmos_jax.train import batches as batches_lib

    run = open_run(workdir)
    batch = next(batches_lib.eval_batches(run.split("train"), 8, 0, 1, 1))
    images, centres = jnp.asarray(batch["image"]), jnp.asarray(batch["grasp"][:, :2] / batch["image"].shape[1])
    for readout, lr in (("patches", 1e-4), ("cls", 1e-3), ("cells", 1e-3)):  # cls and cells need the larger steps
        probe = vp.CentreProbe(run.model_config.vision, readout, nnx.Rngs(0))
        optimizer = nnx.Optimizer(probe, optax.adamw(lr), wrt=nnx.Param)
        losses = [float(vp.train_step(probe, optimizer, images, centres)) for _ in range(40)]
        assert np.mean(losses[-10:]) < 0.5 * losses[0], (readout, losses)  # one batch can be fitted

    result = vp.vision_probe(workdir, steps=2, batch_size=8)
    assert result["test_examples"] == len(run.split("test")) and result["train_examples_seen"] == 16
    assert all(np.isfinite(result["mae_px"])) and all(0 <= e < 224 for e in result["mean_guess_mae_px"])
    assert 0 <= result["within_20px"] <= 1 and 0 <= result["mean_guess_within_20px"] <= 1
    cells = vp.vision_probe(workdir, steps=2, batch_size=8, readout="cells")
    side = next(batches_lib.eval_batches(run.split("test"), 8, 0, 1, 1))["image"].shape[1]
    assert all(0 < e < side for e in cells["mae_px"])
    assert np.all(np.asarray(result["centres_px"]["test"]["std"]) >= 0)
    assert vp.main([f"--workdir={workdir}", "--steps=0"]) == 1 and "steps=0" in capsys.readouterr().err
    assert vp.main([f"--workdir={workdir}", "--steps=1", "--batch-size=4", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["steps"] == 1


@pytest.mark.slow  # 31 s and 98 s (make test's --durations, 2026-11-27, 2 cores)
@pytest.mark.parametrize("run_fixture, places", [("workdir", {"tower", "slots"}),
                                                  ("values_workdir", {"tower", "slots", "decoder", "answer"})])
def test_the_angle_probe_reads_every_test_view_at_each_place_of_the_trained_and_untrained_model(
        run_fixture, places, request, capsys):
    """Digit numbers have no angle token: the probe reads the tower and the slots of one example per
    view; with value tokens, also the decoder at the angle token and the decoder's own answer."""
    from kosmos_jax.diagnostics import angle_probe as ap

    workdir = request.getfixturevalue(run_fixture)
    result = ap.angle_probe(workdir, examples=8)
    run = open_run(workdir)
    angle_ids = angle_token_ids(run.tokenizer.piece_texts())
    views = {r["image_index"] for r in run.split("test").examples
             if not len(angle_ids) or np.isin(r["tokens"][r["loss_mask"]], angle_ids).any()}
    assert result["test_views"] == len(views) and 2 <= result["train_views"] <= 8
    for name in ("trained", "untrained"):
        assert set(result[name]) == places
        for place in places - {"answer"}:
            assert 0 <= result[name][place]["test"] <= 100 and 0 <= result[name][place]["angle_share"] <= 1
        if "answer" in places:
            assert 1 <= result[name]["answer"]["distinct_test"] <= len(views)
    assert 0 <= result["constant"]["test"] <= 100
    assert ap.main([f"--workdir={workdir}", "--examples=1"]) == 2
    assert ap.main([f"--workdir={workdir}", "--examples=8", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["step"] == 2


@pytest.mark.slow  # 72 s with the values run it trains (make test's --durations, 2026-11-27, 2 cores)
def test_value_tokens_are_read_as_the_run_s_config_says_unless_told(values_workdir, tmp_path, capsys):

    configured, rows, _ = evaluate(values_workdir, max_examples=8)
    greedy, greedy_rows, _ = evaluate(values_workdir, max_examples=8, value_window=0)
    assert open_run(values_workdir).config.decode.value_window == configured["value_window"] == 32
    assert greedy["value_window"] == 0 and configured["angle_window"] == greedy["angle_window"] == 32
    for results in (configured, greedy):
        assert results["constrained"]["parse_failures"] == 0 and results["target_ceiling"] == 100.0
    # only the coordinate values may differ: the angle answers are read alike either way
    angles = [(a["answer"], b["answer"]) for a, b in zip(rows, greedy_rows) if a["part"] == "angle"]
    assert angles and all(a == b for a, b in angles)
    old = tmp_path / "made_before_decode"
    shutil.copytree(values_workdir, old, ignore=shutil.ignore_patterns("eval"))
    description = json.loads((old / "run.json").read_text())
    del description["config"]["decode"]
    (old / "run.json").write_text(json.dumps(description))
    made_before = evaluate(old, max_examples=8)[0]
    assert made_before["value_window"] == made_before["angle_window"] == 0  # runs made before the settings: greedy, as scored then
    assert main(["--workdir", str(values_workdir), "--value-window=-1"]) == 2
    assert "flag --value_window=-1: -1 is not a non-negative integer" in capsys.readouterr().err
    assert main(["--workdir", str(values_workdir), "--angle-window=128"]) == 2
    assert "flag --angle_window=128: 128 is not an integer in the range [0, 127]" in capsys.readouterr().err


@pytest.mark.slow  # 52 s (make test's --durations, 2026-12-02, 2 cores)
def test_an_exported_folder_scores_a_cornell_folder_as_its_run_does(workdir, tmp_path, capsys):
    folder = tmp_path / "photos"
    scenes.write_dataset(folder, photos=3, seed=12)
    exported = tmp_path / "exported"
    export_pretrained(workdir, exported)
    code, out, err = run_cli(capsys, f"--workdir={workdir}", f"--cornell={folder}", "--json")
    assert code == 0, err[-3000:]
    from_run = json.loads(out)
    code, out, err = run_cli(capsys, f"--pretrained={exported}", f"--cornell={folder}", f"--out={tmp_path / 'scores'}",
                             "--json")
    assert code == 0, err[-3000:]
    from_folder = json.loads(out)
    assert from_folder["pretrained"] == str(exported.resolve()) and from_folder["step"] == from_run["step"] == 2
    for key in ("accuracy", "by_kind", "by_scene", "distinct", "target_ceiling", "constrained", "unconstrained",
                "instructions", "photos", "value_window", "angle_window"):
        assert from_folder[key] == from_run[key], key
    answers = lambda path: [json.loads(line) for line in path.read_text().splitlines()]
    assert answers(tmp_path / "scores" / "cornell-photos" / "answers.jsonl") == answers(
        workdir / "eval" / "2" / "cornell-photos" / "answers.jsonl")
    assert sorted(p.name for p in exported.iterdir()) == ["config.json", "kosmos_e.json", "model.safetensors",
                                                         "tokenizer.model"]  # nothing written into the folder


def test_nounconstrained_scores_a_run_and_an_exported_folder_with_the_grammar_only(workdir, tmp_path, capsys):
    folder = tmp_path / "grammar_only"
    scenes.write_dataset(folder, photos=2, seed=13)
    exported = tmp_path / "exported"
    export_pretrained(workdir, exported)
    both = evaluate(workdir, cornell=folder)[0]
    for source in ([f"--workdir={workdir}"], [f"--pretrained={exported}", f"--out={tmp_path / 'scores'}"]):
        code, out, err = run_cli(capsys, *source, f"--cornell={folder}", "--json", "--nounconstrained")
        assert code == 0, err[-3000:]
        results = json.loads(out)
        assert "unconstrained" not in results and results["constrained"] == both["constrained"], source
        assert results["accuracy"] == both["accuracy"] and results["instructions"] == both["instructions"]


def test_an_exported_folder_is_refused_what_only_a_run_has_in_one_line(workdir, tmp_path, capsys):
    exported = tmp_path / "exported"
    export_pretrained(workdir, exported)
    photos = f"--cornell={tmp_path}"
    for args, says in (([f"--pretrained={exported}"], "give --cornell=PATH"),
                       ([f"--pretrained={exported}", photos, "--step=2"], "--step belongs to --workdir"),
                       ([f"--pretrained={exported}", photos, "--split=validation"], "--split belongs to --workdir"),
                       ([f"--pretrained={exported}", photos, f"--out={exported / 'scores'}"], "lies inside"),
                       ([f"--pretrained={tmp_path / 'nowhere'}", photos], "no such folder"),
                       ([f"--workdir={workdir}", f"--out={tmp_path / 'scores'}"], "--out goes with --pretrained")):
        code, out, err = run_cli(capsys, *args)
        assert code == 1 and not out and says in err, (args, err)
        assert len(err.strip().splitlines()) == 1 and err.startswith("error: ")
    assert sorted(p.name for p in exported.iterdir()) == ["config.json", "kosmos_e.json", "model.safetensors",
                                                         "tokenizer.model"]


def test_a_prompt_written_from_text_is_the_prompt_the_build_stored(workdir, tmp_path):
    """What the zoom asks (NON, no instruction) and the predict command asks (any instruction) are laid
    out as the build laid out the stored examples of those instructions."""
    run = open_run(workdir)
    folder = tmp_path / "photos"
    scenes.write_dataset(folder, photos=4, seed=11)
    records = cornell_examples(folder, run.tokenizer, run.format_config, ("non", "multi")).records
    cues = dict(prompt_cues(run.format_config, "grasp"))
    checked = set()
    for record in records:
        cue, instruction = cues[record["part"]], record["instruction"]
        ids, image_mask = written_prompt(run.tokenizer, instruction, cue)
        stored_ids, stored_mask = prompt(record, run.tokenizer, cue)
        np.testing.assert_array_equal(ids, stored_ids)
        np.testing.assert_array_equal(image_mask, stored_mask)
        checked.add((record["kind"], bool(instruction)))
    assert ("non", False) in checked and any(has_text for _, has_text in checked)


@pytest.mark.parametrize("stored", [False, True], ids=["cornell_folder", "stored_split"])
def test_a_mosaic_s_zoomed_answer_is_the_answer_to_a_non_example_showing_its_quadrant(stored, request, tmp_path):
    """zoomed_grasps against the one-pass evaluation: NON examples whose image is each mosaic's chosen
    quadrant enlarged, answered and combined as any example is, then mapped back (one row a batch:
    the same computation, to the bit). On a Cornell folder's records (images in them) and on a run's
    stored test split (its images joined back on reading, as make demo's held-out fold)."""
    run = open_run(request.getfixturevalue("mosaic_workdir" if stored else "workdir"))
    if stored:
        records = run.split("test")
    else:
        folder = tmp_path / "photos"
        scenes.write_dataset(folder, photos=4, seed=11)
        records = cornell_examples(folder, run.tokenizer, run.format_config, ("non", "multi")).records
    mesh = make_mesh(1, -1, 1)
    _, params = run.params(None, mesh)
    evaluate_records = lambda examples: GraspEvaluation(run.model_config, mesh, examples, run.tokenizer,
                                                        run.format_config, "honest", batch_size=1)
    evaluation = evaluate_records(records)
    first = evaluation.grasps(evaluation.answers(params))
    zoomed, texts = evaluation.zoomed_grasps(params, first)
    mosaics = [g for g, instruction in enumerate(evaluation.instructions) if instruction.scene == "multi"]
    assert mosaics and set(texts) == set(mosaics)
    assert np.isnan(np.delete(zoomed, mosaics, axis=0)).all()  # single photos are not zoomed
    non = next(instruction for instruction in evaluation.instructions if instruction.kind == "non")
    corners = quadrant_corners(first[mosaics, :2], records[0]["image"].shape[0])
    shown = [{**records[index], "image": zoomed_view(records[min(evaluation.instructions[g].examples.values())]["image"],
                                                     corner)}
             for g, corner in zip(mosaics, corners) for index in non.examples.values()]
    again = evaluate_records(shown)
    assert len(again.instructions) == len(mosaics)
    np.testing.assert_array_equal(from_zoomed(again.grasps(again.answers(params)), corners), zoomed[mosaics])


@pytest.mark.slow  # 25 s (2 cores shared with a training run, 2026-12-07)
def test_the_mosaic_zoom_scores_each_mosaic_again_and_keeps_the_single_photos(workdir, tmp_path):
    folder = tmp_path / "photos"
    scenes.write_dataset(folder, photos=4, seed=11)
    done = run_module("kosmos_jax.evaluate", f"--workdir={workdir}", f"--cornell={folder}", "--kinds=non,multi",
                      "--nounconstrained", "--mosaic_zoom", "--json")
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads(done.stdout)
    zoomed, one_pass = results["mosaic_zoom"], results["by_scene"]
    assert zoomed["by_scene"]["single"] == {key: one_pass["single"][key] for key in ("accuracy", "instructions", "examples")}
    assert zoomed["instructions"] == results["instructions"]
    right = lambda figures: round(figures["accuracy"] * figures["instructions"] / 100)
    assert right(zoomed["by_scene"]["multi"]) - right(one_pass["multi"]) == \
        zoomed["mosaics_right_only_zoomed"] - zoomed["mosaics_right_only_first"]
    rows = [json.loads(line) for line in (workdir / "eval" / "2" / "cornell-photos" / "answers.jsonl").read_text().splitlines()]
    assert all(("zoom_answer" in row) == (row["scene"] == "multi") for row in rows)
    assert all(row["zoom_answer"] for row in rows if row["scene"] == "multi")
    table = run_module("kosmos_jax.evaluate", f"--workdir={workdir}", f"--cornell={folder}", "--kinds=non,multi",
                       "--nounconstrained", "--mosaic_zoom")
    assert "Mosaic zoom (each mosaic instruction answered again on the quadrant its first answer chose)" in table.stdout

