"""Fuzz target for the ShapeCoder data-line reader: parser, executor and primitives in one
(``shapeprog.coder.data.parse_record``), with a seeded mutator over real data lines.

``mutate(rng, text)`` returns a variant of a data line (numbers, tokens, wrapped sub-expressions,
characters); ``run(data)`` reads it and returns the primitives' numbers. Only ParseError may escape; the
printed program must parse back to itself.
"""
from __future__ import annotations

import random
import re

from shapeprog.coder import data as scdata
from shapeprog.coder.lang import parse, to_text
from shapeprog.coder.limits import MAX_ABS_NUMBER, MAX_COUNT
from shapeprog.errors import ParseError, RefactorError
from shapeprog.limits import decode

from fuzz.engine import Target, mutate as mutate_bytes

__all__ = ["BOUND_S", "TARGETS", "mutate", "run", "run_dream_rules", "run_refactor", "seeds"]

#: The longest one input may take (on a loaded 2-core machine).
BOUND_S = 3.0

_NUMBERS = ["0", "0.0", "-0.0", "1", "2.0", "0.5", "-0.5", "1e-30", "1e308", "nan", "inf", "-", ".", "1.2.3",
            str(MAX_ABS_NUMBER), str(-MAX_ABS_NUMBER), "1000.0001", "9" * 400, "3.14", "-3.14", "1e2", "+.5"]
_TOKENS = ["(", ")", ",", ":", "=", "Cuboid", "Move", "Rotate", "Union", "SymRef", "SymTrans", "Add", "Sub",
           "Mul", "Div", "Inv", "AX", "AY", "AZ", "INT#1#", f"INT#{MAX_COUNT}#", f"INT#{MAX_COUNT + 1}#", "INT#",
           "x", "S_0_0_", "Rectangle", "#", ";", "\u0663", "\xff", "\n", " "]
_WRAPS = ["SymRef({},AX)", "SymRef({},AZ)", f"SymTrans({{}},AY,INT#{MAX_COUNT}#,1.5)", "SymTrans({},AX,INT#3#,-1)",
          "Rotate({},AY,1.6)", "Rotate({},AX,3.14)", "Move({},1000,-1000,0)", "Union({},{})"]
_EXTRA = ["0_0_0:SymTrans(SymRef(Move(Cuboid(0.1,0.2,0.3),-0.4,0,0),AX),AZ,INT#3#,Mul(0.5,2))",
          "1_0_1:Cuboid(Add(0.1,Inv(-0.2)),Sub(1,0.5),Div(1,4))",
          "2_0_2:Rotate(Rotate(Rotate(Cuboid(0.5,0.2,0.8),AX,0.9),AY,-0.4),AZ,3.1)"]
_NUMBER = re.compile(r"(?<![\w.#])-?\d+\.\d+")
_CALL = re.compile(r"(?:Move|Rotate|Cuboid|SymRef|SymTrans)\(")


def seeds(n: int = 24, seed: int = 0) -> list[str]:
    """``n`` data lines (every category), chosen with ``seed``, plus a few lines using every function."""
    rng = random.Random(seed)
    lines = []
    for cat in scdata.CATEGORIES:
        lines += rng.sample(scdata.read_lines(cat), n // len(scdata.CATEGORIES))
    return lines + _EXTRA


def _sub_expression(text: str, start: int) -> int:
    """The end of the call starting at ``start`` (matching parentheses), or -1."""
    depth = 0
    for k in range(text.index("(", start), len(text)):
        depth += {"(": 1, ")": -1}.get(text[k], 0)
        if depth == 0:
            return k + 1
    return -1


def mutate(rng: random.Random, text: str) -> str:
    """One to four edits of a data line: a number, a token, a wrapped sub-expression or a character."""
    for _ in range(rng.randint(1, 4)):
        kind = rng.randrange(4)
        if kind == 0:
            spans = [m.span() for m in _NUMBER.finditer(text)]
            if spans:
                a, b = rng.choice(spans)
                value = rng.choice(_NUMBERS) if rng.random() < 0.5 else repr(round(rng.uniform(-3, 3), 2))
                text = text[:a] + value + text[b:]
        elif kind == 1:
            words = re.split(r"([(),])", text)
            k = rng.randrange(len(words))
            words[k] = rng.choice(_TOKENS)
            text = "".join(words)
        elif kind == 2:
            calls = [m.start() for m in _CALL.finditer(text)]
            if calls:
                a = rng.choice(calls)
                b = _sub_expression(text, a)
                if b > 0:
                    text = text[:a] + rng.choice(_WRAPS).replace("{}", text[a:b]) + text[b:]
        else:
            k = rng.randrange(len(text) + 1)
            text = text[:k] + rng.choice(["", " ", "(", ")", ",", "-", "e", "9", ".", "\x00"]) + text[k + 1:]
    return text


def run(data: bytes) -> list:
    """Read one data line (bytes, UTF-8); the numbers of its primitives. Only ParseError may escape."""
    rec = scdata.parse_record(decode(data, "fuzz.txt"), "fuzz.txt", 1)
    assert parse(to_text(rec.program)) == rec.program, "to_text does not round-trip"
    return [v for p in rec.prims for v in p]


def _mutator(data: bytes, rng: random.Random, seeds_: list) -> bytes:
    if rng.random() < 0.2:
        return mutate_bytes(data, rng, seeds_)
    return mutate(rng, data.decode("utf-8", "surrogatepass")).encode("utf-8", "surrogatepass")


def run_refactor(data: bytes) -> list:
    """Read one data line and refactor its program with the semantic rewrites (small limits); the
    refactored program must re-cover the line's primitives. Only ParseError and RefactorError may escape."""
    from shapeprog.coder.execute import execute
    from shapeprog.coder.objective import match
    from shapeprog.coder.refactor import refactor

    rec = scdata.parse_record(decode(data, "fuzz.txt"), "fuzz.txt", 1)
    if len(rec.prims) > 16 or any(min(p[:3]) <= 0 for p in rec.prims):
        return [v for p in rec.prims for v in p]  # beyond the scenes discovery takes, or a hard error
    r = refactor(rec.program, iterations=3, max_nodes=3000, time_limit=1.0)
    got = execute(r.expr, strict=False)
    assert len(got) == len(rec.prims) and match(got, rec.prims).valid, "the refactor changed the primitives"
    return [v for p in got for v in p] + [r.cost]


def run_dream_rules(data: bytes) -> list:
    """Read one data line and check its program against the dream rejection rules
    (``shapeprog.coder.dream.reject_reason``); the reason must be one of ``REJECTIONS`` or None, and a
    valid dream must keep every primitive within the bounds. Only ParseError may escape."""
    from shapeprog.coder.dream import BOUND, REJECTIONS, reject_reason
    from shapeprog.coder.execute import corners

    rec = scdata.parse_record(decode(data, "fuzz.txt"), "fuzz.txt", 1)
    why = reject_reason(rec.program)
    assert why is None or why in REJECTIONS, f"unknown reason {why!r}"
    if why is None:
        assert len(rec.prims) <= 16 and abs(corners(rec.prims)).max() <= BOUND + 1e-9, "a valid dream out of bounds"
    return [REJECTIONS.index(why) if why else -1]


TARGETS = [Target("shapecoder/data-line", [t.encode() for t in seeds()], run, (ParseError,), BOUND_S, _mutator),
           Target("shapecoder/refactor", [t.encode() for t in seeds(6)], run_refactor, (ParseError, RefactorError),
                  BOUND_S, _mutator),
           Target("shapecoder/dream-rules", [t.encode() for t in seeds(6)], run_dream_rules, (ParseError,), BOUND_S,
                  _mutator)]
