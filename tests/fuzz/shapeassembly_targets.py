"""Fuzz target for the ShapeAssembly parser and executor: a seeded mutator over corpus programs.

``mutate(rng, seed_text)`` returns a variant of a real program (token, number, line and byte edits that
aim at the language's limits); ``run(data)`` parses and executes it and returns the executed shape's
numbers. The fuzz engine (``tests/fuzz/engine.py``) counts as findings any exception other than the
project's own (ParseError, ExecutionError), an input slower than :data:`BOUND_S`, and a non-finite number.
"""
from __future__ import annotations

import random
import re
import warnings

import torch

from shapeprog import corpus
from shapeprog.errors import ExecutionError, ParseError, ParseWarning
from shapeprog.execute import execute
from shapeprog.lang import parse, to_text
from shapeprog.limits import MAX_ABS_NUMBER, MAX_TRANSLATE_COPIES, decode

from fuzz.engine import Target

__all__ = ["BOUND_S", "TARGETS", "mutate", "run", "seeds"]

_SHAPE_FIELDS = ("centers", "dims", "axes", "corners", "root_dims")

#: The longest one parse and execution may take (on a loaded 2-core machine).
BOUND_S = 6.0

_NUMBERS = ["0", "0.0", "-0.0", "1", "1.0", "0.5", "1e-30", "-1e-30", "1e308", "1e999", "-1e999", "nan", "inf",
            str(MAX_ABS_NUMBER), str(-MAX_ABS_NUMBER), "1000.0001", "9" * 400, "1e25", "3.4e38", ".5", "5.",
            str(MAX_TRANSLATE_COPIES), str(MAX_TRANSLATE_COPIES + 1), "100000000"]
_TOKENS = ["(", ")", ",", "=", "{", "}", "bbox", "cube0", "cube1", "cube3", "Program_1", "Program_0", "Cuboid",
           "attach", "squeeze", "reflect", "translate", "X", "Y", "Z", "top", "bot", "True", "False", "Assembly"]
_IN_RANGE = ["0.0", "1.0", "0.5", "1e-30", "-1e-30", "1000.0", "-1000.0", "999.999", "1e-45", "0.001", "-0.5", "2.0"]
_NUMBER = re.compile(r"(?<![\w.])-?\d+\.\d+(?:e-?\d+)?")
_LINES = ["reflect(cube0, X)", "translate(cube0, Y, 200, 0.9)", "translate(cube1, X, 256, 0.5)",
          "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)", "cube2 = Cuboid(0.0, 0.0, 0.0, False)",
          "squeeze(cube0, bbox, cube1, top, 0.5, 0.5)", "bbox = Cuboid(0.0, 1.0, 1.0, True)",
          "Program_1 = Cuboid(0.5, 0.5, 0.5, False)", "}", "Assembly Program_1 {"]


def seeds(n: int = 64, seed: int = 0) -> list[str]:
    """``n`` corpus programs (every category), chosen with ``seed``, plus the flat example file."""
    rng = random.Random(seed)
    texts = [corpus.example_text("ex-0.txt")]
    for cat in corpus.CATEGORIES:
        ids = corpus.ids(cat, "all")
        texts += [corpus.read(cat, i) for i in rng.sample(ids, n // len(corpus.CATEGORIES))]
    return texts


def mutate(rng: random.Random, seed_text: str) -> str:
    """One to four random edits of ``seed_text``: numbers, tokens, whole lines, duplicated lines, bytes.

    Half of the variants change only numbers, to values inside the language's range, so that they
    still parse and reach the executor.
    """
    if rng.random() < 0.5:
        spans = [m.span() for m in _NUMBER.finditer(seed_text)]
        for a, b in sorted(rng.sample(spans, min(len(spans), rng.randint(1, 6))), reverse=True):
            value = rng.choice(_IN_RANGE) if rng.random() < 0.7 else repr(rng.uniform(-3, 3))
            seed_text = seed_text[:a] + value + seed_text[b:]
        return seed_text
    lines = seed_text.split("\n")
    for _ in range(rng.randint(1, 4)):
        i = rng.randrange(len(lines))
        kind = rng.randrange(7)
        words = lines[i].replace("(", " ( ").replace(")", " ) ").replace(",", " , ").split()
        if kind == 0 and words:  # replace a token by a number
            words[rng.randrange(len(words))] = rng.choice(_NUMBERS)
            lines[i] = "\t" + " ".join(words)
        elif kind == 1 and words:  # replace a token by a keyword or punctuation
            words[rng.randrange(len(words))] = rng.choice(_TOKENS)
            lines[i] = "\t" + " ".join(words)
        elif kind == 2:  # insert a line
            lines.insert(i, "\t" + rng.choice(_LINES))
        elif kind == 3:  # delete a line
            del lines[i]
            if not lines:
                lines = [""]
        elif kind == 4:  # duplicate a stretch of lines
            j = rng.randrange(i, min(len(lines), i + 8) + 1)
            lines[j:j] = lines[i:j] * rng.randint(1, 40)
        elif kind == 5:  # swap two lines
            j = rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        else:  # a character edit
            text = lines[i]
            k = rng.randrange(len(text) + 1)
            lines[i] = text[:k] + rng.choice(["\xff", "\x00", "\u0663", "\r", " ", "-", "e", "9", ".", ""]) + text[k + 1:]
    return "\n".join(lines)


def run(data: bytes) -> list[float]:
    """Parse and execute one input (bytes, decoded as the CLI decodes files); the numbers of the executed
    shape. Only ParseError and ExecutionError may escape; the printed program must parse back to itself."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ParseWarning)  # a stray comma is a warning, not a finding
        program = parse(decode(data, "fuzz.txt"), "fuzz.txt")
    with torch.no_grad():
        shape = execute(program)
    assert parse(to_text(program)) == program, "to_text does not round-trip"
    return torch.cat([getattr(shape, n).reshape(-1) for n in _SHAPE_FIELDS]).tolist()


def _mutate_bytes(data: bytes, rng: random.Random, _seeds) -> bytes:
    return mutate(rng, data.decode("utf-8", "surrogatepass")).encode("utf-8", "surrogatepass")


TARGETS = [Target("shapeassembly/text", [t.encode() for t in seeds(n=24)], run, (ParseError, ExecutionError),
                  BOUND_S, _mutate_bytes)]
