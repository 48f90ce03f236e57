"""ShapeAssembly: a language of attached cuboids, its differentiable executor, corpus and metrics.

Example:
    >>> import shapeprog
    >>> p = shapeprog.parse(shapeprog.corpus.read("chair", 173), "chair/173.txt")
    >>> shape = shapeprog.execute(p)
    >>> tuple(shape.corners.shape)
    (6, 8, 3)
"""
from __future__ import annotations

from . import corpus  # cheap: reads nothing until asked
from .errors import ExecutionError, ParseError
from .lang import parse, to_text
from .execute import execute, execute_batch  # the function shadows the module name
from .fit import fit

__all__ = ["ExecutionError", "ParseError", "parse", "to_text", "print_program", "execute", "execute_batch", "fit", "corpus"]

print_program = to_text
