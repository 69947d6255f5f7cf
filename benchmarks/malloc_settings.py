"""glibc's malloc settings against each other on a training run: seconds a step, page faults, system time.

    .venv/bin/python benchmarks/malloc_settings.py [--model demo|grconvnet_rgbd] [--data_root demo_out/datasets]
        [--steps 60] [--rounds 2] [--out RECORD.json]

`--model=demo` (the default) trains `configs/kosmos_e.py:demo_grounded224_consensus` from make demo's start,
`--model=grconvnet_rgbd` the GR-ConvNet baseline on the Cornell photos of ../shared/data. Each round trains it for
`--steps` steps in a fresh process under each setting in turn, the order reversed every other round (so that a
neighbour's load falls on all alike), and reads the median
seconds a step after the first `--skip` steps from the run's metrics.jsonl; the process's page faults and system
time come from getrusage. The settings change where freed memory goes, never a number the step computes: the
record holds each run's last loss, which must agree. `--data_root` is a folder holding make demo's dataset
(`make demo` writes demo_out/datasets); the demo runs reuse it, so nothing is built.

Ours: make demo's setting (the Makefile's KEEP_FREED). Peer: huge pages alone (the Makefile's default setting).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import re
import resource
import statistics
import subprocess
import sys
import tempfile

from kosmos_jax.experiments.spec import DEMO_START, REPO


def makefile_setting(pattern: str) -> str:
    """A value the Makefile assigns, so that the benchmark times the settings make uses."""
    found = re.search(pattern, (REPO / "Makefile").read_text(), re.M)
    if found is None:
        raise SystemExit(f"the Makefile has no line matching {pattern!r}")
    return found.group(1)


# make demo's setting and every other target's
SETTINGS = {"keep_freed": makefile_setting(r"^KEEP_FREED := (\S+)$"),
            "huge_pages": makefile_setting(r"^export GLIBC_TUNABLES \?= (\S+)$")}
CORNELL = REPO.parent / "shared" / "data" / "cornell"


def training_flags(model: str, data_root: pathlib.Path) -> list[str]:
    if model == "demo":
        return ["--config=configs/kosmos_e.py:demo_grounded224_consensus", f"--config.init_from={DEMO_START}",
                f"--config.data.root={data_root}", "--config.train.grasp_eval_at_end=False",
                "--config.optimizer.warmup_steps=10"]
    return ["--config=configs/baselines.py:grconvnet_rgbd", "--config.data.source=cornell"]


def one_run(tunables: str, flags: list[str], steps: int, skip: int) -> dict:
    with tempfile.TemporaryDirectory() as workdir:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        done = subprocess.run(
            [sys.executable, "-m", "kosmos_jax.train", *flags, f"--workdir={workdir}/run",
             f"--config.train.steps={steps}", f"--config.train.eval_every={steps + 1}",
             f"--config.train.checkpoint_every={steps + 1}"],
            cwd=REPO, env={**os.environ, "GLIBC_TUNABLES": tunables}, capture_output=True, text=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if done.returncode:
            raise SystemExit(f"training under {tunables!r} failed:\n{done.stderr[-3000:]}")
        rows = [json.loads(line) for line in (pathlib.Path(workdir) / "run" / "metrics.jsonl").read_text().splitlines()]
    timed = [row for row in rows if "step_s" in row]
    return {"step_s": statistics.median(row["step_s"] for row in timed if row["step"] > skip),
            "last_loss": timed[-1]["loss"], "minor_page_faults": after.ru_minflt - before.ru_minflt,
            "system_s": round(after.ru_stime - before.ru_stime, 2), "user_s": round(after.ru_utime - before.ru_utime, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=("demo", "grconvnet_rgbd"), default="demo")
    parser.add_argument("--data_root", default="demo_out/datasets", help="make demo's datasets (--model=demo)")
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--skip", type=int, default=20, help="steps left out of the median (compile, warm-up)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", help="write the record (JSON) here")
    args = parser.parse_args()
    data_root = (REPO / args.data_root).resolve()
    if args.model == "demo" and not any(data_root.glob("instruct_grasp/*/*/dataset_info.json")):
        raise SystemExit(f"{data_root} holds no built dataset: run make demo first, or give --data_root")
    if args.model == "grconvnet_rgbd" and not CORNELL.is_dir():
        raise SystemExit(f"{CORNELL} is missing: the baseline trains on the shared Cornell photos")
    if args.skip < 0 or args.steps < args.skip + 10:
        raise SystemExit(f"--steps ({args.steps}) must exceed --skip ({args.skip}) by at least 10: the trainer logs "
                         "a row every 10 steps")
    runs = {name: [] for name in SETTINGS}
    flags = training_flags(args.model, data_root)
    for round_number in range(args.rounds):
        for name, tunables in list(SETTINGS.items())[:: -1 if round_number % 2 else 1]:
            runs[name].append(one_run(tunables, flags, args.steps, args.skip))
            print(f"round {round_number + 1}, {name}: {runs[name][-1]}", flush=True)
    losses = {run["last_loss"] for named in runs.values() for run in named}
    if len(losses) != 1:
        raise SystemExit(f"the settings changed the training itself: last losses {sorted(losses)}")
    ours, peer = (statistics.median(run["step_s"] for run in runs[name]) for name in SETTINGS)
    print(f"keep_freed {ours:.4f} s a step, huge_pages {peer:.4f} s a step: {peer / ours:.3f}x")
    record = {"model": args.model, "settings": SETTINGS, "steps": args.steps, "skip": args.skip, "runs": runs,
              "median_step_s": {"keep_freed": ours, "huge_pages": peer}, "speedup": peer / ours,
              "data": str(args.data_root) if args.model == "demo" else str(CORNELL)}
    if args.out:
        pathlib.Path(args.out).write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
