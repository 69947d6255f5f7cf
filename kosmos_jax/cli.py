"""`kosmos-grasp`: one command in front of the project's entry points.

    kosmos-grasp build       python -m kosmos_jax.dataset.build        a dataset: views, samples, array_record files
    kosmos-grasp train       python -m kosmos_jax.train                train a config (resumes a workdir)
    kosmos-grasp evaluate    python -m kosmos_jax.evaluate             score a run's decoded grasps (--overlays=N)
    kosmos-grasp experiments python -m kosmos_jax.experiments          train and evaluate over folds and data sizes
    kosmos-grasp plan        python -m kosmos_jax.train.compile --plan the TPU memory plan of a config
    kosmos-grasp predict     python -m kosmos_jax.predict              a grasp for your photo and instruction

`kosmos-grasp COMMAND ARGS` replaces itself with `python -m MODULE ARGS` (same interpreter), so each
command's flags, --help, exit status and signals are the module's own. Modules are named, not
imported, so this file imports nothing heavy and a command whose module is absent says so.
"""

from __future__ import annotations

import importlib.util
import os
import sys

PROG = "kosmos-grasp"
COMMANDS = {  # name: (module, arguments it always gets, what it does)
    "build": ("kosmos_jax.dataset.build", (), "build a dataset: views, samples, array_record files"),
    "train": ("kosmos_jax.train", (), "train a config in a workdir (resumes it)"),
    "evaluate": ("kosmos_jax.evaluate", (), "score a trained run's decoded grasps; --overlays=N draws them"),
    "experiments": ("kosmos_jax.experiments", (), "train and evaluate a config over folds and data sizes"),
    "plan": ("kosmos_jax.train.compile", ("--plan",), "compile a config for every planned TPU topology: memory"),
    "predict": ("kosmos_jax.predict", (), "a grasp for a photo and an instruction (--json, --out=overlay.png)"),
}


def usage() -> str:
    width = max(map(len, COMMANDS))
    rows = [f"  {name:<{width}}  {what}" for name, (_, _, what) in COMMANDS.items()]
    return (f"usage: {PROG} COMMAND [ARGS ...]\n\nKOSMOS-E in JAX: build data, train, evaluate, predict grasps.\n\n"
            "commands:\n" + "\n".join(rows) + f"\n\n`{PROG} COMMAND --help` shows a command's own flags.")


def command_line(name: str, arguments: list[str]) -> list[str]:
    """The `python -m` argv that `kosmos-grasp NAME ARGUMENTS` stands for."""
    module, fixed, _ = COMMANDS[name]
    return [sys.executable, "-m", module, *fixed, *arguments]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:
        print(usage(), file=sys.stderr)
        return 2
    if argv[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    name, arguments = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"error: unknown command {name!r}; commands: {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    module = COMMANDS[name][0]
    if importlib.util.find_spec(module) is None:
        print(f"error: {PROG} {name} runs {module}, which this installation does not have", file=sys.stderr)
        return 1
    line = command_line(name, arguments)
    sys.stdout.flush()
    os.execv(line[0], line)
    return 0  # not reached: execv replaces the process


if __name__ == "__main__":
    sys.exit(main())
