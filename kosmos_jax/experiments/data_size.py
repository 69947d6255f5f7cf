"""Fig. 6: accuracy against training-data size, from the aggregated rows of the trained arms.

    write(workdir, rows)    # WORKDIR/data_size.json (the plotted points) and WORKDIR/data_size.png

A point is an arm that belongs to a series (arm(..., series="augmentations", "photos", or both
comma-separated: one arm may sit on two lines) under one protocol and scheme: x the mean of its folds' training examples (each the train split's example
count of the run), y the mean accuracy over folds, the error bar the std over folds. One line per
(series, scheme), one panel per protocol, x on a log scale.
"""

from __future__ import annotations

import json
import pathlib

from matplotlib.figure import Figure

SCHEME_LABEL = {"image": "IW", "object": "OW"}


def points(rows: list[dict]) -> list[dict]:
    chosen = [r for r in rows if r["kind"] == "trained" and r.get("series") and r["n_folds"]]
    out = [{"series": series, "arm": r["arm"], "protocol": r["protocol"], "scheme": r["scheme"],
            "training_examples": r["training_examples_mean"], "training_examples_per_fold": r["training_examples"],
            "accuracy_mean": r["mean"], "accuracy_std": r["std"], "n_folds": r["n_folds"],
            "fold_accuracies": r["fold_accuracies"]} for r in chosen for series in r["series"].split(",")]
    return sorted(out, key=lambda p: (p["protocol"], p["series"], p["scheme"], p["training_examples"]))


def lines(chosen: list[dict]) -> dict[tuple, list[dict]]:
    """{(protocol, series, scheme): its points by training examples}."""
    out: dict[tuple, list[dict]] = {}
    for point in chosen:
        out.setdefault((point["protocol"], point["series"], point["scheme"]), []).append(point)
    return out


def figure(chosen: list[dict]) -> Figure:
    if not chosen:
        raise ValueError("no arm with a data-size series has a finished fold: nothing to plot")
    protocols = sorted({p["protocol"] for p in chosen})
    fig = Figure(figsize=(5.5 * len(protocols), 4.2), layout="constrained")
    axes = fig.subplots(1, len(protocols), squeeze=False)[0]
    for ax, protocol in zip(axes, protocols):
        for (line_protocol, series, scheme), line in lines(chosen).items():
            if line_protocol != protocol:
                continue
            ax.errorbar([p["training_examples"] for p in line], [p["accuracy_mean"] for p in line],
                        yerr=[p["accuracy_std"] for p in line], marker="o", capsize=3,
                        label=f"{SCHEME_LABEL[scheme]}, {series}")
        ax.set_xscale("log")
        ax.set_xlabel("training examples")
        ax.set_ylabel("grasp accuracy (%)")
        ax.set_title(f"{protocol} protocol (mean +- std over folds)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    return fig


def write(root, rows: list[dict]) -> tuple[pathlib.Path, pathlib.Path]:
    root = pathlib.Path(root)
    chosen = points(rows)
    data = root / "data_size.json"
    data.write_text(json.dumps({"x": "training examples (mean over folds of the train split's example count)",
                                "y": "grasp accuracy, percent (mean +- std over folds)", "points": chosen}, indent=1) + "\n")
    plot = root / "data_size.png"
    if chosen:
        figure(chosen).savefig(plot, dpi=120)
    return data, plot
