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
from .hierarchy import as_hierarchy, is_hierarchy_text, parse as parse_hierarchy, rename_block
from .lang import MacroProgram, parameters
from .library import Expansion, Library, as_macro_program

__all__ = ["CompiledHierarchy", "CompiledMacroProgram", "MacroPlan", "compile_hierarchy", "compile_program", "execute",
           "execute_batch", "execute_hierarchy", "hierarchy_parameters", "program_parameters"]


def program_parameters(program: MacroProgram, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """The program's free parameters as a (P,) tensor: every number of its lines in text order, the
    bbox dims first (:func:`shapeprog.macros.lang.parameters`)."""
    program = as_macro_program(program, None, "shapeprog.macros.program_parameters")
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
    program = as_macro_program(program, library, "shapeprog.macros.compile_program")
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
        if isinstance(programs, (MacroProgram, str)):
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
    """Execute several macro programs (or their texts) together (one :class:`MacroPlan`); equal to
    :func:`execute` on each."""
    if isinstance(programs, (MacroProgram, str)):
        raise TypeError("execute_batch takes a list of macro programs; execute(program, library) runs one")
    programs = [as_macro_program(p, library, "shapeprog.macros.execute_batch") for p in programs]
    if not programs:
        return []
    if device is None and params is not None:
        device = next((t.device for t in params if t is not None), None)
    return MacroPlan(programs, library, dtype, device).run(params)


def execute(program: MacroProgram, library: Library | None = None, params: torch.Tensor | None = None,
            dtype: torch.dtype = torch.float32, device=None) -> ExecutedShape:
    """Execute a macro program.

    Args:
        program: a :class:`~shapeprog.macros.lang.MacroProgram` or its text (parsed with ``library``); a
            refactored program (:func:`shapeprog.macros.refactor`), a
            :class:`~shapeprog.macros.hierarchy.MacroHierarchy` or its text runs as :func:`execute_hierarchy`.
        library: the library its lines call (default: the base functions only).
        params: optional (P,) tensor of free parameters (:func:`program_parameters`, for a hierarchy
            :func:`hierarchy_parameters`) replacing the program's numbers; the result is differentiable in it.
        dtype, device: execution dtype and device (default: that of ``params``, else CPU).

    Returns:
        The :class:`~shapeprog.execute.ExecutedShape` of its cuboids (bbox excluded).

    Raises:
        MacroError: the program does not expand (see :meth:`Library.expand`).
        ExecutionError: a cuboid comes out non-finite.
    """
    h = as_hierarchy(program)
    if h is None and isinstance(program, str) and is_hierarchy_text(program):
        h = parse_hierarchy(program, library=library)
    if h is not None:
        return execute_hierarchy(h, library, params, dtype, device)
    program = as_macro_program(program, library, "shapeprog.macros.execute")
    return execute_batch([program], library, None if params is None else [params], dtype, device)[0]


@dataclass
class CompiledHierarchy:
    """A hierarchical macro program (:class:`~shapeprog.macros.hierarchy.MacroHierarchy`) ready for the
    ShapeAssembly executor.

    Attributes:
        blocks: each block's :class:`CompiledMacroProgram`.
        program: the hierarchical ShapeAssembly program: block ``k`` is ``blocks[k]``'s flat program with
            its cuboids named as the macro program binds them (so ``Program_k`` cuboids are sub-programs).
        sizes: each block's number of free parameters (the whole program's parameters are the blocks'
            in order).
        orders: per block, the expansion line of each statement of :attr:`program`'s block (declarations
            come first there).
        rows: per block, the (S,) indices of the block's compiled numbers in that statement order.
    """

    blocks: list
    program: Program
    sizes: list
    orders: list
    rows: list

    def numbers(self, params: torch.Tensor) -> torch.Tensor:
        """The executor's numbers of :attr:`program` for the concatenated free parameters, differentiable."""
        parts = params.split(self.sizes)
        return torch.cat([b.numbers(x)[r] for b, x, r in zip(self.blocks, parts, self.rows)])


def hierarchy_parameters(h, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """The free parameters of a hierarchical macro program: each block's (:func:`program_parameters`) in order."""
    return torch.cat([program_parameters(p, dtype, device) for p in h.programs])


def compile_hierarchy(h, library: Library | None = None) -> CompiledHierarchy:
    """Compile every block of a hierarchical macro program (:func:`compile_program`) and join the flat
    programs into one hierarchical ShapeAssembly program (corpus format)."""
    blocks = [compile_program(p, library) for p in h.programs]
    renamed = [rename_block(c.program.blocks[0], c.expansion.names, n) for c, n in zip(blocks, h.names)]
    sa = Program(tuple(b for b, _ in renamed), flat=False)
    rows = []
    for c, (_, order) in zip(blocks, renamed):
        sizes = [_N_NUMBERS[type(st).__name__] for st in c.program.blocks[0].statements]
        start = [sum(sizes[:k]) for k in range(len(sizes))]
        rows.append(torch.tensor([start[k] + j for k in order for j in range(sizes[k])], dtype=torch.long))
    return CompiledHierarchy(blocks, sa, [len(parameters(p)) for p in h.programs], [o for _, o in renamed], rows)


#: The executor's numbers per statement kind (translate's count is structure).
_N_NUMBERS = {"Cuboid": 3, "Attach": 6, "Squeeze": 2, "Reflect": 0, "Translate": 1}


def execute_hierarchy(h, library: Library | None = None, params: torch.Tensor | None = None,
                      dtype: torch.dtype = torch.float32, device=None) -> ExecutedShape:
    """Execute a hierarchical macro program with the ShapeAssembly executor (sub-programs drawn inside
    their ``Program_k`` cuboids); differentiable in ``params`` (:func:`hierarchy_parameters`) when given.
    ``ExecutedShape.line`` indexes the lines of ``to_text(compile_hierarchy(h).program)``."""
    c = compile_hierarchy(h, library)
    if params is not None and device is None:
        device = params.device
    plan = ExecutionPlan([c.program], dtype, device)
    return plan.run(None if params is None else [c.numbers(params)])[0]
