"""The experiment runner: fold lists, arm configs, the skip and resume logic (a fake trainer counts its
calls), aggregation (mean, std, n; table.md; the no-learning rows), the data-size plot, every
experiment config (cpu and paper) built without training, the SLURM aggregate step, and one tiny
sweep end to end (slow)."""

import copy
import json
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time

import matplotlib.image
import numpy as np
import pytest

from kosmos_jax.experiments import aggregate, carried, checks, compare_sizes, data_size, records, runner, spec
from kosmos_jax.experiments.spec import ExperimentError, arm, experiment

REPO = pathlib.Path(__file__).resolve().parents[1]
EXPERIMENTS = ("table1", "table2", "table3", "table4", "table5", "data_size")
DEMO_EXPERIMENTS = ("table1", "table2", "table3", "table4", "data_size")  # those with a cpu_demo variant


# -- fold lists, arms, training configs ------------------------------------------------------------


@pytest.mark.parametrize("text, k, expected", [("", 5, [0, 1, 2, 3, 4]), ("0,2", 5, [0, 2]), (" 3 ", 5, [3]),
                                               ("2,0", 3, [0, 2]), (4, 5, [4])])
def test_parse_folds(text, k, expected):
    assert spec.parse_folds(text, k) == expected


@pytest.mark.parametrize("text, k, message", [
    ("5", 5, "fold 5 does not exist with k=5"), ("0,0", 5, "names a fold twice"), ("a", 5, "expected fold numbers"),
    ("0,,1", 5, "expected fold numbers"), ("-1", 5, "expected fold numbers"), ("0", 1, "at least 2 folds"),
    (None, 5, "expected text"),
])
def test_parse_folds_errors(text, k, message):
    with pytest.raises(ExperimentError, match=message):
        spec.parse_folds(text, k)


def test_parse_names():
    assert spec.parse_names("paper, honest", spec.PROTOCOLS, "protocol") == ["paper", "honest"]
    with pytest.raises(ExperimentError, match="unknown scheme 'photo'"):
        spec.parse_names("image,photo", spec.SCHEMES, "scheme")
    with pytest.raises(ExperimentError, match="comma-separated list"):
        spec.parse_names("", spec.SCHEMES, "scheme")


def test_nested_and_dotted_overrides():
    tree = spec.nested({"data.build.kinds": "non", "data.source": "cornell", "train.steps": 3})
    assert tree == {"data": {"build": {"kinds": "non"}, "source": "cornell"}, "train": {"steps": 3}}
    assert spec.dotted(arm("configs/kosmos_e.py:tiny", {"data.build.kinds": "non"}).overrides) == {"data.build.kinds": "non"}
    with pytest.raises(ExperimentError, match="another override sets to a value"):
        spec.nested({"data": 1, "data.source": "x"})


def one_arm(config: str, overrides: dict | None = None, **fields):
    return experiment("unit", {"a": arm(config, overrides)}, **{"schemes": "image", "protocols": "honest", **fields})


def test_arm_config_applies_overrides_and_fold_settings():
    config = one_arm("configs/kosmos_e.py:tiny", {"data.build.kinds": "all", "train.steps": 3})
    base = spec.arm_config(config, "a")
    assert base.data.build.kinds == "all" and base.train.steps == 3
    fold = spec.fold_config(base, spec.Run("a", "paper", "object", 2), 4)
    assert (fold.data.build.protocol, fold.data.build.split, fold.data.build.fold, fold.data.build.folds) == (
        "paper", "object", 2, 4)
    assert base.data.build.protocol == "honest"  # the arm's config is left as it was
    baseline = spec.fold_config(spec.arm_config(one_arm("configs/baselines.py:tiny"), "a"),
                                spec.Run("a", "paper", "image", 1), 3)
    assert (baseline.data.protocol, baseline.data.scheme, baseline.data.fold, baseline.data.folds) == ("paper", "image", 1, 3)


@pytest.mark.parametrize("config, overrides, message", [
    ("configs/missing.py:tiny", None, "config file 'configs/missing.py' does not exist"),
    ("configs/kosmos_e.py:huge", None, "unknown variant 'huge'"),
    ("configs/kosmos_e.py:tiny", {"data.build.kindz": "non"}, "no field 'data.build.kindz'"),
    ("configs/kosmos_e.py:tiny", {"dataa.source": "x"}, "no field 'dataa'"),
    ("configs/kosmos_e.py:tiny", {"train.steps": "many"}, "train.steps='many'"),
])
def test_arm_config_errors(config, overrides, message):
    with pytest.raises(ExperimentError, match=message):
        spec.arm_config(one_arm(config, overrides), "a")


def test_unknown_arm_and_arm_order():
    config = experiment("unit", {"zeta": arm("configs/baselines.py:tiny"), "alpha": arm("configs/baselines.py:tiny")},
                        schemes="image", protocols="honest", k=3)
    assert spec.arm_names(config) == ["zeta", "alpha"]  # the config's order, not the ConfigDict's sorted keys
    config.run_arms = "alpha,beta"
    with pytest.raises(ExperimentError, match="unknown arm 'beta'; expected some of zeta, alpha"):
        spec.runs(config)
    with pytest.raises(ExperimentError, match="unknown arm 'beta'"):
        spec.arm_config(config, "beta")


def test_init_from_sets_weights_and_tokenizer(tmp_path):
    (tmp_path / spec.KOSMOS_TOKENIZER).write_text("x")
    config = one_arm("configs/kosmos_e.py:paper")
    config.init_from = str(tmp_path)
    base = spec.arm_config(config, "a")
    assert base.init_from == str(tmp_path) and base.data.build.tokenizer == str(tmp_path / spec.KOSMOS_TOKENIZER)

# -- the sweep with a fake trainer ---------------------------------------------------------------


class FakeTrainer:
    """Records each call; writes the run.json a baseline run has (training views) and finishes,
    or stops early (SIGTERM) when asked."""

    def __init__(self, stop_at=None, fail_at=None):
        self.calls, self.stop_at, self.fail_at = [], stop_at, fail_at

    def __call__(self, config, workdir):
        run = (config.data.protocol, config.data.scheme, config.data.fold)
        self.calls.append((pathlib.Path(workdir).parent.name, *run, config.data.folds))
        if run == self.fail_at:
            raise FloatingPointError("loss is NaN")
        workdir.mkdir(parents=True, exist_ok=True)
        (workdir / "run.json").write_text(json.dumps({"config": config.to_dict(), "views": {"train": 10 + config.data.fold}}))
        if run == self.stop_at:
            return {"finished": False, "step": 1, "stopped": "preempted"}
        return {"finished": True, "step": config.train.steps, "resumed_from": 0}


def fake_evaluate(workdir, step):
    fold = int(workdir.name[-1])
    figures = {"accuracy": 10.0 * (fold + 1), "instructions": 4}
    return {"accuracy": figures["accuracy"], "step": step, "by_kind": {"non": figures}, "by_scene": {"single": figures}}


def baseline_experiment(folds="0,1"):
    fits = {"train.batch_size": 8}  # over the suite's 8 fake devices
    arms = {"b1": arm("configs/baselines.py:tiny", fits), "b2": arm("configs/baselines.py:tiny", {"train.steps": 4, **fits})}
    return experiment("unit", arms, schemes="image,object", protocols="honest", k=3, folds=folds)


def sweep(config, root, trainer, lines=None):
    return runner.run_experiment(config, root, train=trainer, evaluate=fake_evaluate, command="pytest",
                                 say=(lines if lines is not None else []).append)


def test_finished_folds_are_skipped(tmp_path):
    config, trainer = baseline_experiment(), FakeTrainer()
    summary = sweep(config, tmp_path, trainer)
    assert summary["trained"] == 8 and summary["failed"] == []
    assert sorted(trainer.calls) == sorted((arm_, "honest", scheme, fold, 3) for arm_ in ("b1", "b2")
                                           for scheme in ("image", "object") for fold in (0, 1))
    lines = []
    again = sweep(config, tmp_path, trainer, lines)
    assert len(trainer.calls) == 8 and again["skipped"] == 8 and again["trained"] == 0
    assert sum(line.endswith(f"done, skipped ({tmp_path / 'b1' / 'honest-image-fold0'})") for line in lines) == 1
    assert sum("done, skipped" in line for line in lines) == 8
    (tmp_path / "b2" / "honest-object-fold1" / records.FOLD_FILE).unlink()
    sweep(config, tmp_path, trainer)
    assert trainer.calls[8:] == [("b2", "honest", "object", 1, 3)]


def test_fold_subset_and_arm_subset(tmp_path):
    config, trainer = baseline_experiment(folds="2"), FakeTrainer()
    config.run_arms = "b2"
    sweep(config, tmp_path, trainer)
    assert sorted(trainer.calls) == [("b2", "honest", "image", 2, 3), ("b2", "honest", "object", 2, 3)]


def test_a_stopped_training_stops_the_sweep_and_resumes(tmp_path):
    config = baseline_experiment()
    stopping = FakeTrainer(stop_at=("honest", "image", 1))
    with pytest.raises(runner.SweepStopped, match="b1 honest-image fold 1: training stopped at step 1"):
        sweep(config, tmp_path, stopping)
    assert len(stopping.calls) == 2 and records.read_record(tmp_path / "b1" / "honest-image-fold1") is None
    trainer = FakeTrainer()
    sweep(config, tmp_path, trainer)
    assert trainer.calls[0] == ("b1", "honest", "image", 1, 3) and len(trainer.calls) == 7


def test_a_failed_fold_is_reported_and_the_rest_go_on(tmp_path):
    summary = sweep(baseline_experiment(), tmp_path, FakeTrainer(fail_at=("honest", "object", 0)))
    assert summary["trained"] == 6
    assert summary["failed"] == [("b1 honest-object fold 0", "FloatingPointError: loss is NaN"),
                                 ("b2 honest-object fold 0", "FloatingPointError: loss is NaN")]
    assert "b1 honest-object fold 0" in summary["results"]["missing"]


def test_a_bad_config_fails_before_any_training(tmp_path):
    config, trainer = baseline_experiment(), FakeTrainer()
    config.arms.b2.overrides.train.steps = 0
    with pytest.raises(ExperimentError, match="train.steps=0"):
        sweep(config, tmp_path, trainer)
    config.arms.b2.overrides.train.steps = 4
    config.arms.b1.overrides.train.batch_size = 3
    with pytest.raises(ExperimentError, match="b1 honest-image fold 0: on this machine's .* does not split"):
        sweep(config, tmp_path, trainer)
    assert trainer.calls == []


def test_missing_source_or_weights_fail_before_any_training(tmp_path):
    trainer = FakeTrainer()
    config = baseline_experiment()
    config.arms.b1.overrides.data = {"source": str(tmp_path / "nowhere")}
    with pytest.raises(ExperimentError, match=f"arm 'b1': data source .*{tmp_path / 'nowhere'} does not exist"):
        sweep(config, tmp_path, trainer)
    paper = one_arm("configs/kosmos_e.py:paper", {"data.source": "synthetic"})
    with pytest.raises(ExperimentError, match="arm 'a' starts from KOSMOS-2's weights: give --config.init_from"):
        sweep(paper, tmp_path, trainer)
    paper.init_from = str(tmp_path / "no_weights")
    with pytest.raises(ExperimentError, match="init_from folder .*no_weights does not exist"):
        sweep(paper, tmp_path, trainer)
    assert trainer.calls == []


def test_fold_record(tmp_path):
    sweep(baseline_experiment(), tmp_path, FakeTrainer())
    record = records.read_record(tmp_path / "b2" / "honest-object-fold1")
    assert record["accuracy"] == 20.0 and record["training_examples"] == 11 and record["task"] == "baseline"
    assert (record["arm"], record["protocol"], record["scheme"], record["fold"], record["k"]) == ("b2", "honest", "object", 1, 3)
    assert record["overrides"] == {"train.batch_size": 8, "train.steps": 4} and record["command"] == "pytest"
    assert record["machine"]["cpu_count"] == os.cpu_count() and record["machine"]["devices"]
    assert set(record["seconds"]) == {"train", "evaluate", "total"} and record["no_learning"] is None

# -- aggregation ---------------------------------------------------------------------------------


def test_summary():
    assert aggregate.summary([10.0, 20.0, 30.0]) == {"mean": 20.0, "std": round(float(np.std([10, 20, 30])), 4),
                                                     "n_folds": 3}
    assert aggregate.summary([]) == {"mean": None, "std": None, "n_folds": 0}


def test_aggregate_results_and_table(tmp_path):
    sweep(baseline_experiment(), tmp_path, FakeTrainer())
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["missing"] == [] and results["experiment"] == "unit"
    rows = {(r["arm"], r["scheme"]): r for r in results["rows"]}
    assert len(rows) == 4
    row = rows[("b1", "object")]
    assert row["folds"] == [0, 1] and row["fold_accuracies"] == [10.0, 20.0]
    assert (row["mean"], row["std"], row["n_folds"]) == (15.0, 5.0, 2)
    assert row["by_kind"]["non"]["mean"] == 15.0 and row["by_scene"]["single"]["n_folds"] == 2
    assert row["training_examples"] == [10, 11] and row["commands"] == ["pytest"] and len(row["machines"]) == 1
    table = (tmp_path / "table.md").read_text()
    assert "| arm | IW honest | OW honest |" in table
    assert "| b1 | 15.00 +- 5.00 (2) | 15.00 +- 5.00 (2) |" in table
    assert "| b2 | 15.00 +- 5.00 (2) | 15.00 +- 5.00 (2) |" in table
    assert "`pytest`" in table and "per instruction kind" not in table  # NON only: no per-kind section
    # the aggregate step alone reads the same records back
    (tmp_path / "results.json").unlink()
    again = aggregate.write_results(baseline_experiment(folds=""), tmp_path, "aggregate")
    assert again["missing"] == [f"{a} honest-{s} fold 2" for a in ("b1", "b2") for s in ("image", "object")]
    assert "Folds not run yet (4)" in (tmp_path / "table.md").read_text()


def test_arms_scored_under_their_own_protocols_and_public_on_fold_0_only(tmp_path):
    """An arm may name some of the experiment's protocols; `public` is one split, so only fold 0 of each scheme
    trains under it, and the table gets its columns."""
    config, trainer = baseline_experiment(), FakeTrainer()
    config.protocols = "honest,public"
    config.arms.b2.protocols = "honest"
    assert [r.name for r in spec.runs(config) if r.arm == "b1"] == [
        f"b1 honest-{s} fold {f}" for s in ("image", "object") for f in (0, 1)] + [
        "b1 public-image fold 0", "b1 public-object fold 0"]
    summary = sweep(config, tmp_path, trainer)
    assert summary["trained"] == 10 and summary["failed"] == []
    assert ("b1", "public", "image", 0, 3) in trainer.calls and not any(c[0] == "b2" and c[1] == "public"
                                                                         for c in trainer.calls)
    assert summary["results"]["missing"] == []
    table = (tmp_path / "table.md").read_text()
    assert "| arm | IW honest | OW honest | IW public | OW public |" in table
    assert "| b1 | 15.00 +- 5.00 (2) | 15.00 +- 5.00 (2) | 10.00 +- 0.00 (1) | 10.00 +- 0.00 (1) |" in table
    assert "| b2 | 15.00 +- 5.00 (2) | 15.00 +- 5.00 (2) | - | - |" in table
    config.folds = "1"
    assert [r.name for r in spec.runs(config)] == [f"{a} honest-{s} fold 1" for a in ("b1", "b2")
                                                   for s in ("image", "object")]


def test_an_arm_protocol_outside_the_experiments_and_kosmos_e_under_public_are_refused(tmp_path):
    config = baseline_experiment()
    config.arms.b2.protocols = "honest,paper"
    with pytest.raises(ExperimentError, match="arm 'b2' names protocol 'paper', which the experiment does not run"):
        spec.runs(config)
    config.arms.b2.protocols = "honest,open"
    with pytest.raises(ExperimentError, match="unknown arm 'b2': protocols 'open'"):
        spec.runs(config)
    kosmos = one_arm("configs/kosmos_e.py:tiny")
    kosmos.protocols = "honest,public"
    trainer = FakeTrainer()
    with pytest.raises(ExperimentError, match="a public-image fold 0: .*protocol 'public' scores a baseline's"):
        sweep(kosmos, tmp_path, trainer)
    with pytest.raises(ExperimentError, match="protocol 'public' scores a baseline's"):
        checks.check_experiment(kosmos)
    assert trainer.calls == []


def kosmos_record(root, config, run, accuracy, tests, kinds):
    scores = lambda value: {"accuracy": value, "instructions": 10,
                            "by_kind": {k: {"accuracy": value, "instructions": 5} for k in kinds},
                            "by_scene": {"single": {"accuracy": value, "instructions": 10}}}
    record = {"experiment": config.name, "arm": run.arm, "protocol": run.protocol, "scheme": run.scheme,
              "fold": run.fold, "accuracy": accuracy, "by_kind": {k: {"accuracy": accuracy + i} for i, k in enumerate(kinds)},
              "by_scene": {"single": {"accuracy": accuracy}}, "training_examples": 100, "seconds": {"total": 60.0},
              "machine": records.machine(), "command": "cmd",
              "no_learning": {"tests": tests, "scores": {"image_centre": scores(2.0 + run.fold), "gt_mean_oracle": scores(90.0)}}}
    records.write_json(run.workdir(root) / records.FOLD_FILE, record)


def kosmos_experiment(tmp_path, kinds=("non",), same_tests=True):
    config = experiment("t", {"x": arm("configs/kosmos_e.py:tiny"), "y": arm("configs/kosmos_e.py:tiny")},
                        schemes="image", protocols="honest", k=2)
    for run in spec.runs(config):
        tests = f"fold{run.fold}" if same_tests or run.arm == "x" else f"other{run.fold}"
        kosmos_record(tmp_path, config, run, 10.0 * (run.fold + 1) + (run.arm == "y"), tests, kinds)
    return config


def test_no_learning_rows_shared_by_arms_with_the_same_tests(tmp_path):
    config = kosmos_experiment(tmp_path)
    results = aggregate.write_results(config, tmp_path)
    shared = [r for r in results["rows"] if r["kind"] == "no_learning"]
    assert [(r["arm"], r["tests_of"]) for r in shared] == [("image_centre", ["x", "y"]), ("gt_mean_oracle", ["x", "y"])]
    assert shared[0]["fold_accuracies"] == [2.0, 3.0] and shared[0]["mean"] == 2.5
    table = (tmp_path / "table.md").read_text()
    assert "| image centre | 2.50 +- 0.50 (2) |" in table and "| ground-truth mean (oracle) | 90.00 +- 0.00 (2) |" in table
    assert "| y | 16.00 +- 5.00 (2) |" in table


def test_no_learning_rows_of_different_tests_are_apart(tmp_path):
    config = kosmos_experiment(tmp_path, kinds=("non", "colour", "multi-colour"), same_tests=False)
    results = aggregate.write_results(config, tmp_path)
    assert sorted(tuple(r["tests_of"]) for r in results["rows"] if r["kind"] == "no_learning") == [
        ("x",), ("x",), ("y",), ("y",)]
    table = (tmp_path / "table.md").read_text()
    assert "| image centre (tests of y) | 2.50 +- 0.50 (2) |" in table
    assert "## IW honest: per instruction kind and scene" in table
    assert "| arm | colour | multi-colour | non | scene single |" in table
    assert "| x | 16.00 +- 5.00 (2) | 17.00 +- 5.00 (2) | 15.00 +- 5.00 (2) | 15.00 +- 5.00 (2) |" in table

# -- the data-size plot --------------------------------------------------------------------------


def size_rows():
    def row(arm_, series, scheme, examples, accuracies):
        return {"kind": "trained", "arm": arm_, "series": series, "protocol": "honest", "scheme": scheme,
                "training_examples": examples, "training_examples_mean": float(np.mean(examples)),
                "fold_accuracies": accuracies, **aggregate.summary(accuracies)}
    return [row("p100", "photos", "image", [640, 660], [5.0, 7.0]), row("p300", "augmentations,photos", "image",
            [1900, 1950], [10.0, 14.0]), row("a8", "augmentations", "image", [3800, 3900], [20.0, 20.0]),
            row("p100", "photos", "object", [600, 610], [3.0, 5.0]), row("other", "", "image", [10], [99.0]),
            {"kind": "no_learning", "arm": "image_centre", "protocol": "honest", "scheme": "image", "n_folds": 2,
             "tests_of": ["p100", "a8"], "mean": 4.0},
            {"kind": "no_learning", "arm": "gt_mean_oracle", "protocol": "honest", "scheme": "image", "n_folds": 2,
             "tests_of": ["p300"], "mean": 80.0}]


def test_data_size_points_and_figure():
    points = data_size.points(size_rows())
    lines = data_size.lines(points)
    assert set(lines) == {("honest", "photos", "image"), ("honest", "augmentations", "image"), ("honest", "photos", "object")}
    assert [p["arm"] for p in lines[("honest", "photos", "image")]] == ["p100", "p300"]  # p300 sits on both lines
    assert [p["arm"] for p in lines[("honest", "augmentations", "image")]] == ["p300", "a8"]
    figure = data_size.figure(points)
    (ax,) = figure.axes
    assert ax.get_xscale() == "log"
    plotted = {c.get_label(): (list(c.lines[0].get_xdata()), list(c.lines[0].get_ydata())) for c in ax.containers}
    assert plotted["IW, photos"] == ([650.0, 1925.0], [6.0, 12.0])
    assert plotted["OW, photos"] == ([605.0], [4.0])  # one point, on no other OW line: drawn
    assert ax.get_title() == "honest protocol (mean +- std over 2 folds)"
    # the references at the x of the arms whose test they scored, one line per series, labelled once
    references = data_size.references(size_rows(), points)
    assert [(r["predictor"], r["series"], r["training_examples"]) for r in references] == [
        ("gt_mean_oracle", "augmentations", 1925.0), ("gt_mean_oracle", "photos", 1925.0),
        ("image_centre", "augmentations", 3850.0), ("image_centre", "photos", 650.0)]
    ax = data_size.figure(points, references).axes[0]
    assert {line.get_label() for line in ax.get_lines() if not line.get_label().startswith("_")} == {
        "IW, image centre", "IW, oracle (ground-truth mean)"}
    assert [(list(line.get_xdata()), list(line.get_ydata())) for line in ax.get_lines()
            if line.get_linestyle() == ":"] == [([3850.0], [4.0]), ([650.0], [4.0])]
    assert {text.get_text() for text in ax.get_legend().get_texts()} == {
        "IW, photos", "IW, augmentations", "OW, photos", "IW, image centre", "IW, oracle (ground-truth mean)"}


def test_data_size_leaves_out_a_one_point_series_that_another_line_draws():
    # p300 alone on the augmentations line (a8 dropped): its point is on the photos line, so that series
    # would be a legend entry with nothing of its own; a one-point series on no other line stays
    rows = [r for r in size_rows() if r["arm"] != "a8"]
    assert set(data_size.lines(data_size.points(rows))) == {("honest", "photos", "image"), ("honest", "photos", "object")}


def write_sweep(path, rows):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"experiment": "data_size", "rows": rows}))
    return path


def test_compare_sizes_draws_each_sweep_and_shared_references_once(tmp_path, capsys):
    scratch_rows = [{**r, "fold_accuracies": [a - 5 for a in r["fold_accuracies"]], "mean": r["mean"] - 5}
                    if r["kind"] == "trained" else r for r in size_rows()]
    first = write_sweep(tmp_path / "a" / "results.json", size_rows())
    second = write_sweep(tmp_path / "b" / "results.json", scratch_rows)
    out = tmp_path / "plots" / "compare.png"
    assert compare_sizes.main([f"--sweeps=pretrained={first},scratch={second}", f"--out={out}"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and "from 2 sweeps" in capsys.readouterr().out
    written = json.loads(out.with_suffix(".json").read_text())
    by_sweep = {(p["sweep"], p["series"], p["arm"], p["scheme"]): p["accuracy_mean"] for p in written["points"]}
    assert by_sweep[("pretrained", "pretrained: photos", "p100", "image")] == 6.0
    assert by_sweep[("scratch", "scratch: photos", "p100", "image")] == 1.0
    assert by_sweep[("scratch", "scratch: augmentations", "a8", "image")] == 15.0
    # the same tests in both sweeps: each reference once, on the first sweep's lines, as that sweep alone draws it
    alone = data_size.references(size_rows(), data_size.points(size_rows()))
    assert [{**r, "series": r["series"].removeprefix("pretrained: ")} for r in written["references"]] == [
        {**r, "sweep": "pretrained"} for r in alone]
    chosen, references = compare_sizes.combined([("pretrained", size_rows()), ("scratch", scratch_rows)])
    ax = data_size.figure(chosen, references).axes[0]
    assert {"IW, pretrained: photos", "IW, scratch: photos", "OW, scratch: photos"} <= {
        text.get_text() for text in ax.get_legend().get_texts()}


def test_compare_sizes_draws_references_of_other_tests_on_their_own_sweeps_lines():
    """A sweep scored on other tests (another image-centre figure) keeps its reference line apart: no line
    joins one sweep's reference to another's."""
    other_tests = [{**r, "mean": 9.0} if r["arm"] == "image_centre" else r for r in size_rows()]
    chosen, references = compare_sizes.combined([("a", size_rows()), ("b", other_tests)])
    assert sorted((r["sweep"], r["accuracy_mean"]) for r in references if r["predictor"] == "image_centre") == [
        ("a", 4.0), ("a", 4.0), ("b", 9.0), ("b", 9.0)]
    assert [r["sweep"] for r in references if r["predictor"] == "gt_mean_oracle"] == ["a", "a"]  # the same tests
    ax = data_size.figure(chosen, references).axes[0]
    dotted = [set(line.get_ydata()) for line in ax.get_lines() if line.get_linestyle() == ":"]
    assert sorted(map(sorted, dotted)) == [[4.0], [4.0], [9.0], [9.0]]


def test_compare_sizes_names_arms_trained_on_different_data(tmp_path, capsys):
    other = [{**r, "training_examples": [e + 1 for e in r["training_examples"]]} if r["arm"] == "p100" else r
             for r in size_rows()]
    first = write_sweep(tmp_path / "a.json", size_rows())
    second = write_sweep(tmp_path / "b.json", other)
    assert compare_sizes.main([f"--sweeps=a={first},b={second}", f"--out={tmp_path / 'c.png'}"]) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note:")]
    assert len(notes) == 2 and all("p100" in note and "'a'" in note and "'b'" in note for note in notes)


@pytest.mark.parametrize("sweeps,out,message", [
    ("nolabel", "c.png", "LABEL=PATH"),
    ("a=missing.json", "c.png", "cannot read"),
    ("a=notresults.json", "c.png", "not an experiment's results.json"),
    ("a=good.json,a=good.json", "c.png", "share a label"),
    ("a=good.json", "c.pdf", ".png"),
    ("a=empty.json", "c.png", "nothing to plot"),
])
def test_compare_sizes_refuses_bad_input_in_one_line(tmp_path, capsys, monkeypatch, sweeps, out, message):
    monkeypatch.chdir(tmp_path)
    write_sweep(tmp_path / "good.json", size_rows())
    write_sweep(tmp_path / "empty.json", [r for r in size_rows() if r["kind"] != "trained"])
    (tmp_path / "notresults.json").write_text("[1, 2]")
    assert compare_sizes.main([f"--sweeps={sweeps}", f"--out={out}"]) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and len(error.splitlines()) == 1
    assert not (tmp_path / "c.png").exists()


def test_data_size_files(tmp_path):
    data, plot = data_size.write(tmp_path, size_rows())
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert matplotlib.image.imread(plot).shape[2] in (3, 4)
    written = json.loads(data.read_text())["points"]
    assert [(p["arm"], p["series"], p["training_examples"], p["accuracy_mean"], p["accuracy_std"]) for p in written
            if p["scheme"] == "image"] == [("p300", "augmentations", 1925.0, 12.0, 2.0),
                                           ("a8", "augmentations", 3850.0, 20.0, 0.0),
                                           ("p100", "photos", 650.0, 6.0, 1.0), ("p300", "photos", 1925.0, 12.0, 2.0)]

# -- the experiment configs ------------------------------------------------------------------------


@pytest.mark.parametrize("name,variant", [(name, variant) for name in EXPERIMENTS for variant in ("cpu", "paper")]
                         + [(name, "cpu_demo") for name in DEMO_EXPERIMENTS] + [("data_size", "cpu_scratch")])
def test_experiment_config_builds(name, variant):
    config = spec.load_config(f"configs/experiments/{name}.py:{variant}")
    reports = checks.check_experiment(config)
    cells = {(r["arm"], r["protocol"], r["scheme"]) for r in reports}
    assert cells == {(a, p, s) for a in config.arms for p in config.protocols.split(",") for s in config.schemes.split(",")}
    assert all(r["params"] > 0 for r in reports)
    if variant == "paper":
        assert config.folds == "" and spec.parse_folds(config.folds, config.k) == list(range(5))
        assert all(r["params"] > 1e9 for r in reports if r["task"] == "kosmos_e")  # KOSMOS-2's size
    if name == "data_size":
        assert config.data_size_plot and all(config.arms[a].series for a in config.arms)


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_cpu_kosmos_arms_build_on_the_demo_config(name):
    """The cpu arms take their model, optimiser and batch from configs/kosmos_e.py:demo_kosmos2, the
    demo recipe they were run with (KOSMOS-2's connector, digits), not from the demo's newer one."""
    demo = spec.load_config("configs/kosmos_e.py:demo_kosmos2")
    config = spec.load_config(f"configs/experiments/{name}.py:cpu")
    kosmos = [a for a in config.arms if config.arms[a].config.startswith("configs/kosmos_e.py")]
    assert kosmos
    for name_ in kosmos:
        assert config.arms[name_].config == "configs/kosmos_e.py:demo_kosmos2"
        built = spec.arm_config(config, name_)
        assert built.model == demo.model and built.optimizer == demo.optimizer
        assert built.train.batch_size == demo.train.batch_size
        assert "model" not in config.arms[name_].overrides and "optimizer" not in config.arms[name_].overrides


# what each cpu_demo variant may change in the demo's data build, besides the instruction kinds
DEMO_BUILD_CHANGES = {"data_size": {"augmentations"}, "table1": set(), "table2": {"augmentations", "max_length"},
                      "table3": {"representation"}, "table4": {"individual", "angle_code", "max_length"}}


@pytest.mark.parametrize("name", DEMO_EXPERIMENTS)
def test_the_cpu_demo_variants_train_the_demo_recipe(name):
    demo = spec.load_config("configs/kosmos_e.py:demo")
    config = spec.load_config(f"configs/experiments/{name}.py:cpu_demo")
    for arm_name in spec.arm_names(config):
        assert config.arms[arm_name].config == "configs/kosmos_e.py:demo"
        built = spec.arm_config(config, arm_name)
        assert built.model == demo.model and built.optimizer == demo.optimizer and built.train == demo.train
        changed = {key for key in demo.data.build.keys() if built.data.build[key] != demo.data.build[key]}
        assert changed <= {"kinds"} | DEMO_BUILD_CHANGES[name]
        assert built.data.build.train_crop == "image_centre" and built.data.build.numbers == "values"
    assert config.protocols == "honest"  # the demo's photo-centre crops would replace the paper protocol's own


def test_table1_cpu_pretrained_fine_tunes_the_shipped_start_as_make_demo_does():
    tune = spec.load_config("configs/kosmos_e.py:demo_photos_finetune")
    config = spec.load_config("configs/experiments/table1.py:cpu_pretrained")
    assert spec.arm_names(config) == ["kosmos_e"] and config.protocols == "honest"
    built = spec.arm_config(config, "kosmos_e")
    assert built.init_from == "results/pretrain/demo_photos1200" and (spec.REPO / built.init_from).is_dir()
    assert built.model == tune.model and built.optimizer == tune.optimizer and built.train == tune.train
    assert built.data.source == "cornell" and built.data.build.kinds == "non"
    assert built.data.build.train_crop == "image_centre" and built.require_init


@pytest.mark.parametrize("variant", ["cpu_pretrained", "cpu_grounded"])
def test_table2_from_a_start_that_knows_every_kind(variant):
    """The cpu_demo mixes and data, from the stream pretraining run named in the config's docstring (its
    config's model) or the committed grounding start (the folder's own model): the start's weights load only
    into the same model; make demo's fine-tune rate."""
    from kosmos_jax.models import weights
    from kosmos_jax.train.run_start import check_same_model
    from kosmos_jax.workdir.model import model_config

    demo = spec.load_config("configs/experiments/table2.py:cpu_demo")
    config = spec.load_config(f"configs/experiments/table2.py:{variant}")
    tune = spec.load_config("configs/kosmos_e.py:demo_photos_finetune")
    start = {"cpu_pretrained": "runs/pretrain/stream_wide1500", "cpu_grounded": spec.GROUNDING6000_START}[variant]
    start_model = (weights.read_config(spec.REPO / start) if variant == "cpu_grounded" else
                   model_config(spec.load_config("configs/pretrain.py:demo_stream_instruct").model, 1000))
    assert spec.arm_names(config) == spec.arm_names(demo) and config.protocols == "honest"
    assert config.folds == demo.folds and config.schemes == demo.schemes
    for name in spec.arm_names(config):
        built, scratch = spec.arm_config(config, name), spec.arm_config(demo, name)
        assert built.init_from == start and built.require_init
        assert built.data == scratch.data and built.train == scratch.train
        assert built.optimizer == tune.optimizer  # make demo's fine-tune schedule
        check_same_model(start_model, model_config(built.model, start_model.text.vocab_size), built.init_from)
        assert built.model.connector_instruction and not scratch.model.connector_instruction


def test_the_cpu_demo_data_sweep_counts_photos_and_augmentations():
    """Two lines that meet at the demo itself (300 photos of 16 augmentations), both schemes."""
    config = spec.load_config("configs/experiments/data_size.py:cpu_demo")
    built = {n: spec.arm_config(config, n) for n in spec.arm_names(config)}
    series = {n: set(config.arms[n].series.split(",")) for n in built}
    photos = sorted((b.data.synthetic_photos, b.data.build.augmentations) for n, b in built.items() if "photos" in series[n])
    augmentations = sorted((b.data.synthetic_photos, b.data.build.augmentations)
                           for n, b in built.items() if "augmentations" in series[n])
    assert photos == [(100, 16), (300, 16), (1000, 16)]
    assert augmentations == [(300, 4), (300, 8), (300, 16)]
    assert built["photos300_aug16"].data == spec.load_config("configs/kosmos_e.py:demo").data
    assert all(b.data.build.kinds == "non" for b in built.values())
    assert config.schemes == "image,object"


def test_the_pretrained_data_sweep_fine_tunes_the_shipped_start_on_more_and_more_photos():
    """make demo's recipe at four photo counts, 1,200 being the demo's own data; three folds for the spread."""
    tune = spec.load_config("configs/kosmos_e.py:demo_photos_finetune")
    config = spec.load_config("configs/experiments/data_size.py:cpu_pretrained")
    built = {n: spec.arm_config(config, n) for n in spec.arm_names(config)}
    assert sorted(b.data.synthetic_photos for b in built.values()) == [150, 300, 600, 1200]
    assert built["photos1200_aug4"].data == tune.data
    for b in built.values():
        assert b.init_from == "results/pretrain/demo_photos1200" and (spec.REPO / b.init_from).is_dir()
        assert b.model == tune.model and b.optimizer == tune.optimizer and b.train == tune.train and b.require_init
        assert b.data.build.augmentations == 4 and b.data.build.kinds == "non"
    assert spec.parse_folds(config.folds, config.k) == [0, 1, 2] and config.schemes == "image"


def test_the_cornell_data_sweep_fine_tunes_the_grounding_start_on_more_and_more_views():
    """The paper's Fig. 6 on Cornell: make demo's fine-tune, NON only, at four augmentation counts, both schemes."""
    tune = spec.load_config("configs/kosmos_e.py:demo_grounded")
    config = spec.load_config("configs/experiments/data_size.py:cornell_grounded")
    built = {n: spec.arm_config(config, n) for n in spec.arm_names(config)}
    assert sorted(b.data.build.augmentations for b in built.values()) == [2, 4, 8, 16]
    assert all(config.arms[n].series == "augmentations" for n in built)
    for b in built.values():
        assert b.init_from == spec.GROUNDING_START and (spec.REPO / b.init_from).is_dir() and b.require_init
        assert b.model == tune.model and b.optimizer == tune.optimizer and b.train == tune.train
        assert b.data.source == "cornell" and b.data.build.kinds == "non"
        assert b.data.build.train_crop == tune.data.build.train_crop == "image_centre"
    assert spec.parse_folds(config.folds, config.k) == [0, 1]
    assert (config.schemes, config.protocols) == ("image,object", "honest")


def test_table1_converged_scores_the_shipped_baselines_under_three_protocols_beside_make_demos_fine_tune():
    """cpu_converged: the baselines as configs/baselines.py ships them (chosen on validation) under honest, paper
    and public; KOSMOS-E as the Cornell Fig. 6 sweep's 4-view arm, honest only."""
    config = spec.load_config("configs/experiments/table1.py:cpu_converged")
    fig6 = spec.load_config("configs/experiments/data_size.py:cornell_grounded")
    assert spec.arm_names(config) == ["kosmos_e", "grconvnet_rgbd", "grconvnet_rgb", "ggcnn2_d"]
    kosmos = spec.arm_config(config, "kosmos_e")
    assert kosmos == spec.arm_config(fig6, "cornell_aug4") and kosmos.init_from == spec.GROUNDING_START
    for name in ("grconvnet_rgbd", "grconvnet_rgb", "ggcnn2_d"):
        built, shipped = spec.arm_config(config, name), spec.load_config(f"configs/baselines.py:{name}")
        assert built.data.source == "cornell" and built.train == shipped.train and built.optimizer == shipped.optimizer
        assert built.optimizer.end_lr == built.optimizer.peak_lr  # the constant rate chosen on validation
    cells = {(r.arm, r.protocol, r.scheme, r.fold) for r in spec.runs(config)}
    assert {p for a, p, _, _ in cells if a == "kosmos_e"} == {"honest"}
    assert {(p, f) for a, p, s, f in cells if a == "ggcnn2_d" and s == "image"} == {
        ("honest", 0), ("honest", 1), ("paper", 0), ("paper", 1), ("public", 0)}
    reports = checks.check_experiment(config)
    assert {(r["arm"], r["protocol"]) for r in reports} == {(a, p) for a, p, _, _ in cells}


def test_the_cornell_epochs_sweep_scales_the_schedule_with_the_views_and_shares_the_four_view_arm():
    """Each arm makes the same passes over its views (100 steps and 25 warm-up steps a view); else as cornell_grounded."""
    fixed = spec.load_config("configs/experiments/data_size.py:cornell_grounded")
    config = spec.load_config("configs/experiments/data_size.py:cornell_grounded_epochs")
    assert spec.arm_names(config) == ["cornell_aug2_steps200", "cornell_aug4", "cornell_aug8_steps800",
                                      "cornell_aug16_steps1600"]
    assert (config.folds, config.schemes, config.protocols) == (fixed.folds, fixed.schemes, fixed.protocols)
    for name in spec.arm_names(config):
        built = spec.arm_config(config, name)
        views = built.data.build.augmentations
        same_steps = spec.arm_config(fixed, f"cornell_aug{views}")
        assert (built.train.steps, built.optimizer.warmup_steps) == (100 * views, 25 * views)
        assert built.train.steps * built.train.batch_size / views == 3200  # examples a view of a photo
        assert built.data == same_steps.data and built.model == same_steps.model
        assert built.optimizer.peak_lr == same_steps.optimizer.peak_lr and built.init_from == same_steps.init_from
        # the 4-view arm is cornell_grounded's own, overrides and recipe: its fold records serve both sweeps
        shared = config.arms[name].overrides == fixed.arms[f"cornell_aug{views}"].overrides
        assert shared == (spec.recipe(built) == spec.recipe(same_steps)) == (views == 4)


def test_the_scratch_data_sweep_is_the_pretrained_one_without_its_start():
    """The same arms, data, steps and folds as cpu_pretrained; the from-scratch recipe's model and rate."""
    scratch_recipe = spec.load_config("configs/kosmos_e.py:demo_photos")
    pretrained = spec.load_config("configs/experiments/data_size.py:cpu_pretrained")
    config = spec.load_config("configs/experiments/data_size.py:cpu_scratch")
    assert spec.arm_names(config) == spec.arm_names(pretrained)
    assert (config.folds, config.schemes, config.protocols) == (pretrained.folds, pretrained.schemes, pretrained.protocols)
    for name in spec.arm_names(config):
        built, tuned = spec.arm_config(config, name), spec.arm_config(pretrained, name)
        assert built.init_from == "" and not built.require_init
        assert built.data == tuned.data and built.train == tuned.train
        assert built.model == scratch_recipe.model and built.optimizer == scratch_recipe.optimizer
        assert built.optimizer.peak_lr > tuned.optimizer.peak_lr


def test_the_cpu_demo_tables_keep_the_cpu_folds_and_tests():
    """Their rows sit beside the cpu variants' (whose baselines they do not train again): same data,
    schemes, first fold and instruction kinds."""
    for name in ("table1", "table2", "table3", "table4"):
        cpu = spec.load_config(f"configs/experiments/{name}.py:cpu")
        demo = spec.load_config(f"configs/experiments/{name}.py:cpu_demo")
        assert demo.schemes == cpu.schemes and spec.parse_folds(demo.folds, demo.k) == [0]
        for arm_name in spec.arm_names(demo):
            ours, theirs = spec.arm_config(demo, arm_name), spec.arm_config(cpu, arm_name)
            assert ours.data.source == theirs.data.source and ours.data.build.kinds == theirs.data.build.kinds
            assert ours.data.build.augmentations == theirs.data.build.augmentations
            assert ours.data.build.representation == theirs.data.build.representation
    assert spec.arm_names(spec.load_config("configs/experiments/table1.py:cpu_demo")) == ["kosmos_e"]
    assert spec.arm_names(spec.load_config("configs/experiments/table2.py:cpu_demo")) == ["non", "single", "multi", "all"]


def test_table1_cpu_reads_cornell_and_its_baselines():
    config = spec.load_config("configs/experiments/table1.py:cpu")
    assert spec.arm_names(config) == ["kosmos_e", "grconvnet_rgbd", "grconvnet_rgb", "ggcnn2_d"]
    assert all(spec.arm_config(config, a).data.source == "cornell" for a in config.arms)
    assert spec.arm_config(config, "kosmos_e").data.build.kinds == "non"

def test_records_carried_out_and_back_are_skipped_and_aggregated(tmp_path):
    """A sweep's records sent to a kept folder come back into a new workdir: nothing trains again,
    and the new workdir aggregates them as the old one did."""
    config, trainer = baseline_experiment(folds="0"), FakeTrainer()
    sweep(config, tmp_path / "old", trainer)
    assert carried.send_out(config, tmp_path / "old", tmp_path / "kept") == [
        f"{a} honest-{s} fold 0" for a in ("b1", "b2") for s in ("image", "object")]
    assert sorted(p.name for p in (tmp_path / "kept" / "b1" / "honest-image-fold0").iterdir()) == [records.FOLD_FILE]
    assert len(carried.bring_in(config, tmp_path / "kept", tmp_path / "new")) == 4
    again = sweep(config, tmp_path / "new", trainer)
    assert len(trainer.calls) == 4 and again["skipped"] == 4
    assert again["results"]["rows"] == json.loads((tmp_path / "old" / "results.json").read_text())["rows"]
    assert carried.bring_in(config, tmp_path / "kept", tmp_path / "new") == []  # identical records: nothing to do
    more = baseline_experiment(folds="0,1")
    sweep(more, tmp_path / "new", trainer)
    assert len(trainer.calls) == 8  # only fold 1 trained
    assert len(carried.send_out(more, tmp_path / "new", tmp_path / "kept")) == 4


def test_carried_records_refuse_another_arm_or_a_clash(tmp_path):
    config = baseline_experiment(folds="0")
    sweep(config, tmp_path / "old", FakeTrainer())
    carried.send_out(config, tmp_path / "old", tmp_path / "kept")
    changed = baseline_experiment(folds="0")
    changed.arms.b2.overrides.train.steps = 5
    with pytest.raises(ExperimentError, match="made by arm 'b2'.*filed under the wrong arm"):
        carried.bring_in(changed, tmp_path / "kept", tmp_path / "new")
    assert not (tmp_path / "new").exists()  # b1's records were not copied either
    clash = tmp_path / "kept" / "b1" / "honest-image-fold0" / records.FOLD_FILE
    clash.write_text(json.dumps({**json.loads(clash.read_text()), "accuracy": 99.0}))
    with pytest.raises(ExperimentError, match="already holds another record of b1 honest-image fold 0"):
        carried.send_out(config, tmp_path / "old", tmp_path / "kept")
    assert json.loads(clash.read_text())["accuracy"] == 99.0  # nothing replaced
    with pytest.raises(ExperimentError, match="--records_from folder .* does not exist"):
        carried.bring_in(config, tmp_path / "absent", tmp_path / "new")


def test_records_of_an_arm_whose_config_file_changed_are_refused(tmp_path, monkeypatch):
    """Same arm name and overrides, but the arm's config file now resolves to another training config
    (a new default of its variant): neither a rerun in the workdir nor --records_from reuses the records."""
    config = baseline_experiment(folds="0")
    sweep(config, tmp_path / "old", FakeTrainer())
    carried.send_out(config, tmp_path / "old", tmp_path / "kept")
    record = json.loads((tmp_path / "kept" / "b1" / "honest-image-fold0" / records.FOLD_FILE).read_text())
    fold = spec.fold_config(spec.arm_config(config, "b1"), spec.runs(config)[0], config.k)
    assert record["recipe"] == spec.recipe(fold) == spec.recipe(copy.deepcopy(fold))
    load = spec.load_config

    def new_default(path):
        loaded = load(path)
        if path == "configs/baselines.py:tiny":
            loaded.train.seed += 1
        return loaded

    monkeypatch.setattr(spec, "load_config", new_default)
    with pytest.raises(ExperimentError, match="another training config than the arm resolves to now"):
        carried.bring_in(config, tmp_path / "kept", tmp_path / "new")
    assert not (tmp_path / "new").exists()
    trainer = FakeTrainer()
    with pytest.raises(ExperimentError, match="another training config than the arm resolves to now"):
        sweep(config, tmp_path / "old", trainer)
    assert trainer.calls == []
    old_record = {key: value for key, value in record.items() if key != "recipe"}  # made before recipes were kept
    spec.check_recipe(old_record, fold, "an old record")


class FillingTrainer(FakeTrainer):
    """Fills in a field of the config it is given, as the trainer fills in a pretrained start's tokenizer."""

    def __call__(self, config, workdir):
        with config.unlocked():
            config.train.seed += 7
        return super().__call__(config, workdir)


def test_a_trainer_filling_in_its_config_leaves_the_record_resumable(tmp_path):
    """The record keeps the fingerprint of the config the rerun resolves to, not of the trainer's
    filled-in copy: a rerun and --records_from skip the folds instead of refusing them."""
    config = baseline_experiment(folds="0")
    sweep(config, tmp_path / "old", FillingTrainer())
    fold = spec.fold_config(spec.arm_config(config, "b1"), spec.runs(config)[0], config.k)
    record = json.loads((tmp_path / "old" / "b1" / "honest-image-fold0" / records.FOLD_FILE).read_text())
    assert record["recipe"] == spec.recipe(fold)
    trainer = FakeTrainer()
    assert sweep(config, tmp_path / "old", trainer)["skipped"] == 4 and trainer.calls == []
    carried.send_out(config, tmp_path / "old", tmp_path / "kept")
    assert len(carried.bring_in(config, tmp_path / "kept", tmp_path / "new")) == 4


COMMITTED_RECORDS = sorted(path for path in (REPO / "results").glob("*/folds/*/*/fold.json")
                           if "recipe" in json.loads(path.read_text()))


@pytest.mark.parametrize("path", COMMITTED_RECORDS, ids=lambda p: str(p.relative_to(REPO / "results")))
def test_committed_fold_records_match_the_configs_they_name(path, monkeypatch):
    """Every committed fold record that keeps its recipe resolves to it today, so --records_from carries it in:
    a config field added without its ADDED_AT entry, or a changed default, shows here and not on a user's resume."""
    monkeypatch.chdir(REPO)
    record = json.loads(path.read_text())
    experiment_config = spec.load_config(record["command"].split("--config=")[1].split()[0])
    run = spec.Run(record["arm"], record["protocol"], record["scheme"], record["fold"])
    spec.check_recipe(record, spec.fold_config(spec.arm_config(experiment_config, run.arm), run, record["k"]), path)


# -- the command and the launcher ------------------------------------------------------------------


def command(*args):
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    return subprocess.run([sys.executable, "-m", "kosmos_jax.experiments", *args], capture_output=True, text=True,
                          timeout=300, cwd=REPO, env=env)


def test_command_check_only_and_errors(tmp_path):
    done = command("--config=configs/experiments/table3.py:cpu", f"--workdir={tmp_path}", "--check_only")
    assert done.returncode == 0, done.stderr[-2000:]
    assert sorted(json.loads(line)["arm"] for line in done.stdout.splitlines()) == ["tlbra", "tlbra_patch", "xya", "xywha"]
    bad = command("--config=configs/experiments/table3.py:cpu", f"--workdir={tmp_path}", "--config.run_arms=xyz")
    assert bad.returncode == 1 and "error: unknown arm 'xyz'; expected some of xya, xywha, tlbra, tlbra_patch" in bad.stderr
    assert not list(tmp_path.iterdir())


BASELINE_EXPERIMENT_FILE = """
from kosmos_jax.experiments.spec import arm, experiment


def get_config(arg=None):
    fits = {"train.batch_size": 8}
    arms = {"b1": arm("configs/baselines.py:tiny", fits), "b2": arm("configs/baselines.py:tiny", {"train.steps": 4, **fits})}
    return experiment("unit", arms, schemes="image,object", protocols="honest", k=3, folds="0")
"""


def test_command_carries_records_in_and_out(tmp_path):
    config_file = tmp_path / "unit.py"
    config_file.write_text(BASELINE_EXPERIMENT_FILE)
    sweep(baseline_experiment(folds="0"), tmp_path / "old", FakeTrainer())
    carried.send_out(baseline_experiment(folds="0"), tmp_path / "old", tmp_path / "kept")
    done = command(f"--config={config_file}", f"--workdir={tmp_path / 'new'}", "--aggregate_only",
                   f"--records_from={tmp_path / 'kept'}", f"--records_to={tmp_path / 'kept2'}")
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"4 fold records copied from {tmp_path / 'kept'} into {tmp_path / 'new'}" in done.stdout
    assert "aggregated 4 folds" in done.stdout and "(0 not run yet)" in done.stdout
    assert f"4 fold records copied from {tmp_path / 'new'} into {tmp_path / 'kept2'}" in done.stdout
    assert len(list((tmp_path / "kept2").rglob(records.FOLD_FILE))) == 4
    missing = command(f"--config={config_file}", f"--workdir={tmp_path / 'new'}", "--aggregate_only",
                      f"--records_from={tmp_path / 'nowhere'}")
    assert missing.returncode == 1 and "--records_from folder" in missing.stderr


def test_a_stopped_sweep_still_carries_out_the_folds_it_finished(tmp_path, monkeypatch, capsys):
    from kosmos_jax.experiments import __main__ as command_module

    config_file = tmp_path / "unit.py"
    config_file.write_text(BASELINE_EXPERIMENT_FILE)
    stopping = FakeTrainer(stop_at=("honest", "object", 0))  # b1's image fold finishes, its object fold stops
    real = runner.run_experiment
    monkeypatch.setattr(runner, "run_experiment", lambda config, root, command: real(
        config, root, train=stopping, evaluate=fake_evaluate, command=command, say=lambda line: None))
    code = command_module.main([f"--config={config_file}", f"--workdir={tmp_path / 'work'}",
                                f"--records_to={tmp_path / 'kept'}"])
    out, err = capsys.readouterr()
    assert code == 3 and "stopped: b1 honest-object fold 0: training stopped at step 1" in err
    assert f"1 fold records copied from {tmp_path / 'work'} into {tmp_path / 'kept'}" in out
    assert [p.parent.name for p in (tmp_path / "kept").rglob(records.FOLD_FILE)] == ["honest-image-fold0"]


class SigtermBeforeTraining(FakeTrainer):
    """A SIGTERM that arrives before the trainer puts in its own handler (e.g. while the fold's dataset is built)."""

    def __init__(self, at):
        super().__init__()
        self.at = at

    def __call__(self, config, workdir):
        if (config.data.protocol, config.data.scheme, config.data.fold) == self.at:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1)  # the handler runs in this thread at once; reaching the next line is a failure
            raise AssertionError("the SIGTERM did not stop the sweep")
        return super().__call__(config, workdir)


def test_a_sigterm_outside_a_training_stops_the_sweep_and_the_finished_folds_are_carried_out(tmp_path, monkeypatch,
                                                                                             capsys):
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers can only be set in the main thread")
    from kosmos_jax.experiments import __main__ as command_module

    config_file = tmp_path / "unit.py"
    config_file.write_text(BASELINE_EXPERIMENT_FILE)
    stopping = SigtermBeforeTraining(at=("honest", "object", 0))  # b1's image fold finishes, its object fold is hit
    real = runner.run_experiment
    monkeypatch.setattr(runner, "run_experiment", lambda config, root, command: real(
        config, root, train=stopping, evaluate=fake_evaluate, command=command, say=lambda line: None))

    def ignored(signum, frame):  # in place of the default action, so that a sweep that misses the signal fails here
        pass

    original = signal.signal(signal.SIGTERM, ignored)
    try:
        code = command_module.main([f"--config={config_file}", f"--workdir={tmp_path / 'work'}",
                                    f"--records_to={tmp_path / 'kept'}"])
        after = signal.getsignal(signal.SIGTERM)
    finally:
        signal.signal(signal.SIGTERM, original)
    out, err = capsys.readouterr()
    assert code == 3 and "stopped: SIGTERM outside a training" in err
    assert f"1 fold records copied from {tmp_path / 'work'} into {tmp_path / 'kept'}" in out
    assert [p.parent.name for p in (tmp_path / "kept").rglob(records.FOLD_FILE)] == ["honest-image-fold0"]
    assert after is ignored


def test_slurm_array_aggregate_step():
    env = {"PATH": os.environ["PATH"], "DRY_RUN": "1", "AGGREGATE": "1"}
    done = subprocess.run(["bash", str(REPO / "launch" / "slurm_array.sbatch"), "configs/experiments/table1.py:paper",
                           "runs/t1", "--config.init_from=/k2"], capture_output=True, text=True, env=env, cwd=REPO,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[1] == (
        f"srun --ntasks=1 {REPO}/.venv/bin/python -m kosmos_jax.experiments --config=configs/experiments/table1.py:paper "
        "--workdir=runs/t1 --aggregate_only --config.init_from=/k2")

# -- end to end ------------------------------------------------------------------------------------


@pytest.mark.slow
def test_tiny_sweep_end_to_end(tmp_path):
    """Two folds of the tiny KOSMOS-E and the tiny GR-ConvNet (2 steps each) on synthetic scenes:
    trained, scored (KOSMOS-E beside the no-learning predictors), aggregated; the same command again
    trains nothing."""
    overrides = {"data.root": str(tmp_path / "data"), "train.steps": 2, "train.checkpoint_every": 2,
                 "train.eval_batches": 1, "optimizer.warmup_steps": 1}
    baseline = {"data.root": str(tmp_path / "data"), "train.steps": 2, "train.checkpoint_every": 2,
                "train.batch_size": 8}  # the suite's 8 fake devices
    config = experiment("tiny", {"kosmos_e": arm("configs/kosmos_e.py:tiny", overrides, protocols="honest"),
                                 "grconvnet": arm("configs/baselines.py:tiny", baseline)},
                        schemes="image", protocols="honest,public", k=3, folds="0,1")
    calls = []

    def counted(config_, workdir):
        calls.append(workdir)
        return runner.default_train(config_, workdir)

    summary = runner.run_experiment(config, tmp_path / "w", train=counted, command="pytest", say=lambda line: None)
    assert summary["trained"] == 5 and summary["failed"] == [] and len(calls) == 5
    for fold in (0, 1):
        record = records.read_record(tmp_path / "w" / "kosmos_e" / f"honest-image-fold{fold}")
        evaluated = json.loads((tmp_path / "w" / "kosmos_e" / f"honest-image-fold{fold}" / "eval" / "2" / "results.json").read_text())
        assert record["accuracy"] == evaluated["accuracy"] and record["eval"]["step"] == 2
        assert record["training_examples"] > 0 and record["no_learning"]["scores"]["gt_mean_oracle"]["instructions"] == (
            evaluated["instructions"])
    baseline_record = records.read_record(tmp_path / "w" / "grconvnet" / "honest-image-fold1")
    assert baseline_record["task"] == "baseline" and baseline_record["no_learning"] is None
    assert 0 <= baseline_record["accuracy"] <= 100 and baseline_record["training_examples"] > 0
    public = records.read_record(tmp_path / "w" / "grconvnet" / "public-image-fold0")
    trained = runner.records.run_description(tmp_path / "w" / "grconvnet" / "public-image-fold0")["config"]
    assert public["eval"]["protocol"] == "public" and trained["data"]["protocol"] == "public"
    assert 0 <= public["accuracy"] <= 100 and public["no_learning"] is None
    rows = {(r["arm"], r["protocol"]): r for r in summary["results"]["rows"]}
    assert set(rows) == {(a, "honest") for a in ("kosmos_e", "grconvnet", "image_centre", "gt_mean_oracle")} | {
        ("grconvnet", "public")}
    assert all(rows[(a, "honest")]["n_folds"] == 2 for a in ("kosmos_e", "grconvnet", "image_centre"))
    assert rows[("grconvnet", "public")]["n_folds"] == 1
    again = runner.run_experiment(config, tmp_path / "w", train=counted, say=lambda line: None)
    assert again["skipped"] == 5 and len(calls) == 5
