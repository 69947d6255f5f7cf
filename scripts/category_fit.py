"""How closely a run's single-photo accuracy by category follows what each target rule's mean or sample would score.

    python scripts/category_fit.py --means=results/answer_parts/target_means.synthetic-300-seed7.json \
        --parts=results/answer_parts/ck50_s0.parts300_seed7.json,...

--parts: records of scripts/answer_parts.py (one per seed; their hits pooled by category); --means: a record of
scripts/target_means.py on the same folder. Prints one JSON line: each category's pooled accuracy beside every
rule's `fitted` and `mean`, and Pearson's r over the categories for each of those.
"""

import argparse
import json
import sys

import numpy as np


def pooled_accuracy(parts_records: list[dict]) -> dict[str, float]:
    """{category: percent of its instructions answered right, over every record}."""
    hits, counts = {}, {}
    for record in parts_records:
        for category, tally in record["categories"].items():
            hits[category] = hits.get(category, 0) + sum(n for key, n in tally.items() if key.endswith(":hit"))
            counts[category] = counts.get(category, 0) + sum(tally.values())
    return {category: 100 * hits[category] / counts[category] for category in sorted(counts)}


def category_fit(means: dict, parts_records: list[dict]) -> dict:
    model = pooled_accuracy(parts_records)
    categories = sorted(model.keys() & means["categories"].keys())
    fit = {}
    for rule in means["rules"]:
        for score in ("fitted", "mean"):
            column = [means["categories"][category][rule][score] for category in categories]
            fit[f"{rule}.{score}"] = round(float(np.corrcoef([model[c] for c in categories], column)[0, 1]), 4)
    return {"categories": {c: {"model": round(model[c], 2), **{f"{rule}.{score}": means["categories"][c][rule][score]
                                                                for rule in means["rules"] for score in ("fitted", "mean")}}
                           for c in categories},
            "pearson_r": fit}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--means", required=True)
    parser.add_argument("--parts", required=True, help="comma-separated answer_parts records")
    args = parser.parse_args(argv)
    means = json.loads(open(args.means).read())
    parts = [json.loads(open(path).read()) for path in args.parts.split(",")]
    print(json.dumps(category_fit(means, parts)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
