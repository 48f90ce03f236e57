"""The size limits of the ShapeCoder language, its executor and its data files. Standard library only.

A program text beyond a limit is refused with a :class:`~shapeprog.errors.ParseError` naming the place
(file, line, column, token) before anything is built; an expression tree beyond a limit is refused by
:func:`shapeprog.coder.lang.check` (:class:`~shapeprog.coder.lang.ProgramError`) or by the executor
(:class:`~shapeprog.coder.execute.ExecutionError`). The limits bound parsing, expansion and execution time;
each leaves a wide margin above the published data (the maxima are given beside them).

Example:
    >>> MAX_PARTS, MAX_COUNT
    (1000, 256)
"""
from __future__ import annotations

__all__ = ["MAX_ABSTRACTIONS", "MAX_ABS_NUMBER", "MAX_COUNT", "MAX_DEPTH", "MAX_NODES", "MAX_PARTS", "MAX_TEXT_LENGTH"]

#: Characters of one program text, or of one line of a data file (data maximum: 1,398).
MAX_TEXT_LENGTH = 100_000
#: Nesting depth of an expression, the root at depth 1, also of an abstraction's body with the abstractions it
#: calls expanded (data maximum: 21).
MAX_DEPTH = 256
#: Abstractions of a library (shipped maximum: 30).
MAX_ABSTRACTIONS = 256
#: Nodes of an expression tree, also after expanding abstractions (checked for every abstraction when it joins a
#: library; data maximum: 245).
MAX_NODES = 100_000
#: Magnitude of a number literal (data maximum: 2.06).
MAX_ABS_NUMBER = 1000.0
#: The count ``k`` of ``INT#k#`` (``SymTrans`` copies; the reference samples 1 to 6).
MAX_COUNT = 256
#: Parts of an executed shape (data maximum: 16).
MAX_PARTS = 1000
