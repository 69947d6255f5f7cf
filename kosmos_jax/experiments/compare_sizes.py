"""Fig. 6 of several data-size sweeps on one plot: e.g. a pretrained start beside the from-scratch recipe.

    python -m kosmos_jax.experiments.compare_sizes --out=results/data_size_scratch/compare.png \
        --sweeps="pretrained start=results/data_size_pretrained/results.json,from scratch=results/data_size_scratch/results.json"

Each sweep is LABEL=PATH, PATH an experiment's results.json (the runner's aggregate of a
data_size_plot experiment). Every series is drawn as data_size.py draws it, named "LABEL: series";
a no-learning reference point is drawn once where the sweeps scored the same tests (the same point),
on its own sweep's line where they did not. Writes OUT (a PNG) and OUT with the suffix .json
(the plotted points and references, each point with its sweep's label). A sweep whose arms share
a name with another's but trained on a different number of examples is named in a printed note:
its points are then not the same data.
"""

from __future__ import annotations

import json
import pathlib
import sys

from kosmos_jax import commands
from kosmos_jax.experiments import data_size

PROG = "python -m kosmos_jax.experiments.compare_sizes"


def parse_sweeps(specs: list[str]) -> list[tuple[str, pathlib.Path]]:
    sweeps = []
    for spec in specs:
        label, separator, path = spec.partition("=")
        if not separator or not label.strip() or not path.strip():
            raise commands.UsageError(f"a sweep is LABEL=PATH to a results.json, got {spec!r}")
        sweeps.append((label.strip(), pathlib.Path(path.strip())))
    labels = [label for label, _ in sweeps]
    if len(set(labels)) != len(labels):
        raise commands.UsageError(f"two sweeps share a label: {labels}")
    return sweeps


def read_rows(path: pathlib.Path) -> list[dict]:
    try:
        results = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        raise commands.UsageError(f"cannot read {path}: {commands.one_line(error)}") from None
    if not isinstance(results, dict) or "rows" not in results:
        raise commands.UsageError(f"{path} is not an experiment's results.json (no 'rows')")
    return results["rows"]


def of_sweep(label: str, point: dict) -> dict:
    return {**point, "series": f"{label}: {point['series']}", "sweep": label}


def combined(sweeps: list[tuple[str, list[dict]]]) -> tuple[list[dict], list[dict]]:
    """(points, references) of every sweep, each on its sweep's lines; a reference point that an earlier
    sweep already has (the same tests scored) is left to that sweep's line."""
    chosen, reference_points, seen = [], [], []
    for label, rows in sweeps:
        points = data_size.points(rows)
        for reference in data_size.references(rows, points):
            if reference not in seen:
                seen.append(reference)
                reference_points.append(of_sweep(label, reference))
        chosen += [of_sweep(label, point) for point in points]
    if not chosen:
        raise commands.UsageError("no sweep has an arm with a data-size series and a finished fold: nothing to plot")
    return chosen, reference_points


def different_data(sweeps: list[tuple[str, list[dict]]]) -> list[str]:
    """Notes on arms of the same name, protocol and scheme whose training examples differ between sweeps."""
    seen, notes = {}, []
    for label, rows in sweeps:
        for row in rows:
            if row["kind"] != "trained" or not row.get("series"):
                continue
            key = (row["arm"], row["protocol"], row["scheme"])
            if key in seen and seen[key][1] != row["training_examples"]:
                notes.append(f"{row['arm']} ({row['protocol']}, {row['scheme']}) trains on {seen[key][1]} examples "
                             f"in {seen[key][0]!r} and {row['training_examples']} in {label!r}")
            seen.setdefault(key, (label, row["training_examples"]))
    return notes


def define_flags(flag_values) -> None:
    define = commands.definer(flag_values)
    define("list", "sweeps", None, "LABEL=PATH pairs, PATH an experiment's results.json, comma-separated")
    define("string", "out", None, "the PNG to write (its .json twin beside it)")


def compare_command(args) -> None:
    if not args.sweeps or not args.out:
        raise commands.UsageError("give --sweeps=LABEL=PATH,... and --out=FILE.png")
    out = pathlib.Path(args.out)
    if out.suffix != ".png":
        raise commands.UsageError(f"--out must name a .png file, got {out}")
    paths = parse_sweeps(args.sweeps)
    sweeps = [(label, read_rows(path)) for label, path in paths]
    for note in different_data(sweeps):
        print(f"note: {note}")
    chosen, reference_points = combined(sweeps)
    out.parent.mkdir(parents=True, exist_ok=True)
    data_size.figure(chosen, reference_points).savefig(out, dpi=120)
    out.with_suffix(".json").write_text(json.dumps({
        "sweeps": {label: str(path) for label, path in paths}, **data_size.plot_data(chosen, reference_points)},
        indent=1) + "\n")
    print(f"wrote {out} and {out.with_suffix('.json')}: {len(chosen)} points from {len(sweeps)} sweeps")


def main(argv=None) -> int:
    return commands.run_command(define_flags, compare_command, argv, prog=PROG, doc=__doc__)


if __name__ == "__main__":
    sys.exit(main())
