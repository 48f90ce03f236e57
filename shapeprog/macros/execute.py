"""Execution of macro programs through the ShapeAssembly executor, differentiably.

A program is expanded to base lines (:meth:`shapeprog.macros.library.Library.expand`), written as a
flat ShapeAssembly program (:func:`shapeprog.macros.grammar.to_shapeassembly`) and run by
:class:`shapeprog.execute.ExecutionPlan`. The executor's numbers are an affine function of the
program's free parameters (every number of the program's lines, :func:`program_parameters`):
``numbers = A @ params + b``, so gradients reach the parameters, and through them the macros'
free float parameters, whatever the nesting. A translate count is structure: it is taken from the
program's own numbers and gets no gradient.

Example:
    >>> import torch
    >>> from shapeprog.macros.library import Library
    >>> lib = Library.from_text("def slab(h: float):\\n    c = Cuboid(bb_x, h, bb_z, True)\\n"
    ...                         "    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> p = lib.parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ns = slab(0.2)\\n")
    >>> x = program_parameters(p).requires_grad_(True)
    >>> shape = execute(p, lib, params=x)
    >>> shape.centers.tolist()
    [[0.0, -0.4000000059604645, 0.0]]
    >>> shape.centers[0, 1].backward(); x.grad.tolist()  # centre y = -bb_y / 2 + h / 2
    [0.0, -0.5, 0.0, 0.5]
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..execute import ExecutedShape, ExecutionPlan
from ..lang import Program
from .grammar import TranslateLine, to_shapeassembly
from .lang import MacroProgram, parameters
from .library import Expansion, Library

__all__ = ["CompiledMacroProgram", "MacroPlan", "compile_program", "execute", "execute_batch", "program_parameters"]


def program_parameters(program: MacroProgram, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """The program's free parameters as a (P,) tensor: every number of its lines in text order, the
    bbox dims first (:func:`shapeprog.macros.lang.parameters`)."""
    return torch.tensor(parameters(program), dtype=dtype, device=device)


@dataclass
class CompiledMacroProgram:
    """A macro program ready for the ShapeAssembly executor.

    Attributes:
        expansion: its base lines (:class:`~shapeprog.macros.library.Expansion`).
        program: the flat ShapeAssembly program of the expansion (statement i = base line i).
        matrix: (S, P) float64, the executor's numbers (S, text order of ``program``) as a linear
            function of the P free parameters.
        offset: (S,) float64, the constant part.
    """

    expansion: Expansion
    program: Program
    matrix: torch.Tensor
    offset: torch.Tensor

    def numbers(self, params: torch.Tensor) -> torch.Tensor:
        """(S,) the executor's numbers for free parameters ``params`` (P,), differentiable."""
        P = self.matrix.shape[1]
        if params.dim() != 1 or params.shape[0] != P:
            raise ValueError(f"`params` must have shape ({P},), got {tuple(params.shape)}")
        m = self.matrix.to(dtype=params.dtype, device=params.device)
        return m @ params + self.offset.to(dtype=params.dtype, device=params.device)


def compile_program(program: MacroProgram, library: Library | None = None) -> CompiledMacroProgram:
    """Expand ``program`` with ``library`` (plus the program's own definitions) for execution."""
    lib = Library() if library is None else library
    exp = lib.expand(program)
    sa = to_shapeassembly(exp.lines, check=False)
    P = len(parameters(program))
    rows = [f for line, forms in zip(exp.lines, exp.floats)
            for f in (forms[1:] if type(line) is TranslateLine else forms)]  # translate n is not a number
    matrix = torch.zeros(len(rows), P, dtype=torch.float64)
    offset = torch.zeros(len(rows), dtype=torch.float64)
    for r, f in enumerate(rows):
        offset[r] = f.const
        for i, c in f.terms:
            matrix[r, i] += c
    return CompiledMacroProgram(exp, sa, matrix, offset)


class MacroPlan:
    """Macro programs compiled once and executed many times (the macro twin of
    :class:`shapeprog.execute.ExecutionPlan`).

    Args:
        programs: macro programs.
        library: the library they call (their own definitions are added per program).
        dtype, device: execution dtype and device.
    """

    def __init__(self, programs: list[MacroProgram], library: Library | None = None,
                 dtype: torch.dtype = torch.float32, device=None):
        if isinstance(programs, MacroProgram):
            raise TypeError("`programs` must be a list of programs; use MacroPlan([program])")
        self.compiled = [compile_program(p, library) for p in programs]
        self.plan = ExecutionPlan([c.program for c in self.compiled], dtype, device)

    def __len__(self) -> int:
        return len(self.compiled)

    def run(self, params: list[torch.Tensor | None] | None = None) -> list[ExecutedShape]:
        """Execute with the programs' own numbers or with ``params`` (one (P_i,) tensor or None per
        program); the result is differentiable in the given tensors. ``ExecutedShape.line`` indexes
        the expansion's lines; ``compiled[i].expansion.source`` maps them to program lines."""
        if params is None:
            return self.plan.run()
        if len(params) != len(self.compiled):
            raise ValueError(f"`params` must hold {len(self.compiled)} tensors, got {len(params)}")
        nums = [None if p is None else c.numbers(p) for c, p in zip(self.compiled, params)]
        return self.plan.run(nums)


def execute_batch(programs: list[MacroProgram], library: Library | None = None,
                  params: list[torch.Tensor | None] | None = None, dtype: torch.dtype = torch.float32,
                  device=None) -> list[ExecutedShape]:
    """Execute several macro programs together (one :class:`MacroPlan`); equal to :func:`execute` on each."""
    if not programs:
        return []
    if device is None and params is not None:
        device = next((t.device for t in params if t is not None), None)
    return MacroPlan(programs, library, dtype, device).run(params)


def execute(program: MacroProgram, library: Library | None = None, params: torch.Tensor | None = None,
            dtype: torch.dtype = torch.float32, device=None) -> ExecutedShape:
    """Execute a macro program.

    Args:
        program: a parsed :class:`~shapeprog.macros.lang.MacroProgram`.
        library: the library its lines call (default: the base functions only).
        params: optional (P,) tensor of free parameters (:func:`program_parameters`) replacing the
            program's numbers; the result is differentiable in it.
        dtype, device: execution dtype and device (default: that of ``params``, else CPU).

    Returns:
        The :class:`~shapeprog.execute.ExecutedShape` of its cuboids (bbox excluded).

    Raises:
        MacroError: the program does not expand (see :meth:`Library.expand`).
        ExecutionError: a cuboid comes out non-finite.
    """
    return execute_batch([program], library, None if params is None else [params], dtype, device)[0]
