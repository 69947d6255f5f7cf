"""Fig. 6: accuracy against training-data size, from the aggregated rows of the trained arms.

    write(workdir, rows)    # WORKDIR/data_size.json (the plotted points) and WORKDIR/data_size.png

A point is an arm that belongs to a series (arm(..., series="augmentations", "photos", or both
comma-separated: one arm may sit on two lines) under one protocol and scheme: x the mean of its folds' training examples (each the train split's example
count of the run), y the mean accuracy over folds, the error bar the std over folds. One line per
(series, scheme), one panel per protocol, x on a log scale with plain tick labels. A series of one
point whose point another line of its scheme draws is left out (it would be a legend entry with
nothing of its own to show). The no-learning predictors are drawn as reference lines: each at the
x of the arms whose test set it scored (`tests_of`), so a reference follows the test set as the
photos series changes it.
"""

from __future__ import annotations

import json
import pathlib

from matplotlib import ticker
from matplotlib.figure import Figure

SCHEME_LABEL = {"image": "IW", "object": "OW"}
REFERENCE_STYLE = {"image_centre": ("image centre", ":"), "gt_mean_oracle": ("oracle (ground-truth mean)", "--")}


def points(rows: list[dict]) -> list[dict]:
    chosen = [r for r in rows if r["kind"] == "trained" and r.get("series") and r["n_folds"]]
    out = [{"series": series, "arm": r["arm"], "protocol": r["protocol"], "scheme": r["scheme"],
            "training_examples": r["training_examples_mean"], "training_examples_per_fold": r["training_examples"],
            "accuracy_mean": r["mean"], "accuracy_std": r["std"], "n_folds": r["n_folds"],
            "fold_accuracies": r["fold_accuracies"]} for r in chosen for series in r["series"].split(",")]
    return sorted(out, key=lambda p: (p["protocol"], p["series"], p["scheme"], p["training_examples"]))


def references(rows: list[dict], chosen: list[dict]) -> list[dict]:
    """The no-learning rows as points at the x of each plotted point (arm and series) whose test set they
    scored, sorted by x within each (protocol, predictor, scheme, series)."""
    out = [{"predictor": r["arm"], "protocol": r["protocol"], "scheme": r["scheme"], "series": p["series"],
            "arm": p["arm"], "training_examples": p["training_examples"], "accuracy_mean": r["mean"]}
           for r in rows if r["kind"] == "no_learning" and r["arm"] in REFERENCE_STYLE
           for p in chosen if p["arm"] in r.get("tests_of", []) and (p["protocol"], p["scheme"]) == (r["protocol"], r["scheme"])]
    return sorted(out, key=lambda p: (p["protocol"], p["predictor"], p["scheme"], p["series"], p["training_examples"]))


def lines(chosen: list[dict]) -> dict[tuple, list[dict]]:
    """{(protocol, series, scheme): its points by training examples}, less the one-point series whose
    point another line of the same protocol and scheme holds."""
    out: dict[tuple, list[dict]] = {}
    for point in chosen:
        out.setdefault((point["protocol"], point["series"], point["scheme"]), []).append(point)
    shown_elsewhere = lambda key, point: any(other[0] == key[0] and other[2] == key[2] and other != key and
                                             len(line) > 1 and point["arm"] in {p["arm"] for p in line}
                                             for other, line in out.items())
    return {key: line for key, line in out.items() if len(line) > 1 or not shown_elsewhere(key, line[0])}


def figure(chosen: list[dict], reference_points: list[dict] = ()) -> Figure:
    if not chosen:
        raise ValueError("no arm with a data-size series has a finished fold: nothing to plot")
    protocols = sorted({p["protocol"] for p in chosen})
    fig = Figure(figsize=(8.0 * len(protocols), 4.2), layout="constrained")
    axes = fig.subplots(1, len(protocols), squeeze=False)[0]
    for ax, protocol in zip(axes, protocols):
        for (line_protocol, series, scheme), line in lines(chosen).items():
            if line_protocol != protocol:
                continue
            ax.errorbar([p["training_examples"] for p in line], [p["accuracy_mean"] for p in line],
                        yerr=[p["accuracy_std"] for p in line], marker="o", capsize=3,
                        label=f"{SCHEME_LABEL[scheme]}, {series}")
        reference_lines: dict[tuple, list[dict]] = {}
        for point in reference_points:
            if point["protocol"] == protocol:
                reference_lines.setdefault((point["predictor"], point["scheme"], point["series"]), []).append(point)
        labelled = set()
        for (predictor, scheme, _), line in sorted(reference_lines.items()):
            name, style = REFERENCE_STYLE[predictor]
            label = None if (predictor, scheme) in labelled else f"{SCHEME_LABEL[scheme]}, {name}"
            labelled.add((predictor, scheme))
            ax.plot([p["training_examples"] for p in line], [p["accuracy_mean"] for p in line], linestyle=style,
                    color="0.35" if scheme == "image" else "0.65", linewidth=1.2, label=label)
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(ticker.FuncFormatter(lambda x, _: f"{x:,.0f}"))
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.set_xlabel("training examples")
        ax.set_ylabel("grasp accuracy (%)")
        folds = sorted({p["n_folds"] for p in chosen if p["protocol"] == protocol})
        spread = "one fold a point: no spread" if folds == [1] else f"mean +- std over {'/'.join(map(str, folds))} folds"
        ax.set_title(f"{protocol} protocol ({spread})")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small")
    return fig


def plot_data(chosen: list[dict], reference_points: list[dict]) -> dict:
    """What a plot's JSON twin holds: its axes, points and reference points."""
    return {"x": "training examples (mean over folds of the train split's example count)",
            "y": "grasp accuracy, percent (mean +- std over folds)", "points": chosen, "references": reference_points}


def write(root, rows: list[dict]) -> tuple[pathlib.Path, pathlib.Path]:
    root = pathlib.Path(root)
    chosen = points(rows)
    reference_points = references(rows, chosen)
    data = root / "data_size.json"
    data.write_text(json.dumps(plot_data(chosen, reference_points), indent=1) + "\n")
    plot = root / "data_size.png"
    if chosen:
        figure(chosen, reference_points).savefig(plot, dpi=120)
    return data, plot
