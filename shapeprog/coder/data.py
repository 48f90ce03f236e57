"""The PartNet shapes of the ShapeCoder paper as unstructured cuboid primitives (vendored in
``shapeprog/data/shapecoder_primitives.tar.xz``; provenance and licence, non-commercial:
``shapeprog/data/NOTICE.md``).

Three files, ``PN_chair.txt``, ``PN_table.txt``, ``PN_storage.txt``, 1,100 lines each; a line is
``<PartNet id>_0_<index>:<program>``, the program a right-nested ``Union`` of
``Move(Cuboid(w,h,d),x,y,z)`` parts, some wrapped in ``Rotate``. As in the paper, the first 400 lines
of each file are the *discovery* set (abstractions are discovered on them) and lines 400 to 1,099 the
*held-out* set (post hoc inference). Each line is parsed with :func:`shapeprog.coder.lang.parse`,
executed, and turned into primitives by :func:`shapeprog.coder.execute.primitives`: re-oriented axes,
2-decimal 9-tuples ``(W, H, D, X, Y, Z, RX, RY, RZ)``, ordered by the position key.

The archive is read on first use and each split is parsed once per process; importing this module
reads nothing.

Example:
    >>> shapes = load("chair")
    >>> len(shapes), shapes[1].key, len(shapes[1].prims)
    (400, '173_0_1', 6)
    >>> shapes[1].prims[0]
    (0.15, 0.52, 0.2, -0.37, -0.51, -0.4, 0.0, 0.0, 0.0)
"""
from __future__ import annotations

import functools
import io
import lzma
import re
import tarfile
import warnings
from dataclasses import dataclass
from importlib import resources

from ..errors import ParseError
from ..limits import decode
from . import limits
from .execute import ExecutionError, run
from .lang import LANG_3D, Call, Expr, Num, Var, _parse_spans, to_text

__all__ = ["CATEGORIES", "DISCOVERY_SIZE", "SPLITS", "DataWarning", "ShapeRecord", "load", "parse_record",
           "read_lines"]

CATEGORIES = ("chair", "table", "storage")
SPLITS = ("discovery", "heldout", "all")
#: Lines of each file in the discovery set (the paper's ``data_size``); the rest are held out.
DISCOVERY_SIZE = 400

_ARCHIVE = "shapecoder_primitives.tar.xz"
_KEY = re.compile(r"([0-9]+)_([0-9]+)_([0-9]+)\Z")


class DataWarning(UserWarning):
    """Some data lines could not be read (each is named in the message as ``file:line: reason``)."""


@dataclass(frozen=True)
class ShapeRecord:
    """One shape of a data file.

    Attributes:
        key: the line's key, ``<PartNet id>_0_<index>`` (e.g. ``'173_0_1'``).
        partnet_id: the PartNet annotation id (the key's first field).
        index: the key's last field (the line index in the file, 0 to 1,099).
        line: the 1-based line number in the file (for messages).
        program: the line's program (the naive union of its parts), a Shape expression of
            :data:`~shapeprog.coder.lang.LANG_3D`.
        prims: the primitives, P tuples of 9 floats ``(W, H, D, X, Y, Z, RX, RY, RZ)``, 2 decimals,
            ordered by :func:`~shapeprog.coder.execute.position_key`.
    """

    key: str
    partnet_id: int
    index: int
    line: int
    program: Expr
    prims: tuple


def parse_record(text: str, file: str = "<string>", line: int = 1) -> ShapeRecord:
    """Read one data line ``<PartNet id>_0_<index>:<program>``.

    The program must execute without hard errors, except that a cuboid dimension of exactly 0 is kept
    (the published chair file has six, in the held-out set).

    Raises:
        ParseError: ``file:line:column: reason`` with the offending token (a missing ``:``, a malformed
            key, a program that does not parse or is not a Shape, a variable, a negative dimension, a
            division by 0, a limit such as :data:`~shapeprog.coder.limits.MAX_PARTS` or
            :data:`~shapeprog.coder.limits.MAX_TEXT_LENGTH`).
    """
    if len(text) > limits.MAX_TEXT_LENGTH:
        raise ParseError(f"line longer than {limits.MAX_TEXT_LENGTH} characters (MAX_TEXT_LENGTH)", file, line,
                         limits.MAX_TEXT_LENGTH + 1, text[limits.MAX_TEXT_LENGTH:limits.MAX_TEXT_LENGTH + 10])
    key, sep, prog = text.partition(":")
    if not sep:
        raise ParseError("expected '<PartNet id>_0_<index>:<program>'", file, line, 1, text[:20])
    m = _KEY.match(key)
    if m is None:
        raise ParseError(f"malformed shape key {key[:40]!r}; expected '<PartNet id>_0_<index>'", file, line, 1,
                         key[:40])
    start = len(key) + 2
    program, toks = _parse_spans(prog, LANG_3D, file=file, line=line, column=start)
    names = [(i, e) for i, e in toks.spans if isinstance(e, Var)]
    if names:
        raise toks.error(f"a data line has no variables; got {names[0][1].name!r}", names[0][0])
    try:
        ex = run(program, LANG_3D)
    except ExecutionError as e:  # a limit, e.g. MAX_PARTS
        raise ParseError(e.reason if e.expr is None else f"{e.expr}: {e.reason}", file, line, start, prog[:20]) from None
    if ex.hard_errors:
        cuboids = [(i, e) for i, e in toks.spans if isinstance(e, Call) and e.fn == "Cuboid"]
        zero = [c for c in cuboids if any(isinstance(a, Num) and a.value == 0 for a in c[1].args)]
        negative = [c for c in cuboids if any(isinstance(a, Num) and a.value < 0 for a in c[1].args)]
        if negative:
            i, node = min(negative, key=lambda c: c[0])
            raise toks.error(f"a negative cuboid dimension in {to_text(node)}", i)
        if len(ex.hard_errors) > len(zero):  # something else than a 0.0 dimension
            others = [e for e in ex.hard_errors if not e.endswith("a dimension is <= 0")]
            raise ParseError(others[0] if others else ex.hard_errors[0], file, line, start, prog[:20])
    return ShapeRecord(key, int(m.group(1)), int(m.group(3)), line, program, ex.primitives(prec=2, orient=True))


def _check_category(category: str) -> None:
    if category not in CATEGORIES:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")


@functools.lru_cache(maxsize=None)
def _files() -> dict:
    data = resources.files("shapeprog").joinpath("data", _ARCHIVE).read_bytes()
    with tarfile.open(fileobj=io.BytesIO(lzma.decompress(data)), mode="r:") as tar:
        return {m.name.lstrip("./"): tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}


def read_lines(category: str) -> list:
    """The lines of ``PN_<category>.txt`` (1,100 strings, without newlines)."""
    _check_category(category)
    name = f"PN_{category}.txt"
    return decode(_files()[name], name).splitlines()


def _bounds(split: str, n: int) -> tuple:
    if split == "discovery":
        return 0, min(DISCOVERY_SIZE, n)
    if split == "heldout":
        return min(DISCOVERY_SIZE, n), n
    if split == "all":
        return 0, n
    raise ValueError(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")


def _parse_lines(lines: list, name: str, lo: int, hi: int) -> tuple:
    records, errors = [], []
    for n in range(lo, hi):
        try:
            records.append(parse_record(lines[n], name, n + 1))
        except ParseError as e:
            errors.append(e)
    return tuple(records), tuple(errors)


@functools.lru_cache(maxsize=None)
def _load(category: str, split: str) -> tuple:
    lines = read_lines(category)
    lo, hi = _bounds(split, len(lines))
    return _parse_lines(lines, f"PN_{category}.txt", lo, hi)


def load(category: str, split: str = "discovery", strict: bool = False) -> list:
    """The shapes of ``category`` (``'chair'``, ``'table'``, ``'storage'``) in ``split``:
    ``'discovery'`` (lines 1 to 400), ``'heldout'`` (lines 401 to 1,100) or ``'all'``, in file order.

    A line that cannot be read is skipped and reported (a :class:`DataWarning` naming
    ``file:line:column: reason`` for each) and the rest still loads; with ``strict=True`` the first error
    is raised instead. Each split is parsed once per process (the records are immutable).

    Returns:
        list of :class:`ShapeRecord`.
    """
    _check_category(category)
    _bounds(split, 0)
    records, errors = _load(category, split)
    if errors:
        if strict:
            raise errors[0]
        warnings.warn(f"{len(errors)} data line(s) skipped: " + "; ".join(str(e) for e in errors), DataWarning,
                      stacklevel=2)
    return list(records)
