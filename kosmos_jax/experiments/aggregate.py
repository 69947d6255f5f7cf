"""Fold records -> rows (per arm, protocol and scheme: fold accuracies, mean +- std, n folds, per kind
and per scene) -> WORKDIR/results.json and WORKDIR/table.md (and the data-size plot when asked).

    results = write_results(config, workdir, command)

Aggregates every record of the experiment found under WORKDIR, whichever process wrote it (the
folds of a SLURM array meet here); the chosen folds (config.folds) not recorded yet are listed as
"missing". The std is over
folds (numpy's, ddof=0, as scoring.fold_scores reports the baselines). The no-learning predictors
get rows of their own, from the KOSMOS-E arms' records; arms whose test instructions are the same
on every fold (records' digests) share them, so a table shows each distinct test set once.
"""

from __future__ import annotations

import datetime
import pathlib

import numpy as np

from kosmos_jax.experiments import data_size, records, spec

DISPLAY = {"image_centre": "image centre", "gt_mean_oracle": "ground-truth mean (oracle)"}
SCHEME_LABEL = {"image": "IW", "object": "OW"}


def summary(values) -> dict:
    values = [float(v) for v in values]
    if not values:
        return {"mean": None, "std": None, "n_folds": 0}
    return {"mean": round(float(np.mean(values)), 4), "std": round(float(np.std(values)), 4), "n_folds": len(values)}


def grouped(records_: list[dict], field: str) -> dict:
    """{group: summary + fold_accuracies} of each kind (or scene) over the folds that have it."""
    names = sorted({name for r in records_ for name in r.get(field) or {}})
    out = {}
    for name in names:
        accuracies = [r[field][name]["accuracy"] for r in records_ if name in (r.get(field) or {})]
        out[name] = {**summary(accuracies), "fold_accuracies": accuracies}
    return out


def found_records(config, root) -> tuple[dict, list[str]]:
    """({run: record} of every recorded fold of the experiment, whichever folds and arms this
    invocation chose; the names of the chosen runs (config.folds, run_arms) not recorded yet)."""
    chosen = set(spec.runs(config))
    found, missing = {}, []
    for run in spec.runs(config, every=True):
        record = records.read_record(run.workdir(root))
        if record is not None:
            found[run] = record
        elif run in chosen:
            missing.append(run.name)
    return found, missing


def trained_rows(config, found: dict) -> list[dict]:
    cells: dict[tuple, list[dict]] = {}
    for run, record in found.items():
        cells.setdefault((run.arm, run.protocol, run.scheme), []).append(record)
    rows = []
    for (arm, protocol, scheme), group in cells.items():
        group.sort(key=lambda r: r["fold"])
        accuracies = [r["accuracy"] for r in group]
        examples = [r["training_examples"] for r in group]
        rows.append({
            "experiment": config.name, "arm": arm, "kind": "trained", "series": config.arms[arm].series,
            "protocol": protocol, "scheme": scheme, "folds": [r["fold"] for r in group],
            "fold_accuracies": accuracies, **summary(accuracies),
            "by_kind": grouped(group, "by_kind"), "by_scene": grouped(group, "by_scene"),
            "training_examples": examples, "training_examples_mean": float(np.mean(examples)),
            "wall_seconds": [r["seconds"]["total"] for r in group],
            "wall_seconds_total": round(sum(r["seconds"]["total"] for r in group), 1),
            "machines": sorted({records.machine_text(r["machine"]) for r in group}),
            "commands": sorted({r["command"] for r in group if r["command"]}),
        })
    return rows


def no_learning_rows(config, found: dict) -> list[dict]:
    """Rows of the no-learning predictors: one per distinct set of test instructions per column."""
    tests: dict[tuple, dict[str, dict[int, dict]]] = {}  # (protocol, scheme) -> arm -> fold -> record
    for run, record in found.items():
        if record.get("no_learning"):
            tests.setdefault((run.protocol, run.scheme), {}).setdefault(run.arm, {})[run.fold] = record
    rows = []
    for (protocol, scheme), by_arm in tests.items():
        groups: dict[tuple, list[str]] = {}
        for arm, folds in by_arm.items():
            key = tuple(sorted((fold, r["no_learning"]["tests"]) for fold, r in folds.items()))
            groups.setdefault(key, []).append(arm)
        for key, arms in groups.items():
            folds = by_arm[arms[0]]
            for predictor in DISPLAY:
                group = [folds[f]["no_learning"]["scores"][predictor] for f, _ in key]
                accuracies = [g["accuracy"] for g in group]
                rows.append({
                    "experiment": config.name, "arm": predictor, "kind": "no_learning", "tests_of": arms,
                    "protocol": protocol, "scheme": scheme, "folds": [f for f, _ in key],
                    "fold_accuracies": accuracies, **summary(accuracies),
                    "by_kind": grouped(group, "by_kind"), "by_scene": grouped(group, "by_scene"),
                    "instructions": [g["instructions"] for g in group],
                })
    return rows


def cell(row: dict | None, figures: dict | None = None) -> str:
    figures = figures if figures is not None else row
    if not figures or not figures.get("n_folds"):
        return "-"
    return f"{figures['mean']:.2f} +- {figures['std']:.2f} ({figures['n_folds']})"


def row_label(row: dict, several_test_sets: bool) -> str:
    if row["kind"] == "trained":
        return row["arm"]
    label = DISPLAY[row["arm"]]
    return f"{label} (tests of {', '.join(row['tests_of'])})" if several_test_sets else label


def markdown(results: dict, config) -> str:
    rows = results["rows"]
    columns = [(p, s) for p in spec.parse_protocols(config.protocols)
               for s in spec.parse_names(config.schemes, spec.SCHEMES, "scheme")]
    several = len({tuple(r["tests_of"]) for r in rows if r["kind"] == "no_learning"}) > 1
    labels = list(dict.fromkeys(row_label(r, several) for r in rows))
    at = {(row_label(r, several), r["protocol"], r["scheme"]): r for r in rows}
    lines = [f"# {config.name}: grasp accuracy in percent, mean +- std over folds (n folds)", "",
             "| arm | " + " | ".join(f"{SCHEME_LABEL[s]} {p}" for p, s in columns) + " |",
             "|---|" + "---:|" * len(columns)]
    lines += [f"| {label} | " + " | ".join(cell(at.get((label, p, s))) for p, s in columns) + " |" for label in labels]
    for protocol, scheme in columns:
        column = [r for r in rows if (r["protocol"], r["scheme"]) == (protocol, scheme)]
        kinds = sorted({k for r in column for k in r["by_kind"]})
        scenes = sorted({k for r in column for k in r["by_scene"]})
        if kinds in ([], ["non"]) and scenes in ([], ["single"]):
            continue
        lines += ["", f"## {SCHEME_LABEL[scheme]} {protocol}: per instruction kind and scene", "",
                  "| arm | " + " | ".join(kinds + [f"scene {s}" for s in scenes]) + " |",
                  "|---|" + "---:|" * (len(kinds) + len(scenes))]
        for r in column:
            figures = [cell(None, r["by_kind"].get(k)) for k in kinds] + [cell(None, r["by_scene"].get(s)) for s in scenes]
            lines.append(f"| {row_label(r, several)} | " + " | ".join(figures) + " |")
    trained = [r for r in rows if r["kind"] == "trained"]
    machines = sorted({m for r in trained for m in r["machines"]})
    commands = sorted({c for r in trained for c in r["commands"]})
    lines += ["", "Rectangle metric (angle within 30 degrees, IoU above 0.25); a fold's figure is the percentage of its "
              "test instructions answered correctly; std over folds (ddof 0). IW: image-wise folds, OW: object-wise; "
              "protocols as in DESIGN.md section 3. No-learning rows are scored on the same test instructions as the "
              "KOSMOS-E arms named beside them (or all of them).",
              f"Wall time (training and evaluation, all folds): {sum(r['wall_seconds_total'] for r in trained):.0f} s.",
              "Machines: " + ("; ".join(machines) or "-"), "Commands: " + ("; ".join(f"`{c}`" for c in commands) or "-")]
    if results["missing"]:
        lines.append(f"Folds not run yet ({len(results['missing'])}): {', '.join(results['missing'])}.")
    return "\n".join(lines) + "\n"


def write_results(config, root, command: str = "") -> dict:
    """Aggregate the records under `root` into results.json and table.md (and the data-size plot)."""
    root = pathlib.Path(root)
    found, missing = found_records(config, root)
    results = {"experiment": config.name, "command": command, "machine": records.machine(),
               "written_at": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
               "rows": trained_rows(config, found) + no_learning_rows(config, found), "missing": missing,
               "config": config.to_dict()}
    records.write_json(root / "results.json", results)
    (root / "table.md").write_text(markdown(results, config))
    if config.data_size_plot:
        data_size.write(root, results["rows"])
    return results
