"""`python -m kosmos_jax.predict` (`kosmos-grasp predict`): one photo, one instruction, one grasp.

    python -m kosmos_jax.predict --workdir=runs/demo --image=photo.png --instruction="Grasp the red mug." \\
        [--step=N] [--out=overlay.png] [--json]
    python -m kosmos_jax.predict --pretrained=EXPORTED --image=...     # a run exported by kosmos_jax.workdir.export
    python -m kosmos_jax.predict --pretrained=FOLDER --tokenizer=sentencepiece.bpe.model --image=... [--scheme=fairseq]

Prints the grasp in the photo's pixels (one JSON line with --json) and, with --out, writes the
photo with the grasp drawn in red and the instruction beneath. Without --instruction the model is
asked with none (KOSMOS-E's NON kind). Bad input prints `error: ...` and exits 1; conversions of the
image (grey, RGBA, 16-bit) print `warning: ...`.
"""

from __future__ import annotations

import contextlib
import json
import math
import pathlib
import sys
import warnings

from absl import flags

from kosmos_jax import commands
from kosmos_jax.predict.errors import PredictError
from kosmos_jax.workdir.pretrained import FORMAT_FILE


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("string", "workdir", None, "a training run's folder (run.json, tokenizer.model, checkpoints/)")
    define("string", "pretrained", None, "an imported KOSMOS-2/KOSMOS-E folder (config.json, model.safetensors)")
    define("integer", "step", None, "checkpoint step of --workdir (default: the newest)")
    define("string", "tokenizer", None, f"with --pretrained: its SentencePiece model file (default: the folder's "
           f"tokenizer.model, when it holds {FORMAT_FILE})")
    define("enum", "scheme", None, f"with --pretrained: the tokenizer's ids (fairseq: KOSMOS-2's; native: this "
           f"project's; default: {FORMAT_FILE}'s, else fairseq)", enum_values=["fairseq", "native"])
    define("string", "image", None, "the photo (PNG, JPEG, ...), any size")
    define("string", "instruction", None, "what to grasp, e.g. 'Grasp the red mug.' (omit it for no instruction: NON)")
    define("string", "out", None, "write the overlay PNG here")
    define("bool", "json", False, "print the grasp as one JSON line")
    flags.mark_flags_as_mutual_exclusive(["workdir", "pretrained"], required=True, flag_values=flag_values)
    flags.mark_flag_as_required("image", flag_values=flag_values)


def checked_options(args):
    """The flags, with what one flag cannot check alone refused."""
    if args.pretrained and not args.tokenizer and not (pathlib.Path(args.pretrained) / FORMAT_FILE).is_file():
        raise commands.UsageError(f"--pretrained={args.pretrained} holds no {FORMAT_FILE} (python -m "
                                  "kosmos_jax.workdir.export writes one): give --tokenizer, the SentencePiece model "
                                  "file its weights were trained with")
    return args


def run(image: str, *, workdir: str | None = None, step: int | None = None, pretrained: str | None = None,
        tokenizer: str | None = None, scheme: str | None = None, instruction: str | None = None,
        out: str | None = None) -> dict:
    """Load, predict, draw: the printed record. One of `workdir` (and its `step`) or `pretrained` (and its
    `tokenizer`, `scheme`) gives the model."""
    from kosmos_jax.predict.images import load_image
    from kosmos_jax.predict.predictor import GraspPredictor
    from kosmos_jax.scoring.drawing import NO_INSTRUCTION, overlay, write_png

    if (workdir is None) == (pretrained is None):
        raise ValueError("give exactly one of workdir and pretrained")
    photo = load_image(image)  # bad images fail before the model is loaded
    if workdir:
        predictor = GraspPredictor.from_workdir(workdir, step)
    else:
        predictor = GraspPredictor.from_pretrained(pretrained, tokenizer, scheme=scheme)
    grasp = predictor.predict(photo, instruction)
    record = {**grasp.to_dict(), "image": image, "instruction": instruction, "overlay": out}
    if out:
        zoom = max(1.0, 448 / min(photo.shape[:2]))  # small photos enlarged so the caption is legible
        write_png(out, overlay(photo, grasp.rectangle(), (), instruction or NO_INSTRUCTION, zoom=zoom))
    return record


def describe(record: dict) -> str:
    lines = [f"grasp at x={record['x']:.1f}, y={record['y']:.1f} px, theta={record['theta']:.3f} rad "
             f"({math.degrees(record['theta']):.1f} deg), width {record['width']:.1f} px, jaw {record['jaw']:.1f} px",
             f"answer: {record['answer']}"]
    if record["overlay"]:
        lines.append(f"overlay written to {record['overlay']}")
    return "\n".join(lines)


def main(argv=None) -> int:
    return commands.run_command(define_flags, predict_command, argv, prog="kosmos-grasp predict", doc=__doc__)


def predict_command(args) -> int:
    args = checked_options(args)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with contextlib.redirect_stdout(sys.stderr):  # stdout holds the grasp only
                record = run(args.image, workdir=args.workdir, step=args.step, pretrained=args.pretrained,
                             tokenizer=args.tokenizer, scheme=args.scheme, instruction=args.instruction, out=args.out)
        except (PredictError, OSError) as error:
            record = None
            message = f"error: {error}"
    for warning in caught:
        if issubclass(warning.category, UserWarning):
            print(f"warning: {warning.message}", file=sys.stderr)
    if record is None:
        print(message, file=sys.stderr)
        return 1
    print(json.dumps(record) if args.json else describe(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
