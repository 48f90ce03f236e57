"""ShapeAssembly: a language of attached cuboids, its differentiable executor, corpus and metrics.

Example:
    >>> import shapeprog
    >>> p = shapeprog.parse(shapeprog.corpus.read("chair", 173), "chair/173.txt")
    >>> shape = shapeprog.execute(p)
    >>> tuple(shape.corners.shape)
    (6, 8, 3)
"""
from __future__ import annotations

import importlib

from .lang import ParseError, parse, to_text
from .execute import execute, execute_batch  # noqa: E402  (the function shadows the module name)
from .fit import fit  # noqa: E402

__all__ = ["ParseError", "parse", "to_text", "print_program", "execute", "execute_batch", "fit", "corpus"]

print_program = to_text

_LAZY = {"corpus": ("shapeprog.corpus", None)}


def __getattr__(name: str):
    # the corpus module loads on first use (it reads nothing until asked anyway)
    if name in _LAZY:
        mod, attr = _LAZY[name]
        m = importlib.import_module(mod)
        return m if attr is None else getattr(m, attr)
    raise AttributeError(f"module 'shapeprog' has no attribute {name!r}")
