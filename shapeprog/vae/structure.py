"""Program structure: structural novelty (ShapeAssembly §7.1.3), editability counts (Table 3) and the token edit
distance of program smoothness (Table 6).

A program's *structure* is the program with every continuous number abstracted (:func:`structure_key`: each
number of :data:`shapeprog.lang.NUM_FIELDS` replaced by 0): cuboid names, the aligned flags, attach and squeeze
targets, faces, reflect and translate axes, translate counts and the block hierarchy are kept. Two programs have
the same structure when they differ only in dimensions and coordinates. :func:`structural_novelty` is the share
of programs whose structure is no training program's; a changed number alone is not novel (unlike the text
novelty :func:`shapeprog.vae.genmetrics.novelty`, which compares numbers to 3 decimals).

Standard library, NumPy and the language only: no model is imported.
"""
from __future__ import annotations

import itertools
import re
from functools import lru_cache
from typing import Iterable, Optional, Sequence

import numpy as np

from ..lang import Program, Reflect, Translate, parse, replace_numbers, round_numbers, to_text
from ..syntax import Cuboid

__all__ = ["STRUCTURE_VALUE", "structure_key", "training_structures", "structural_novelty", "program_tokens",
           "edit_distance", "EDITABILITY_KEYS", "editability", "mean_editability"]

#: The value every continuous number takes in a structure key.
STRUCTURE_VALUE = 0.0
#: A token of a program text: a name, number or keyword, or one punctuation character.
_TOKEN = re.compile(r"[^\s(),={}]+|[(),={}]")


def _program(item, what: str) -> Program:
    """``item`` as a Program: a Program as it is, a text parsed with ``what`` as its file name in errors (the
    programs' reader of this module and of :mod:`shapeprog.vae.genmetrics`)."""
    if isinstance(item, Program):
        return item
    if isinstance(item, str):
        return parse(item, file=what)
    raise TypeError(f"{what}: expected a shapeprog Program or program text, got {type(item).__name__}")


def structure_key(item) -> str:
    """The text of ``item`` (a :class:`~shapeprog.lang.Program` or program text) with every continuous number
    replaced by :data:`STRUCTURE_VALUE`: equal for two programs that differ only in their numbers.

    Raises:
        ParseError: a text that does not parse.
        TypeError: neither a program nor a text.
    """
    return to_text(replace_numbers(_program(item, "<program>"), itertools.repeat(STRUCTURE_VALUE)))


@lru_cache(maxsize=8)
def training_structures(category: str) -> frozenset:
    """The structure keys of a category's corpus train split (read once per process)."""
    from .. import corpus  # lazy: the corpus archive is opened only when a category is asked for

    if category not in corpus.CATEGORIES:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(corpus.CATEGORIES)}")
    return frozenset(structure_key(p) for _, p in corpus.load(category, "train"))


def structural_novelty(programs: Iterable, category: Optional[str] = None,
                       training: Optional[Iterable] = None) -> float:
    """The fraction (0 to 1) of ``programs`` whose structure (:func:`structure_key`) no training program has.

    Args:
        programs: programs or program texts (a text that does not parse is an error: pass valid programs).
        category: the corpus category whose train split is the training set.
        training: instead of ``category``, the training programs (or texts) themselves.

    Raises:
        ValueError: no program, or neither / both of ``category`` and ``training`` given.
        ParseError: a text that does not parse.
    """
    if (category is None) == (training is None):
        raise ValueError("give either category or training (the training programs), not both or neither")
    known = training_structures(category) if training is None else {structure_key(p) for p in training}
    keys = [structure_key(p) for p in programs]
    if not keys:
        raise ValueError("structural_novelty: no program to measure")
    return sum(k not in known for k in keys) / len(keys)


# --------------------------------------------------------------------------------------------------
# token edit distance (program smoothness)


def program_tokens(item) -> list[str]:
    """The tokens of a program's text with its numbers rounded to the corpus's 3 decimals: names, keywords,
    numbers and each of ``( ) , = { }``."""
    return _TOKEN.findall(to_text(round_numbers(_program(item, "<program>"))))


def edit_distance(a: Sequence, b: Sequence) -> int:
    """The Levenshtein distance between two token sequences (insertions, deletions and substitutions cost 1).

    One NumPy row per token of ``a``: substitutions and deletions are vectorised, insertions are a running
    minimum along the row (``cur[j] = min_k (d[k] + j - k)``).
    """
    a, b = list(a), list(b)
    if len(a) < len(b):
        a, b = b, a
    if not b:
        return len(a)
    vocab: dict = {}
    ia = np.array([vocab.setdefault(t, len(vocab)) for t in a])
    ib = np.array([vocab.setdefault(t, len(vocab)) for t in b])
    span = np.arange(len(ib) + 1)
    prev = span.copy()
    for i, t in enumerate(ia, 1):
        d = np.empty_like(prev)
        d[0] = i
        d[1:] = np.minimum(prev[1:] + 1, prev[:-1] + (ib != t))
        prev = np.minimum.accumulate(d - span) + span
    return int(prev[-1])


# --------------------------------------------------------------------------------------------------
# editability


#: The figures :func:`editability` gives per program, in table order.
EDITABILITY_KEYS = ("lines", "blocks", "cuboid_lines", "attach_lines", "squeeze_lines", "reflect_lines",
                    "translate_lines", "macro_lines", "macro_parts")


def editability(item) -> dict:
    """How much of a program a person edits: its line counts and the share made by macro-like lines.

    ``lines``: statements over all blocks (each block's bbox line included; the ``Assembly`` wrappers not);
    ``blocks``; per kind, the lines of ``Cuboid`` / ``attach`` / ``squeeze`` / ``reflect`` / ``translate``;
    ``macro_lines``: the percentage of lines that are squeeze, reflect or translate (one line placing or copying
    parts that attach lines would spell out); ``macro_parts``: the percentage of part instances (each block's
    non-bbox Cuboid lines plus the copies reflect (1) and translate (``n``) make) created by reflect and
    translate.
    """
    p = _program(item, "<program>")
    counts = dict.fromkeys(("cuboid_lines", "attach_lines", "squeeze_lines", "reflect_lines", "translate_lines"), 0)
    declared = copies = 0
    for b in p.blocks:
        for j, s in enumerate(b.statements):
            kind = type(s).__name__.lower()
            counts[f"{kind}_lines"] += 1
            if isinstance(s, Cuboid) and j > 0:
                declared += 1
            elif isinstance(s, Reflect):
                copies += 1
            elif isinstance(s, Translate):
                copies += s.n
    lines = sum(counts.values())
    macro = counts["squeeze_lines"] + counts["reflect_lines"] + counts["translate_lines"]
    return {"lines": lines, "blocks": len(p.blocks), **counts,
            "macro_lines": 100.0 * macro / lines if lines else 0.0,
            "macro_parts": 100.0 * copies / (declared + copies) if declared + copies else 0.0}


def mean_editability(programs: Iterable) -> dict:
    """The mean of :func:`editability` over ``programs`` (``programs`` key: how many); texts that do not parse
    are an error."""
    stats = [editability(p) for p in programs]
    if not stats:
        raise ValueError("mean_editability: no program to measure")
    return {"programs": len(stats), **{k: float(np.mean([s[k] for s in stats])) for k in EDITABILITY_KEYS}}

