"""Words from a vision-language model behind any OpenAI-compatible chat-completions endpoint.

The image goes as a base64 PNG data URL in an `image_url` content part. The prompts follow the
paper's section II (GPT-4 Vision wrote the shape, purpose, strategy, colour and part annotations):
each asks for one sentence in the form of the instruction ("Grasp the [color] object."), and the
reply is searched for that sentence, so a model that adds a preamble or quotes still parses; a
reply with no such sentence, or a body that is not a chat-completions JSON, is a `VLMResponseError`
that quotes what came back.

Requests time out after `timeout_s`. Transport failures (refused or reset connections, a server
that closes without answering, a reply that is not HTTP), time-outs, HTTP 429 and 5xx are retried
up to `max_retries` times, waiting `backoff_s * 2**(k - 1)` before retry k = 1, 2, ... (backoff_s,
2 backoff_s, 4 backoff_s, ...); other HTTP errors fail at once. Every failure is a `VLMError` that
names the URL. Every answer is cached on disk as JSON under `cache_dir`, keyed by sha256 of the image's PNG
bytes, the prompt and the model, so that rebuilding a dataset makes no calls.
"""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import http.client
import json
import os
import pathlib
import re
import tempfile
import time
import urllib.error
import urllib.request
from typing import Callable, Sequence

import cv2
import numpy as np

from kosmos_jax.annotators.base import ObjectWords
from kosmos_jax.annotators.kosmos_e import part_words, slot_words


class VLMError(RuntimeError):
    """The endpoint could not be used (HTTP error, connection refused, retries exhausted)."""


class VLMTimeoutError(VLMError):
    """Every try timed out."""


class VLMResponseError(VLMError):
    """The endpoint answered, but not with a usable reply."""


_SETTING = (
    "I will show you an image of one object placed on a table, taken for robotic grasping. "
)

PROMPTS = {
    "name": _SETTING
    + "Name the object with a short common noun phrase. Your final response should be formatted as "
    '"Grasp the [name]." where [name] is the name of the object.',
    "colour": "As an expert in color recognition, your task is to describe the color(s) of the object "
    "in this image, using precise color nouns such as black, white, or green. If the object displays "
    "several colors, name each of them, or use phrases such as 'with [color] details'. Your final "
    'response should be formatted as "Grasp the [color] object." Do not say what kind of object it is.',
    "shape": _SETTING
    + "Describe the geometric attributes of the object with shape adjectives such as cylindrical, "
    'rectangular, round or flat. Your final response should be formatted as "Grasp the [shape] object." '
    "where [shape] are the shape adjectives.",
    "purpose": _SETTING
    + "Describe the real-world purpose of the object, what it is used for. Your final response should "
    'be formatted as "Grasp the object for [purpose]." where [purpose] is what the object is used for.',
    "strategy": _SETTING
    + "Based on human knowledge of grasping, outline an effective strategy for grasping this object with "
    "a parallel-jaw gripper in three short sentences: its shape, where to grasp it for stability, and how "
    'the gripper should be oriented. Begin with "It is".',
    "part": _SETTING
    + "The object is a {name}. A rectangular grasp is given by the pixel coordinates of its four corners: "
    "{corners}. Determine which specific part of the object this grasp holds (for example the handle or "
    "mouth of a bottle, the front, middle or back end of a remote control, the edge of a hat). Your final "
    'response should be formatted as "Grasp the [part] of the {name}."',
}

_SENTENCE_PATTERNS = {
    "name": r"Grasp the [^.\"\n]+?\.",
    "colour": r"Grasp the [^.\"\n]+? object[^.\"\n]*\.",
    "shape": r"Grasp the [^.\"\n]+? object[^.\"\n]*\.",
    "purpose": r"Grasp the object (?:that is )?(?:used )?for [^\"\n]+?\.",
    "part": r"Grasp the [^.\"\n]+? of [^\"\n]+?\.",
    "strategy": r"It is [^\"]+",
}


def encode_png(image) -> bytes:
    """[H, W, 3] uint8 RGB -> PNG bytes (bytes pass through unchanged)."""
    if isinstance(image, (bytes, bytearray)):
        return bytes(image)
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"the VLM client needs an [H, W, 3] uint8 RGB image, got {image.dtype} {image.shape}")
    ok, png = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    if not ok:
        raise ValueError("PNG encoding failed")
    return png.tobytes()


def cache_key(png: bytes, prompt: str, model: str) -> str:
    digest = hashlib.sha256()
    for part in (png, prompt.encode(), model.encode()):
        digest.update(len(part).to_bytes(8, "little"))
        digest.update(part)
    return digest.hexdigest()


def reply_text(body: bytes) -> str:
    """The assistant's text in a chat-completions response body, or VLMResponseError quoting it."""
    snippet = body[:200].decode("utf-8", "replace")
    try:
        payload = json.loads(body)
        content = payload["choices"][0]["message"]["content"]
    except (ValueError, KeyError, IndexError, TypeError) as error:
        raise VLMResponseError(f"not a chat-completions response ({error!r}): {snippet!r}") from None
    if isinstance(content, list):
        content = "".join(p.get("text", "") for p in content if isinstance(p, dict))
    if not isinstance(content, str) or not content.strip():
        raise VLMResponseError(f"chat-completions response without text content: {snippet!r}")
    return content


def parse_sentence(kind: str, reply: str) -> str:
    """The instruction sentence of `kind` inside a model reply, or VLMResponseError."""
    if kind not in _SENTENCE_PATTERNS:
        raise ValueError(f"no reply format for kind {kind!r}; expected one of {tuple(_SENTENCE_PATTERNS)}")
    cleaned = " ".join(reply.replace("*", "").replace("\u201c", '"').replace("\u201d", '"').split())
    matches = re.findall(_SENTENCE_PATTERNS[kind], cleaned, flags=re.IGNORECASE)
    if not matches:
        raise VLMResponseError(f"the {kind!r} reply does not follow the requested format: {reply[:200]!r}")
    sentence = matches[-1].strip().strip('"').strip()
    return sentence[0].upper() + sentence[1:]


@dataclasses.dataclass
class VLMClient:
    """A cached, retrying client for POST {base_url}/chat/completions."""

    base_url: str
    model: str
    api_key: str | None = None
    timeout_s: float = 60.0
    max_retries: int = 3
    backoff_s: float = 1.0
    cache_dir: str | os.PathLike | None = None
    max_tokens: int = 300
    temperature: float = 0.0
    sleep: Callable[[float], None] = time.sleep
    calls: int = 0  # requests actually sent, for statistics

    def _url(self) -> str:
        return self.base_url.rstrip("/") + "/chat/completions"

    def _cache_path(self, key: str) -> pathlib.Path | None:
        return None if self.cache_dir is None else pathlib.Path(self.cache_dir) / key[:2] / f"{key}.json"

    def _payload(self, png: bytes, prompt: str) -> bytes:
        url = "data:image/png;base64," + base64.b64encode(png).decode("ascii")
        message = {"role": "user", "content": [{"type": "text", "text": prompt}, {"type": "image_url", "image_url": {"url": url}}]}
        body = {"model": self.model, "messages": [message], "max_tokens": self.max_tokens, "temperature": self.temperature}
        return json.dumps(body).encode()

    def _post(self, data: bytes) -> bytes:
        headers = {"Content-Type": "application/json"}
        if self.api_key:
            headers["Authorization"] = f"Bearer {self.api_key}"
        last: Exception | None = None
        timed_out = False
        for attempt in range(self.max_retries + 1):
            if attempt:
                self.sleep(self.backoff_s * 2 ** (attempt - 1))
            self.calls += 1
            try:
                request = urllib.request.Request(self._url(), data=data, headers=headers, method="POST")
                with urllib.request.urlopen(request, timeout=self.timeout_s) as response:
                    return response.read()
            except urllib.error.HTTPError as error:
                last, timed_out = error, False
                if error.code != 429 and error.code < 500:
                    detail = error.read()[:200].decode("utf-8", "replace")
                    raise VLMError(f"{self._url()} answered HTTP {error.code}: {detail!r}") from None
            except OSError as error:
                # a URLError wraps what went wrong while connecting in its `reason`; a time-out,
                # reset or RemoteDisconnected (closed without a reply) later on comes bare
                last, timed_out = error, isinstance(getattr(error, "reason", error), TimeoutError)
            except http.client.HTTPException as error:  # BadStatusLine (not HTTP), IncompleteRead
                last, timed_out = error, False
        kind = VLMTimeoutError if timed_out else VLMError
        what = f"timed out after {self.timeout_s} s" if timed_out else f"failed ({last!r})"
        raise kind(f"{self._url()} {what} on all {self.max_retries + 1} tries") from last

    def ask(self, image, prompt: str) -> str:
        """The model's text reply to the prompt about the image (from the cache when there)."""
        png = encode_png(image)
        path = self._cache_path(cache_key(png, prompt, self.model))
        if path is not None and path.exists():
            return json.loads(path.read_text())["reply"]
        reply = reply_text(self._post(self._payload(png, prompt)))
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            record = json.dumps({"model": self.model, "prompt": prompt, "reply": reply})
            with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False, suffix=".tmp") as handle:
                handle.write(record)
            os.replace(handle.name, path)
        return reply

    def sentence(self, image, kind: str, **fields) -> str:
        """One instruction sentence of `kind` ("part" needs name= and corners=)."""
        if kind not in PROMPTS:
            raise ValueError(f"no VLM prompt for kind {kind!r}; expected one of {tuple(PROMPTS)}")
        return parse_sentence(kind, self.ask(image, PROMPTS[kind].format(**fields)))


def _corner_text(corners) -> str:
    return ", ".join(f"({x:.0f}, {y:.0f})" for x, y in np.asarray(corners, np.float64))


def annotate(client: VLMClient, image, corners: Sequence | None = None,
             kinds: Sequence[str] = ("name", "colour", "shape", "purpose", "strategy")) -> ObjectWords:
    """ObjectWords of one photo from the VLM; with `corners` ([N, 4, 2]) also one part per grasp."""
    sentences: dict[str, object] = {kind: client.sentence(image, kind) for kind in kinds}
    fields = {kind: slot_words(kind, sentence) for kind, sentence in sentences.items()}
    name = fields.get("name")
    parts: tuple[str | None, ...] = ()
    if corners is not None:
        if not name:
            raise ValueError("part annotation needs the object's name; include 'name' in kinds")
        part_sentences = tuple(client.sentence(image, "part", name=name, corners=_corner_text(c)) for c in corners)
        sentences["part"] = part_sentences
        parts = tuple(part_words(s) for s in part_sentences)
    return ObjectWords(
        name=name,
        colour=fields.get("colour"),
        shape=fields.get("shape"),
        purpose=fields.get("purpose"),
        strategy=fields.get("strategy"),
        parts=parts,
        sentences=sentences,
    )
