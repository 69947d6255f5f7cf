"""GraspPredictor: a trained run (or an imported KOSMOS-2/KOSMOS-E folder) and a photo -> a Grasp.

    predictor = GraspPredictor.from_workdir("runs/demo")            # newest checkpoint
    predictor = GraspPredictor.from_pretrained("exported/demo")     # a run exported (workdir.export)
    grasp = predictor.predict("photo.png", "Grasp the red mug.")   # or an H x W x 3 uint8 array
    grasps = predictor.predict_batch(images, instructions)
    grasp = predictor.predict(image)      # no instruction: KOSMOS-E's NON kind ("" is an error)

Each photo is brought to the model's view as the run's test views were made (framing.py), each
instruction to the prompts training laid out (asking.py); the answers are decoded greedily with
the KV cache under the grasp grammar (scoring.model_answers, one jitted program per batch shape and
question), parsed and combined as the evaluation does, and the grasp is mapped back to the
photo's pixels. Batches are padded to one of `batch_sizes` (more rows are decoded in chunks of the
largest) and prompts left-padded to a multiple of PROMPT_STEP tokens, so a new batch length or
instruction length rarely compiles anything new.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
from collections.abc import Sequence

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.kosmos2 import split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_decoding import WINDOWS, configured_windows, value_picker
from kosmos_jax.models.weights import load_pretrained
from kosmos_jax.predict.asking import Asked, ask
from kosmos_jax.predict.errors import ImageError, InstructionError, RunFolderError
from kosmos_jax.predict.framing import PHOTO_SHORT_SIDE, Framing, frame
from kosmos_jax.predict.images import load_image
from kosmos_jax.workdir.sizes import CORNELL_SIZE, run_grasp_size
from kosmos_jax.scoring.model_answers import Decoder
from kosmos_jax.scoring.instructions import combine_asked
from kosmos_jax.scoring.prompts import left_padded
from kosmos_jax.scoring.questions import questions
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.text.tokenizer import Tokenizer, load_tokenizer
from kosmos_jax.workdir.exported import folder_settings
from kosmos_jax.workdir.files import RunError
from kosmos_jax.workdir.pretrained import FORMAT_FILE
from kosmos_jax.workdir.run import open_run

BATCH_SIZES = (1, 4, 16)
PROMPT_STEP = 32


@dataclasses.dataclass(frozen=True)
class Grasp:
    """A grasp in the caller's photo pixels: centre (x, y), theta in radians (DESIGN.md section 2:
    [-pi/2, pi/2), anticlockwise on screen), the gripper's opening `width` and `jaw` size (from
    the answer when it states them, else borrowed as the run's protocol borrows them, sizes.py),
    the answer text, and the answer of each part when the run's outputs are individual."""

    x: float
    y: float
    theta: float
    width: float
    jaw: float
    answer: str
    parts: dict[str, str] = dataclasses.field(default_factory=dict, hash=False)

    def rectangle(self) -> np.ndarray:
        """(x, y, w, h, theta) as the rest of the project holds a grasp."""
        return np.array([self.x, self.y, self.width, self.jaw, self.theta])

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class GraspPredictor:
    """Grasps of a model given as parameters; see the module docstring."""

    def __init__(self, model_config: Kosmos2Config, params, tokenizer: Tokenizer, format_config: FormatConfig, *,
                 protocol: str = "honest", grasp_size: tuple[float, float] = CORNELL_SIZE, mesh: Mesh | None = None,
                 batch_sizes: Sequence[int] = BATCH_SIZES, short_side: int = PHOTO_SHORT_SIDE, source: str = "",
                 value_window: int = 0, angle_window: int = 0):
        if tokenizer.vocab_size > model_config.text.vocab_size:
            raise RunFolderError(f"{source or 'the model'}: its vocabulary of {model_config.text.vocab_size} ids cannot "
                                 f"hold the tokenizer's {tokenizer.vocab_size}; is it the model's tokenizer?")
        if not batch_sizes or min(batch_sizes) < 1:
            raise ValueError(f"batch_sizes must be positive sizes, got {batch_sizes}")
        self.model_config, self.params, self.tokenizer = model_config, params, tokenizer
        self.format_config, self.protocol, self.grasp_size = format_config, protocol, tuple(grasp_size)
        self.batch_sizes, self.short_side, self.source = tuple(sorted(set(batch_sizes))), short_side, source
        self.context = model_config.text.max_position_embeddings
        self._questions = questions(tokenizer, format_config, model_config.text.vocab_size)
        self._decoder = Decoder(model_config, mesh if mesh is not None else make_mesh(1, -1, 1),
                                value_picker(tokenizer.piece_texts(), value_window, angle_window))

    # -- loading --------------------------------------------------------------------------------
    @classmethod
    def from_workdir(cls, workdir, step: int | None = None, *, mesh: Mesh | None = None, **options) -> "GraspPredictor":
        """The run a trainer wrote in `workdir`, at checkpoint `step` (None: the newest)."""
        try:
            run = open_run(workdir)  # before any device is touched: a wrong folder fails at once
            if not run.steps():
                raise RunError(f"{workdir} holds no checkpoint (checkpoints/ is empty or missing): train first, or "
                               "wait for the trainer's first checkpoint")
            mesh = mesh if mesh is not None else make_mesh(1, -1, 1)
            step, params = run.params(step, mesh)
        except RunError as error:
            raise RunFolderError(str(error)) from None
        options.setdefault("grasp_size", run_grasp_size(run))
        options = {**configured_windows(run.config), **options}
        return cls(run.model_config, params, run.tokenizer, run.format_config, protocol=run.protocol, mesh=mesh,
                   source=f"{workdir} step {step}", **options)

    @classmethod
    def from_pretrained(cls, folder, tokenizer=None, *, scheme: str | None = None, numbers: str | None = None,
                        format_config: FormatConfig | None = None, compute_dtype: str = "float32",
                        mesh: Mesh | None = None, **options) -> "GraspPredictor":
        """A transformers-layout folder (config.json + safetensors, models.weights.load_pretrained).

        A folder a run was exported to (workdir.export) holds kosmos_e.json and tokenizer.model: with
        them it needs nothing more. Else give `tokenizer`: a Tokenizer, or a SentencePiece model file
        read with `scheme` ("fairseq" for KOSMOS-2's sentencepiece.bpe.model, "native" for one this
        project trained) and `numbers`; `format_config`: the text format it was fine-tuned with
        (default: KOSMOS-E's, individual XYA with the angle code). Arguments given win over kosmos_e.json."""
        folder = pathlib.Path(folder)
        if not (folder / "config.json").is_file():
            raise RunFolderError(f"{folder}: no config.json; a pretrained folder holds config.json and "
                                 "model.safetensors in transformers' layout (models.weights.save_pretrained writes one)")
        exported = _exported(folder)
        if tokenizer is None and not exported:
            raise RunFolderError(f"{folder} holds no {FORMAT_FILE} (python -m kosmos_jax.workdir.export writes one, "
                                 "with the run's tokenizer.model): give the tokenizer its weights were trained with")
        tokenizer = exported.get("tokenizer") if tokenizer is None else tokenizer
        scheme, numbers = scheme or exported.get("scheme", "fairseq"), numbers or exported.get("numbers", "digits")
        format_config = format_config or exported.get("format_config", FormatConfig())
        options = {**{name: exported[name] for name in ("protocol", "grasp_size", *WINDOWS) if name in exported},
                   **options}
        if not isinstance(tokenizer, Tokenizer):
            if not pathlib.Path(tokenizer).is_file():
                raise RunFolderError(f"{tokenizer}: the tokenizer file is missing (give the SentencePiece model the "
                                     "weights were trained with, e.g. KOSMOS-2's sentencepiece.bpe.model)")
            try:
                tokenizer = load_tokenizer(tokenizer, scheme=scheme, numbers=numbers)
            except ValueError as error:  # e.g. a tokenizer of this project read as KOSMOS-2's
                raise RunFolderError(f"{error} (KOSMOS-2's sentencepiece.bpe.model reads with scheme='fairseq', one "
                                     "this project trained with scheme='native')") from None
        mesh = mesh if mesh is not None else make_mesh(1, -1, 1)
        try:
            model = load_pretrained(folder, compute_dtype=compute_dtype)
        except (FileNotFoundError, ValueError) as error:  # missing files, keys or shapes of another model
            raise RunFolderError(str(error)) from None
        params = jax.device_put(split_model(model)[1], NamedSharding(mesh, PartitionSpec()))
        return cls(model.config, params, tokenizer, format_config, mesh=mesh, source=str(folder),
                   **options)

    # -- prediction -----------------------------------------------------------------------------
    def view(self, image) -> tuple[np.ndarray, Framing]:
        """(the model's view of `image`, the Framing between them)."""
        return frame(load_image(image), self.short_side)

    def predict(self, image, instruction: str | None = None) -> Grasp:
        """The grasp for `instruction` (None: no instruction, KOSMOS-E's NON) on `image` (a path or an
        H x W x 3 uint8 array, any size)."""
        return self.predict_batch([image], [instruction])[0]

    def predict_batch(self, images, instructions=None) -> list[Grasp]:
        """One Grasp per image; `instructions` one per image, or one (a string or None) for all."""
        if isinstance(images, (str, os.PathLike)) or (isinstance(images, np.ndarray) and images.ndim < 4):
            raise ImageError("predict_batch takes a sequence of images (paths or arrays); predict takes one")
        images = list(images)
        if instructions is None or isinstance(instructions, str):
            instructions = [instructions] * len(images)
        instructions = list(instructions)
        if len(images) != len(instructions):
            raise InstructionError(f"{len(images)} images but {len(instructions)} instructions; give one each")
        asked = [ask(text, self.tokenizer, self.format_config, self._questions, self.context) for text in instructions]
        framed = [self.view(image) for image in images]
        answers = self._decode(asked, [view for view, _ in framed])
        return [self._grasp(a, framing, {p.question.part: answers[(row, p.question.part)] for p in a.prompts})
                for row, (a, (_, framing)) in enumerate(zip(asked, framed))]

    def _decode(self, asked: list[Asked], views: list[np.ndarray]) -> dict[tuple[int, str], tuple]:
        """{(row, part): (answer text, parse)}, each question decoded in padded batches."""
        jobs: dict[tuple[str, str], list] = {}
        for row, a in enumerate(asked):
            for prompt in a.prompts:
                jobs.setdefault((a.answer, prompt.question.part), []).append((row, prompt))
        largest, out = self.batch_sizes[-1], {}
        for items in jobs.values():
            question = items[0][1].question
            for start in range(0, len(items), largest):
                chunk = items[start:start + largest]
                size = min(b for b in self.batch_sizes if b >= len(chunk))
                filled = chunk + [chunk[0]] * (size - len(chunk))
                length = PROMPT_STEP * math.ceil(max(len(p.tokens) for _, p in chunk) / PROMPT_STEP)
                ids, mask, image_mask = left_padded([(p.tokens, p.image_mask) for _, p in filled], length,
                                                    self.tokenizer.pad_id)
                pixels = np.stack([views[row] for row, _ in filled])
                generated = self._decoder(self.params, pixels, ids, mask, image_mask, question.prompt.constraint,
                                          question.max_new_tokens)
                for (row, _), tokens in zip(chunk, generated):
                    out[(row, question.part)] = question.parse(tokens, self.format_config)
        return out

    def _grasp(self, asked: Asked, framing: Framing, answers: dict[str, tuple]) -> Grasp:
        parsed = {part: parse for part, (_, parse) in answers.items()}
        x, y, theta = combine_asked(asked.answer, asked.instruction, parsed)
        stated = parsed["grasp" if "grasp" in parsed else "location"].grasp[2:4]
        width, jaw = stated if np.isfinite(stated).all() else self.grasp_size
        in_photo = framing.to_photo(np.array([x, y, width, jaw, theta]))
        texts = [text for text, _ in answers.values()]
        return Grasp(*(float(in_photo[i]) for i in (0, 1, 4, 2, 3)), answer=" ".join(texts),
                     parts=dict(zip(answers, texts)) if self.format_config.individual else {})


def _exported(folder: pathlib.Path) -> dict:
    """from_pretrained's defaults from FOLDER/kosmos_e.json (workdir.exported); {} when it has none."""
    try:
        return folder_settings(folder)
    except ValueError as error:
        raise RunFolderError(str(error)) from None
