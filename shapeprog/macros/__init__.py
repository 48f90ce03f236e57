"""ShapeMOD on ShapeAssembly: sub-programs and their orderings, a typed macro language and library.

* :mod:`~shapeprog.macros.grammar`: the modified grammar (lines with an implicit subject), signatures.
* :mod:`~shapeprog.macros.data`: corpus programs as sub-programs, their orderings O_P and signatures.
* :mod:`~shapeprog.macros.lang`: the text of macro programs (typed macros and the lines calling them).
* :mod:`~shapeprog.macros.library`: a :class:`Library` of base functions and macros; expansion.
* :mod:`~shapeprog.macros.execute`: differentiable execution through the ShapeAssembly executor.
* :mod:`~shapeprog.macros.objective`: the objective f, least-squares fits, the best-program search.
* :mod:`~shapeprog.macros.proposal`: clusters, abstracted programs, candidate macros, generalisation.
* :mod:`~shapeprog.macros.discover`: discovery rounds (greedy or milp selection), resumable, any executor.
* :mod:`~shapeprog.macros.baseline`: the paper's baseline macros; :mod:`~shapeprog.macros.table1`: Table 1.
* :mod:`~shapeprog.macros.api`: :func:`load_library`, :func:`refactor`, :func:`expand`, :func:`collection`.
* :mod:`~shapeprog.macros.refactored`: a category's corpus refactored with a library, written and read
  back (:func:`refactor_corpus`, ``python -m shapeprog refactor-corpus``); :mod:`~shapeprog.macros.perturb`:
  perturbed execution of macro programs (the paper's Fig. 7).
* :mod:`~shapeprog.macros.hierarchy`: hierarchical macro programs (one per sub-program), the text
  ``refactor -o`` writes and the editor reads.

The data decisions and the language: ``docs/shapemod.md``.

Example:
    >>> from shapeprog import macros
    >>> lib = macros.Library.from_text("def post(h: float):\\n    c = Cuboid(0.1, h, 0.1, True)\\n"
    ...                                "    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> p = macros.parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\np0 = post(0.5)\\n", lib)
    >>> macros.execute(p, lib).dims.tolist()
    [[0.10000000149011612, 0.5, 0.10000000149011612]]
    >>> print(macros.to_text(lib.inline(p)), end="")
    bbox = Cuboid(1.0, 1.0, 1.0, True)
    p0 = Cuboid(0.1, 0.5, 0.1, True)
    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)
"""
from __future__ import annotations

from .data import Conversion, CorpusData, Failure, convert_corpus, convert_program, order_errors
from .subprogram import Cube, Ordering, SubProgram
from .api import BlockRefactor, Refactored, collection, expand, load_library, program_stats, refactor
from .execute import execute, execute_batch, program_parameters
from .lang import Call, Linear, Literal, MacroDef, MacroError, MacroProgram, Name, Param, from_lines, to_text
from .library import Library, parse
from .refactored import load_refactored, read_refactored, refactor_corpus, write_refactored

__all__ = [  # by the module each name comes from, in the order of the imports above
    "Conversion", "CorpusData", "Failure", "convert_corpus", "convert_program", "order_errors",
    "Cube", "Ordering", "SubProgram",
    "BlockRefactor", "Refactored", "collection", "expand", "load_library", "program_stats", "refactor",
    "execute", "execute_batch", "program_parameters",
    "Call", "Linear", "Literal", "MacroDef", "MacroError", "MacroProgram", "Name", "Param", "from_lines", "to_text",
    "Library", "parse",
    "load_refactored", "read_refactored", "refactor_corpus", "write_refactored",
]
