"""SentencePiece tokenizers with KOSMOS-2's special-token layout.

Two ways to get one:
- `train_tokenizer(texts, ...)`: trains a BPE model in memory on the generated text, with the
  KOSMOS-2 tag and patch tokens (and, with `numbers="values"`, one token per grasp value such as
  "x_12" or "a_77") as user-defined symbols. Its ids are native: the model is trained with
  `<s>`=0, `<pad>`=1, `</s>`=2, `<unk>`=3 and the 64 image slot ids 4..67 reserved (control
  symbols, `tokens.IMAGE_SLOT_TOKENS`), so that the prompt layout is KOSMOS-2's and no slot id is
  also a tag, patch or text id.
  Digits are split ("x_1 2"), so no number gets a piece of its own by accident. Training is
  deterministic (one thread, no sentence sampling).
- `load_tokenizer(path, scheme="fairseq")`: an existing SentencePiece model such as KOSMOS-2's
  `sentencepiece.bpe.model` (its own ids `<unk>`=0, `<s>`=1, `</s>`=2), mapped to fairseq's
  dictionary the way XLM-RoBERTa's tokenizer does: `<s>`=0, `<pad>`=1, `</s>`=2, `<unk>`=3,
  piece i >= 3 -> i + 1, then `<mask>` = N + 1, the 11 tags from N + 2 and the 1024 patch tokens
  from N + 13 (N pieces; N = 64000 gives `<image>`=64003 and patch tokens 64013..65036, the ids of
  DESIGN.md section 4). The tags and patch tokens are appended to a copy of the model as
  user-defined pieces, so SentencePiece matches them inside text. One known difference from
  transformers' Kosmos2 tokenizer, which strips the space before an added token: here a space
  before a tag or patch token stays a "▁" token, so decode(encode(text)) == text holds.
"""

from __future__ import annotations

import dataclasses
import io
import pathlib
from typing import Iterable, Sequence

import sentencepiece as spm
from sentencepiece import sentencepiece_model_pb2

from kosmos_jax.text import tokens as special

SCHEMES = ("native", "fairseq")
# SentencePiece's own <unk>=0, <s>=1, </s>=2 in fairseq's dictionary (<s>=0, <pad>=1, </s>=2, <unk>=3)
_FAIRSEQ_OF_PIECE = {0: 3, 1: 0, 2: 2}
_PIECE_OF_FAIRSEQ = {v: k for k, v in _FAIRSEQ_OF_PIECE.items()}


@dataclasses.dataclass(frozen=True)
class Tokenizer:
    """A SentencePiece model plus the id scheme that maps its piece ids to model ids."""

    model_proto: bytes
    scheme: str = "native"
    numbers: str = "digits"

    def __post_init__(self):
        if self.scheme not in SCHEMES:
            raise ValueError(f"unknown tokenizer scheme {self.scheme!r}; expected one of {SCHEMES}")
        special.check_number_mode(self.numbers)
        processor = spm.SentencePieceProcessor(model_proto=self.model_proto)
        object.__setattr__(self, "_sp", processor)
        object.__setattr__(self, "_pieces", processor.get_piece_size())
        if self.scheme == "fairseq":
            object.__setattr__(self, "_base", self._pieces - len(special.SPECIAL_SYMBOLS))
        missing = [s for s in special.SPECIAL_SYMBOLS if processor.piece_to_id(s) == processor.unk_id()]
        if missing:
            raise ValueError(f"tokenizer model lacks {len(missing)} special tokens, e.g. {missing[:3]}")

    # -- ids --------------------------------------------------------------------------------
    def _to_model_id(self, piece_id: int) -> int:
        if self.scheme == "native":
            return piece_id
        if piece_id < 3:
            return _FAIRSEQ_OF_PIECE[piece_id]
        if piece_id < self._base:
            return piece_id + 1
        return piece_id + 2  # appended tags and patches sit after <mask> = N + 1

    def _to_piece_id(self, model_id: int) -> int:
        if self.scheme == "native":
            return model_id
        if model_id in _PIECE_OF_FAIRSEQ:
            return _PIECE_OF_FAIRSEQ[model_id]
        if model_id == 1 or model_id == self._base + 1:
            raise ValueError(f"id {model_id} (<pad>/<mask>) has no SentencePiece piece")
        return model_id - 1 if model_id <= self._base else model_id - 2

    @property
    def vocab_size(self) -> int:
        return self._pieces if self.scheme == "native" else self._pieces + 2

    @property
    def bos_id(self) -> int:
        return 0

    @property
    def pad_id(self) -> int:
        return 1

    @property
    def eos_id(self) -> int:
        return 2

    @property
    def unk_id(self) -> int:
        return 3

    def token_id(self, piece: str) -> int:
        """The model id of one piece; KeyError when the model does not know it."""
        piece_id = self._sp.piece_to_id(piece)
        if piece_id == self._sp.unk_id() and piece != special.UNK:
            raise KeyError(f"piece {piece!r} is not in the tokenizer's vocabulary")
        return self._to_model_id(piece_id)

    @property
    def reserves_image_slots(self) -> bool:
        """Whether the image slot ids 4..67 are reserved (a tokenizer trained here) rather than
        ordinary pieces that text also uses (KOSMOS-2's model, or a native model trained before
        slots were reserved, where they are also the tag and patch tokens)."""
        return all(self._sp.is_control(self._to_piece_id(i)) and self._sp.id_to_piece(self._to_piece_id(i)) == token
                   for i, token in zip(special.IMAGE_SLOT_IDS, special.IMAGE_SLOT_TOKENS))

    @property
    def image_start_id(self) -> int:
        return self.token_id(special.IMAGE_START)

    @property
    def image_end_id(self) -> int:
        return self.token_id(special.IMAGE_END)

    # -- text -------------------------------------------------------------------------------
    def encode(self, text: str) -> list[int]:
        """Model ids of `text` (no <s> or </s>)."""
        return [self._to_model_id(i) for i in self._sp.encode(text)]

    def pieces(self, text: str) -> list[str]:
        return self._sp.encode_as_pieces(text)

    def decode(self, ids: Iterable[int]) -> str:
        """Text of model ids; <s>, <pad>, </s> and image slots are the caller's to remove."""
        return self._sp.decode([self._to_piece_id(int(i)) for i in ids])

    def piece_texts(self) -> list[str]:
        """The text of every model id, as a grammar over token strings takes it: '▁' as a space, a
        byte piece as its character when ASCII, '' for control pieces, <unk>, non-ASCII bytes and
        ids without a piece (fairseq's <pad> and <mask>)."""
        texts = [""] * self.vocab_size
        for piece_id in range(self._pieces):
            if self._sp.is_control(piece_id) or self._sp.is_unknown(piece_id):
                continue
            piece = self._sp.id_to_piece(piece_id)
            if self._sp.is_byte(piece_id):  # "<0x41>"
                byte = int(piece[3:5], 16)
                text = chr(byte) if byte < 0x80 else ""
            else:
                text = piece.replace("\u2581", " ")
            texts[self._to_model_id(piece_id)] = text
        return texts

    # -- files ------------------------------------------------------------------------------
    def save(self, path) -> pathlib.Path:
        """Write the SentencePiece model (the scheme and number mode travel in the caller's config)."""
        path = pathlib.Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(self.model_proto)
        return path


def _symbols(numbers: str, representations: Sequence[str], image_size: int) -> list[str]:
    symbols = list(special.SPECIAL_SYMBOLS)
    if numbers == "values":
        seen = set(symbols)
        for representation in representations:
            for token in special.value_tokens(representation, image_size):
                if token not in seen:
                    seen.add(token)
                    symbols.append(token)
    return symbols


def train_tokenizer(
    texts: Iterable[str],
    numbers: str = "digits",
    text_pieces: int = 1000,
    representations: Sequence[str] = ("xya",),
    image_size: int = 224,
) -> Tokenizer:
    """Train a BPE SentencePiece model in memory on `texts` (deterministic).

    text_pieces: how many pieces besides the special and value symbols (an upper bound: small
      corpora stop merging earlier). Characters never seen fall back to bytes, so any text
      round-trips.
    """
    special.check_number_mode(numbers)
    texts = [t for t in texts if t]
    if not texts:
        raise ValueError("cannot train a tokenizer on no text")
    if text_pieces < 1:
        raise ValueError(f"text_pieces must be positive, got {text_pieces}")
    symbols = _symbols(numbers, representations, image_size)
    model = io.BytesIO()
    spm.SentencePieceTrainer.train(
        sentence_iterator=iter(texts),
        model_writer=model,
        model_type="bpe",
        vocab_size=len(symbols) + 4 + special.IMAGE_SLOTS + 256 + text_pieces,
        hard_vocab_limit=False,
        # ids 4..67, before the user-defined symbols (a list: a tuple arrives as one string)
        control_symbols=list(special.IMAGE_SLOT_TOKENS),
        user_defined_symbols=symbols,
        bos_id=0,
        pad_id=1,
        eos_id=2,
        unk_id=3,
        split_digits=True,
        byte_fallback=True,
        character_coverage=1.0,
        num_threads=1,
        input_sentence_size=0,
        shuffle_input_sentence=False,
        minloglevel=2,
    )
    return Tokenizer(model.getvalue(), scheme="native", numbers=numbers)


def load_tokenizer(path, scheme: str = "fairseq", numbers: str = "digits") -> Tokenizer:
    """Load a SentencePiece model file.

    scheme "fairseq": a model with its own ids `<unk>`=0, `<s>`=1, `</s>`=2 (KOSMOS-2's) mapped to
      fairseq's dictionary, the tags and patch tokens appended (see the module docstring).
    scheme "native": a model written by `Tokenizer.save` after `train_tokenizer`.
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no SentencePiece model at {path}")
    proto = path.read_bytes()
    if scheme == "native":
        return Tokenizer(proto, scheme="native", numbers=numbers)
    if scheme != "fairseq":
        raise ValueError(f"unknown tokenizer scheme {scheme!r}; expected one of {SCHEMES}")
    model = sentencepiece_model_pb2.ModelProto()
    try:
        model.ParseFromString(proto)
    except Exception as error:  # protobuf raises its own DecodeError
        raise ValueError(f"{path} is not a SentencePiece model: {error}") from error
    expected = {0: special.UNK, 1: special.BOS, 2: special.EOS}
    found = {i: model.pieces[i].piece for i in expected if i < len(model.pieces)}
    if found != expected:
        raise ValueError(f"{path}: the fairseq scheme needs pieces 0..2 = {expected}, found {found}")
    if numbers == "values":
        raise ValueError("value tokens need a tokenizer trained with them; KOSMOS-2's model has none (use numbers='digits')")
    known = {p.piece for p in model.pieces}
    clash = [s for s in special.SPECIAL_SYMBOLS if s in known]
    if clash:
        raise ValueError(f"{path} already holds special tokens {clash[:3]}; load it with scheme='native'")
    for symbol in special.SPECIAL_SYMBOLS:
        piece = model.pieces.add()
        piece.piece = symbol
        piece.score = 0.0
        piece.type = sentencepiece_model_pb2.ModelProto.SentencePiece.USER_DEFINED
    return Tokenizer(model.SerializeToString(), scheme="fairseq", numbers=numbers)


def fairseq_layout(pieces: int) -> dict[str, int]:
    """The fairseq ids of KOSMOS-2's special tokens for a SentencePiece model of `pieces` pieces."""
    layout = {special.BOS: 0, special.PAD: 1, special.EOS: 2, special.UNK: 3, "<mask>": pieces + 1}
    for offset, symbol in enumerate(special.SPECIAL_SYMBOLS):
        layout[symbol] = pieces + 2 + offset
    return layout
