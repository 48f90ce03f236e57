"""The size limits of ShapeAssembly programs, checked while parsing. Standard library only.

A text beyond a limit is refused with a :class:`~shapeprog.errors.ParseError` naming file, line and
column before anything is executed, so that parsing and execution time stay bounded. The values,
beside the corpus maxima they leave room above: ``docs/shapeassembly.md`` (Limits).

Example:
    >>> MAX_TRANSLATE_COPIES, MAX_CUBOIDS
    (256, 1000)
    >>> number("1e308", "p.txt", 3, 15)
    Traceback (most recent call last):
    ...
    shapeprog.errors.ParseError: p.txt:3:15: number 1e308 is out of range (limit: magnitude 1000.0)
"""
from __future__ import annotations

import math

from .errors import ParseError

__all__ = [
    "MAX_ABS_NUMBER",
    "MAX_ATTACHES",
    "MAX_BLOCKS",
    "MAX_CUBOIDS",
    "MAX_DEPTH",
    "MAX_LINE_LENGTH",
    "MAX_LINES",
    "MAX_TRANSLATE_COPIES",
    "check_lines",
    "check_tree",
    "count",
    "decode",
    "number",
]

#: Lines of a program text (corpus maximum: 72).
MAX_LINES = 1000
#: Characters of one line (corpus maximum: 71).
MAX_LINE_LENGTH = 1000
#: Magnitude of every number: extents, attach and squeeze coordinates, translate spans (corpus maximum: 2.788).
MAX_ABS_NUMBER = 1000.0
#: Copies made by one ``translate`` (corpus maximum: 36).
MAX_TRANSLATE_COPIES = 256
#: ``Assembly`` blocks (nodes) of a program (corpus maximum: 8).
MAX_BLOCKS = 256
#: Depth of the sub-program tree, the root block at depth 0 (corpus maximum: 2).
MAX_DEPTH = 16
#: Leaf cuboids of the executed program, counting macro copies and every copy of a sub-program
#: (corpus maximum: 51).
MAX_CUBOIDS = 1000
#: Attach operations of the executed program, all blocks together: one per attach, two per squeeze,
#: and each reflect/translate copy repeats the attaches of its source (corpus maximum: 102).
MAX_ATTACHES = 2000

Loc = tuple  # (line, column, token) of a statement or block header


def decode(data: bytes, file: str = "<bytes>") -> str:
    """A program file's bytes as text (UTF-8); a bad byte is a :class:`ParseError` at its line and column."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        head = data[:e.start]
        line = head.count(b"\n") + 1
        col = len(head[head.rfind(b"\n") + 1:].decode("utf-8", "replace")) + 1
        bad = data[e.start:e.end]
        raise ParseError(f"not UTF-8 text (byte {bad[:1].hex()!r} at offset {e.start})", file, line, col,
                         bad.decode("latin-1")) from None


def check_lines(lines: list[str], file: str) -> None:
    """The line count and every line's length."""
    if len(lines) > MAX_LINES:
        raise ParseError(f"more than {MAX_LINES} lines (MAX_LINES)", file, MAX_LINES + 1, 1, "")
    for i, text in enumerate(lines):
        if len(text) > MAX_LINE_LENGTH:
            raise ParseError(f"line longer than {MAX_LINE_LENGTH} characters (MAX_LINE_LENGTH)", file, i + 1,
                             MAX_LINE_LENGTH + 1, text[MAX_LINE_LENGTH:MAX_LINE_LENGTH + 10])


def number(text: str, file: str, line: int, column: int) -> float:
    """A number token's value, finite and at most :data:`MAX_ABS_NUMBER` in magnitude."""
    value = float(text)
    if not math.isfinite(value) or abs(value) > MAX_ABS_NUMBER:
        raise ParseError(f"number {text} is out of range (limit: magnitude {MAX_ABS_NUMBER})", file, line, column,
                         text)
    return value


def count(text: str, file: str, line: int, column: int) -> int:
    """A translate count token's value, 1 to :data:`MAX_TRANSLATE_COPIES` (decimal digits only)."""
    if not (text.isascii() and text.isdigit()) or not text.strip("0"):
        raise ParseError(f"expected a positive integer count, got {text[:20]!r}", file, line, column, text)
    if len(text.lstrip("0")) > len(str(MAX_TRANSLATE_COPIES)) or int(text) > MAX_TRANSLATE_COPIES:
        shown = text if len(text) <= 20 else f"{text[:10]}...({len(text)} digits)"
        raise ParseError(f"translate count {shown} exceeds the limit of {MAX_TRANSLATE_COPIES} "
                         "(MAX_TRANSLATE_COPIES)", file, line, column, text)
    return int(text)


def check_tree(blocks: dict[str, tuple[Loc, list[tuple[Loc, list, int]]]], parent: dict[str, str],
               file: str) -> None:
    """Depth of the sub-program tree, and the leaf cuboids and attach operations it executes to.

    Args:
        blocks: per block name (in file order), the location of its header and one row per
            statement: the statement's location, for each cuboid slot the statement creates (bbox
            excluded) the name of the sub-program block placed there or None for a leaf, and the
            number of attach operations the statement executes to.
        parent: the parent block of every non-root block (no cycles).
        file: the file name for errors.
    """
    depth: dict[str, int] = {}
    for name in blocks:
        d, n = 0, name
        while n in parent:
            n, d = parent[n], d + 1
        depth[name] = d
        if d > MAX_DEPTH:
            raise ParseError(f"sub-programs nested deeper than {MAX_DEPTH} (MAX_DEPTH)", file, *blocks[name][0])
    ops = 0
    for loc, _, n in (row for _, rows in blocks.values() for row in rows):
        ops += n
        if ops > MAX_ATTACHES:
            raise ParseError(f"the program executes to more than {MAX_ATTACHES} attach operations "
                             "(MAX_ATTACHES)", file, *loc)
    total: dict[str, int] = {}
    for name in sorted(blocks, key=lambda n: -depth[n]):  # children before their parents
        acc = 0
        for loc, slots, _ in blocks[name][1]:
            acc += sum(1 if child is None else total[child] for child in slots)
            if acc > MAX_CUBOIDS:
                raise ParseError(f"the program executes to more than {MAX_CUBOIDS} cuboids (MAX_CUBOIDS)", file,
                                 *loc)
        total[name] = acc
