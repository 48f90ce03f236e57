"""The VAE's training data: a category's corpus programs as line-vector trees (:func:`load_trees`), the
seeded validation carve-out of the corpus's train split (:func:`validation_split`), and the
macro-refactored programs with their library (:func:`load_macro_trees`, :func:`load_macro_library`).
:class:`shapeprog.vae.train.VAEDataModule` serves them.
"""
from __future__ import annotations

import warnings

import numpy as np
import torch

from .. import corpus
from ..errors import ParseError
from ..lang import parse
from ..macros.api import load_library
from ..macros.refactored import load_refactored, read_refactored
from .layout import LineLayout, MacroNode, macro_program_to_tree
from .vectors import VectorNode, program_to_tree

__all__ = [
    "CATEGORIES",
    "load_macro_library",
    "load_macro_trees",
    "load_trees",
    "validation_split",
]


#: The categories a run trains on: one of the corpus's, or all three together.
CATEGORIES = corpus.CATEGORIES + ("all",)


def _check_category(category: str) -> None:
    if category not in CATEGORIES:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")


# ------------------------------------------------------------------------------------------ data


def validation_split(category: str, fraction: float = 0.05, count: int | None = None,
                     seed: int = 42) -> tuple[list[str], list[str]]:
    """A seeded validation carve-out of the corpus's train split.

    Args:
        category: ``chair``, ``table``, ``storage`` or ``all`` (each category carved on its own).
        fraction: the share of each category's train split held out (rounded, at least 1).
        count: held-out shapes per category instead of ``fraction``.
        seed: the draw; a category's draw depends only on ``seed`` and the category.

    Returns:
        ``(train, val)``: program keys ``"chair/173"``, each in the corpus's split-file order.
    """
    _check_category(category)
    if count is None and not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must be in (0, 1), got {fraction!r}")
    train, val = [], []
    for cat in corpus.CATEGORIES if category == "all" else (category,):
        ids = corpus.ids(cat, "train")
        n = max(1, round(fraction * len(ids))) if count is None else int(count)
        if not 0 < n < len(ids):
            raise ValueError(f"cannot hold out {n} of the {len(ids)} {cat} training shapes")
        rng = np.random.default_rng([int(seed), corpus.CATEGORIES.index(cat)])
        held = set(rng.choice(len(ids), size=n, replace=False).tolist())
        val += [f"{cat}/{i}" for k, i in enumerate(ids) if k in held]
        train += [f"{cat}/{i}" for k, i in enumerate(ids) if k not in held]
    return train, val


def load_trees(keys: list[str], dtype: torch.dtype = torch.float32) -> tuple[list[str], list[VectorNode]]:
    """The line-vector trees of corpus programs ``"category/id"``.

    A program that does not parse or cannot be encoded (:func:`~shapeprog.vae.vectors.program_to_tree`) is
    left out and named in a :class:`~shapeprog.corpus.CorpusWarning`; the rest still load.

    Returns:
        ``(keys, trees)`` of the programs loaded, in the order given.
    """
    kept, trees, errors = [], [], []
    for key in keys:
        cat, i = key.split("/")
        name = f"{key}.txt"
        try:
            trees.append(program_to_tree(parse(corpus.read(cat, i), file=name), file=name, dtype=dtype))
            kept.append(key)
        except (ParseError, KeyError) as e:
            errors.append(f"{name}: {e}")
    if errors:
        warnings.warn(f"{len(errors)} program(s) left out: " + "; ".join(errors), corpus.CorpusWarning, stacklevel=2)
    return kept, trees


def load_macro_library(library: str):
    """The macro library a run trains with: :func:`shapeprog.macros.load_library` (a library file when one
    exists at that path, else a shipped category's, e.g. ``"chair"``).

    Raises:
        NotShippedError: neither a file nor a shipped library (a ``FileNotFoundError``).
        ParseError: the file does not parse (named, with line and column).
    """
    return load_library(library)


def load_macro_trees(keys: list[str], layout: LineLayout, programs: dict,
                     dtype: torch.dtype = torch.float32) -> tuple[list[str], list[MacroNode]]:
    """The line-vector trees of the macro programs of ``keys`` (``"chair/173"``), taken from ``programs``
    (``{id: MacroHierarchy}`` of one category, :func:`shapeprog.macros.read_refactored`).

    A key without a program (its refactoring failed) or whose program cannot be encoded is left out and named
    in a :class:`~shapeprog.corpus.CorpusWarning`.

    Returns:
        ``(keys, trees)`` of the programs loaded, in the order given.
    """
    kept, trees, errors = [], [], []
    for key in keys:
        i = int(key.split("/")[1])
        if i not in programs:
            errors.append(f"{key}: no macro program")
            continue
        try:
            trees.append(macro_program_to_tree(programs[i], layout, file=f"{key}.txt", dtype=dtype))
            kept.append(key)
        except ParseError as e:
            errors.append(str(e))
    if errors:
        warnings.warn(f"{len(errors)} program(s) left out: " + "; ".join(errors[:20])
                      + (" ..." if len(errors) > 20 else ""), corpus.CorpusWarning, stacklevel=2)
    return kept, trees


def _read_macro_programs(category: str, keys: list[str], programs: str | None, library) -> dict:
    ids = sorted({int(k.split("/")[1]) for k in keys})
    if programs is None:
        return load_refactored(category, ids=ids)[0]
    return read_refactored(programs, library=library, ids=ids)[0]
