"""A KOSMOS-E run's parameters as a self-contained folder in transformers' KOSMOS-2 layout.

    python -m kosmos_jax.workdir.export --workdir=runs/demo --out=exported/demo [--step=N]
    python -m kosmos_jax.predict --pretrained=exported/demo --image=photo.png
    export_pretrained("runs/demo", "exported/demo")           # the newest checkpoint
    GraspPredictor.from_pretrained("exported/demo")

Writes config.json and model.safetensors (models.weights.save_pretrained) from the parameters of
one checkpoint (restored alone, on one device), the run's tokenizer.model, and kosmos_e.json (the
run's text format, tokenizer scheme, protocol and grasp size, and the starts it was trained from:
workdir.pretrained). A model whose
connector adds a grid code is written with this project's extended config.json, which transformers
refuses rather than compute another model; training starts from any such folder with
--config.init_from=FOLDER.
"""

from __future__ import annotations

import dataclasses
import pathlib
import shutil
import sys

import jax
from absl import flags
from flax import nnx

from kosmos_jax import commands
from kosmos_jax.models import weights
from kosmos_jax.models.kosmos2 import abstract_model, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_decoding import configured_windows
from kosmos_jax.workdir.sizes import run_grasp_size
from kosmos_jax.scoring.model_answers import fixed_streams
from kosmos_jax.workdir.files import TOKENIZER_FILE
from kosmos_jax.workdir.pretrained import folder_description, start_chain, write_description
from kosmos_jax.workdir.run import open_run


def export_pretrained(workdir, folder, step: int | None = None, max_shard_bytes: int | None = None) -> int:
    """Write checkpoint `step` (None: the newest) of the run in `workdir` to `folder`, which must be
    new or empty (an older export's shards would mix with these); returns the step."""
    check_new_folder(folder)
    run = open_run(workdir)
    step, params = run.params(step, one_device_mesh())
    write_exported(run, step, params, folder, max_shard_bytes)
    return step


def check_new_folder(folder) -> None:
    folder = pathlib.Path(folder)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise FileExistsError(f"{folder} exists and is not an empty folder; export to a new one")


def one_device_mesh():
    return make_mesh(1, 1, 1, devices=jax.devices()[:1])


def write_exported(run, step: int, params, folder, max_shard_bytes: int | None = None, **described) -> None:
    """`params` (laid out as the run's model's) written to `folder` with the run's tokenizer and a kosmos_e.json
    that describes `run` at `step`, plus the `described` fields."""
    folder = pathlib.Path(folder)
    graphdef, _, rest = split_model(abstract_model(run.model_config))
    weights.save_pretrained(nnx.merge(graphdef, params, fixed_streams(rest)), folder, max_shard_bytes,
                            extensions=True)
    shutil.copyfile(run.workdir / TOKENIZER_FILE, folder / TOKENIZER_FILE)
    write_description(folder, dict(folder_description(
        dataclasses.asdict(run.format_config), run.tokenizer.scheme, run.tokenizer.numbers, run.protocol,
        run_grasp_size(run), step, run.workdir.resolve(), **configured_windows(run.config),
        started_from=start_chain(run.description.get("init"))), **described))


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("string", "workdir", None, "a KOSMOS-E training run's folder")
    define("string", "out", None, "the folder to write (new or empty)")
    define("integer", "step", None, "the checkpoint to export (default: the newest)")
    flags.mark_flags_as_required(["workdir", "out"], flag_values=flag_values)


def main(argv=None) -> int:
    return commands.run_command(define_flags, export_command, argv, prog="python -m kosmos_jax.workdir.export",
                                doc=__doc__)


def export_command(args) -> int:
    try:
        step = export_pretrained(args.workdir, args.out, args.step)
    except (OSError, ValueError) as error:  # workdir.files.RunError is a FileNotFoundError
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"step {step} of {args.workdir} written to {args.out}; "
          f"predict with: python -m kosmos_jax.predict --pretrained={args.out} --image=PHOTO")
    return 0


if __name__ == "__main__":
    sys.exit(main())
