"""Where a run's figures go: WORKDIR/metrics.jsonl, TensorBoard event files and the terminal.

One JSON line per logged step (`step`, `loss` at full float precision, `learning_rate`, `grad_norm`,
`examples_per_s`, `tokens_per_s`, `step_s`, `data_wait_fraction`, ...), eval lines with `split`.
TensorBoard files are written with tensorboardX (no TensorFlow). On an interactive terminal a
progress bar shows the newest loss; otherwise each logged step is one plain line on stderr.
Only process 0 writes; the other processes' logs do nothing.
"""

from __future__ import annotations

import json
import math
import pathlib
import sys

METRICS_FILE = "metrics.jsonl"
AUXILIARY_LOSSES = ("pointing", "patch_angle", "tower_angle", "slot_angle", "tower_offset", "slot_offset", "answer_pointing",
                    "phrase_patch", "tower_category", "tower_colour")  # logged beside the loss when a run adds them


def _plain(value):
    """A JSON-ready number: Python float or int (NaN and inf as strings JSON can hold)."""
    if hasattr(value, "item"):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


class MetricsLog:
    def __init__(self, workdir, total_steps: int, start_step: int, enabled: bool = True, interactive: bool | None = None):
        self.enabled = enabled
        self.total_steps = total_steps
        self.bar = None
        self.writer = None
        if not enabled:
            return
        workdir = pathlib.Path(workdir)
        workdir.mkdir(parents=True, exist_ok=True)
        self.file = open(workdir / METRICS_FILE, "a", encoding="utf-8")
        from tensorboardX import SummaryWriter  # imported here: only process 0 needs it

        self.writer = SummaryWriter(str(workdir / "tensorboard"))
        interactive = sys.stderr.isatty() if interactive is None else interactive
        if interactive:
            from tqdm import tqdm

            self.bar = tqdm(total=total_steps, initial=start_step, unit="step", dynamic_ncols=True)

    def write(self, record: dict) -> None:
        """Log one record (a training step's, or an eval's with "split")."""
        if not self.enabled:
            return
        record = {key: _plain(value) for key, value in record.items()}
        self.file.write(json.dumps(record) + "\n")
        self.file.flush()
        prefix = record.get("split", "train")
        for key, value in record.items():
            if key not in ("step", "split") and isinstance(value, (int, float)) and not isinstance(value, bool):
                self.writer.add_scalar(f"{prefix}/{key}", value, record["step"])
        self.writer.flush()
        self._show(record)

    def _show(self, record: dict) -> None:
        if "split" in record:
            text = f"eval ({record['split']}) step {record['step']}: loss {record['loss']:.4f}, accuracy {record['accuracy']:.4f}"
            print(text, file=sys.stderr, flush=True) if self.bar is None else self.bar.write(text)
            return
        if self.bar is not None:
            self.bar.n = record["step"]
            self.bar.set_postfix(loss=f"{record['loss']:.4f}", lr=f"{record['learning_rate']:.2e}")
            return
        auxiliary = "".join(f", {name.replace('_', ' ')} {record[name]:.3f}" for name in AUXILIARY_LOSSES if name in record)
        print(f"step {record['step']}/{self.total_steps}: loss {record['loss']:.4f}{auxiliary}, lr {record['learning_rate']:.3e}, "
              f"grad norm {record['grad_norm']:.3f}, {record['examples_per_s']:.1f} examples/s, "
              f"data wait {100 * record['data_wait_fraction']:.1f}%", file=sys.stderr, flush=True)

    def message(self, text: str) -> None:
        if not self.enabled:
            return
        print(text, file=sys.stderr, flush=True) if self.bar is None else self.bar.write(text)

    def close(self) -> None:
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.close()
        self.writer.close()
        self.file.close()


def read_metrics(workdir) -> list[dict]:
    """Every record of WORKDIR/metrics.jsonl, in order."""
    path = pathlib.Path(workdir) / METRICS_FILE
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def train_losses(workdir) -> dict[int, float]:
    """{step: loss} of the training lines; a step logged twice (a resumed run redoing steps after its
    last checkpoint) keeps its newest line."""
    return {r["step"]: r["loss"] for r in read_metrics(workdir) if "split" not in r}
