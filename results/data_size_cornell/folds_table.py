"""Fig. 6 on Cornell, fold by fold: each arm's accuracy on every fold record in folds/ (photos right in brackets),
and the slope of accuracy on log2(views) within each fold (paired: one fold's four arms share its test photos).

    python results/data_size_cornell/folds_table.py      # from the repository root
"""
import json, pathlib, statistics, sys
root = pathlib.Path("results/data_size_cornell/folds")
arms = ["cornell_aug2", "cornell_aug4", "cornell_aug8", "cornell_aug16"]
for scheme in ("image", "object"):
    print(f"\n{scheme}-wise")
    print("| views | " + " | ".join(f"fold {k}" for k in range(5)) + " | mean +- std | n |")
    for arm in arms:
        cells, accs = [], []
        for k in range(5):
            f = root / arm / f"honest-{scheme}-fold{k}" / "fold.json"
            if f.exists():
                r = json.loads(f.read_text())
                n = r["by_scene"]["single"]["instructions"]
                right = round(r["accuracy"] * n / 100)
                cells.append(f"{r['accuracy']:.2f} ({right}/{n})"); accs.append(r["accuracy"])
            else:
                cells.append("not run")
        sd = statistics.pstdev(accs) if accs else 0
        print(f"| {arm} | " + " | ".join(cells) + f" | {statistics.mean(accs):.2f} +- {sd:.2f} | {len(accs)} |")

# the slope of accuracy on log2(views) within each fold (paired: each fold's own test photos)
print("\nslope per doubling of the views, points (least squares over the four arms of one fold)")
xs = [1, 2, 3, 4]
allslopes = []
for scheme in ("image", "object"):
    slopes = []
    for k in range(5):
        ys = []
        for arm in arms:
            f = root / arm / f"honest-{scheme}-fold{k}" / "fold.json"
            if f.exists():
                ys.append(json.loads(f.read_text())["accuracy"])
        if len(ys) == 4:
            mx, my = statistics.mean(xs), statistics.mean(ys)
            slopes.append(sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs))
    allslopes += slopes
    if len(slopes) > 1:
        print(f"{scheme}: " + ", ".join(f"{s:+.2f}" for s in slopes)
              + f"; mean {statistics.mean(slopes):+.2f} +- {statistics.stdev(slopes) / len(slopes) ** 0.5:.2f} (SE, n={len(slopes)})")
if len(allslopes) > 1:
    print(f"both: mean {statistics.mean(allslopes):+.2f} +- {statistics.stdev(allslopes) / len(allslopes) ** 0.5:.2f} (SE, n={len(allslopes)})")
