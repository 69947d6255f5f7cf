"""The small text files of the grasp data sets: decoding, lines, fields and numbers, strictly.

Lines end at \\r\\n, \\r or \\n only (str.splitlines also breaks at form feeds, vertical tabs and
U+2028, which would shift the line numbers an error reports), fields are separated by spaces or
tabs, and a number is an ASCII decimal (float() and int() would also take '1_0' and non-ASCII
digits).
"""

from __future__ import annotations

import codecs
import pathlib
import re

_LINE_BREAK = re.compile(r"\r\n|\r|\n")
_LINE_BREAK_BYTES = re.compile(rb"\r\n|\r|\n")
_FIELD_GAP = re.compile(r"[ \t]+")
_INTEGER = re.compile(r"[0-9]+")
_NUMBER = re.compile(
    r"[+-]?(?:(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|nan|inf|infinity)", re.IGNORECASE)


def read_text(path: str | pathlib.Path, error: type[Exception]) -> str:
    """The UTF-8 text of `path` (a leading BOM dropped); `error` naming the file, line and column
    of the first byte that is not UTF-8."""
    path = pathlib.Path(path)
    data = path.read_bytes()
    if data.startswith(codecs.BOM_UTF8):
        data = data[len(codecs.BOM_UTF8):]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as failure:
        before = _LINE_BREAK_BYTES.split(data[: failure.start])
        raise error(f"{path}, line {len(before)}, column {len(before[-1]) + 1}: not UTF-8 text "
                    f"(byte 0x{data[failure.start]:02x})") from None


def split_lines(text: str) -> list[str]:
    """Lines of `text`, broken at \\r\\n, \\r and \\n only; a final line break adds no empty line."""
    lines = _LINE_BREAK.split(text)
    return lines[:-1] if lines and lines[-1] == "" else lines


def split_fields(line: str) -> list[str]:
    """The fields of a line separated by spaces or tabs; [] for a blank line."""
    stripped = line.strip(" \t")
    return _FIELD_GAP.split(stripped) if stripped else []


def parse_number(field: str) -> float:
    """An ASCII decimal number ('12', '-3.5', '1e3', 'NaN', 'inf') as a float; ValueError otherwise."""
    if not _NUMBER.fullmatch(field):
        raise ValueError(f"not a number: {field!r}")
    return float(field)


def is_ascii_integer(field: str) -> bool:
    """Whether `field` is ASCII digits only ('12', '0042'; not '-1', '1_0', '١٢' or '')."""
    return bool(_INTEGER.fullmatch(field))
