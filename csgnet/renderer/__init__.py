"""The batched stack renderer of CSG programs, in PyTorch (CPU or GPU).

Programs arrive as token-index tensors ``(B, T)`` of mixed lengths (``$`` or any index after it pads), or
as :class:`~csgnet.lang.Program` objects with arbitrary integer parameters. The result is exact to the
pixel and voxel against the per-program NumPy path (:mod:`csgnet.renderer.reference`), because both evaluate the
shared geometry of :mod:`csgnet.primitives`.

How it is fast: canvases are bit-packed. A 2D image is 64 int64 words (one per row, bit = column); a 3D
volume is 64x64 int64 words (one per (x, y) column, bit = z). Every primitive is, per row (2D) or per
column (3D), a union of at most four integer intervals computed in closed form (circle half-widths,
square bounds, the triangle's scan-line fill and its Bresenham outline; sphere, cube and cylinder z
extents), and the boolean operators are word-wise ``| & ~``.

Two ways through a batch:

* :func:`execute` without a trace (and :func:`render_tokens`, :func:`render_programs`) plans first:
  it simulates every program's stack on references, on the CPU, and turns the operations that a
  valid result depends on into a table ordered by tree height; each group of table rows is a few
  batched row gathers and one word-wise operation (see :func:`_execute_plan`). Values are only
  computed on the range of x-slab blocks where they can be non-zero, and bool output unpacks only
  the non-empty blocks of each result.
* :class:`StackMachine` steps the whole batch through the programs one token position at a time; it
  gives the stack traces and serves decoders that execute predicted prefixes incrementally.

Large CPU results come from recycled memory (:class:`_BufferPool`): fresh multi-megabyte arrays cost
more in page faults than the rendering itself.

Clipping: everything outside the 64-pixel (or voxel) canvas is dropped; 3D shapes are clipped too,
never wrapped around (the reference had no clipping).

Invalid programs (an operator without two operands, shapes left over, empty) render all False. In a
stack trace, a program is all zeros from the token where it underflows, and frozen after its ``$``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from ..lang import Program
from ..primitives import MAX_PARAMS, SIZE
from .buffers import _POOL, pack, popcount, unpack
from .plan import _execute_plan
from .raster import _canvas_words, draw_packed
from .stack import Execution, StackMachine, _max_depth, apply_op_
from .tokens import PrimitiveCache, encode_programs, encode_programs_ids, encode_tokens, primitive_cache

__all__ = [
    "encode_programs",
    "encode_programs_ids",
    "encode_tokens",
    "execute",
    "render_tokens",
    "render_programs",
    "stack_trace",
    "Execution",
    "StackMachine",
    "PrimitiveCache",
    "primitive_cache",
    "apply_op_",
    "draw_packed",
    "pack",
    "popcount",
    "unpack",
    "SIZE",
]


def execute(kinds: torch.Tensor, params: torch.Tensor, dim: int, trace_k: int | None = None,
            token_ids: torch.Tensor | None = None) -> Execution:
    """Run a batch of encoded programs (see :func:`encode_programs`, :func:`encode_tokens`).

    Args:
        kinds: (B, T) int64 kind codes.
        params: (B, T, 5) int64 parameters.
        dim: 2 or 3.
        trace_k: if set, also record the top ``trace_k`` stack slots after every token.
        token_ids: (B, T) vocabulary indices of the same programs, if they are vocabulary programs:
            primitives then come from the :class:`PrimitiveCache` instead of being drawn.
    """
    if kinds.dim() != 2 or params.shape[:2] != kinds.shape or params.shape[-1] != MAX_PARAMS:
        raise ValueError(f"expected kinds (B, T) and params (B, T, 5), got {tuple(kinds.shape)} and {tuple(params.shape)}")
    B, T = kinds.shape
    if not trace_k:
        return _execute_plan(kinds, params, dim, token_ids)
    machine = StackMachine(B, dim, _max_depth(kinds), kinds.device, workspace=True)
    shape = (T + 1, B, trace_k) + _canvas_words(dim)
    if kinds.device.type == "cpu":
        trace = _POOL.empty(shape, np.int64)
    else:
        trace = torch.empty(shape, dtype=torch.int64, device=kinds.device)
    machine._top(trace_k, trace[0])
    for t in range(T):
        machine.step(kinds[:, t], params[:, t], None if token_ids is None else token_ids[:, t])
        machine._top(trace_k, trace[t + 1])
    return Execution(machine.result(), machine.valid, trace)


def render_tokens(tokens: torch.Tensor, dim: int, lengths: torch.Tensor | None = None) -> torch.Tensor:
    """Render token-index programs ``(B, T)`` (padded with ``$``) to bool ``(B, 64, 64[, 64])``
    on the tokens' device."""
    tokens = torch.as_tensor(tokens)
    kinds, params = encode_tokens(tokens, dim, lengths)
    return _execute_plan(kinds, params, dim, tokens.long(), as_bool=True)


def render_programs(programs: Sequence[Program | str], dim: int, device=None) -> torch.Tensor:
    """Render programs (objects or text, any integer parameters) to bool ``(B, 64, 64[, 64])``."""
    kinds, params, ids = encode_programs_ids(programs, dim, device)
    return _execute_plan(kinds, params, dim, ids, as_bool=True)


def stack_trace(programs, dim: int, k: int | None = None, lengths=None, packed: bool = False) -> torch.Tensor:
    """The stack trace CSGNetStack trains on.

    Args:
        programs: token indices ``(B, T)`` or a sequence of programs.
        dim: 2 or 3.
        k: slots per state (default: the deepest stack in the batch).
        packed: return int64 words instead of bools.

    Returns:
        ``(T+1, B, K, 64, 64[, 64])`` bool: state 0 is the empty stack, state t the stack after t tokens,
        slot 0 the top; empty slots, states after an underflow, are all False.
    """
    ids = None
    if isinstance(programs, (torch.Tensor, np.ndarray)):
        ids = torch.as_tensor(programs).long()
        kinds, params = encode_tokens(ids, dim, lengths)
    else:
        kinds, params, ids = encode_programs_ids(programs, dim)
    k = k or _max_depth(kinds)
    tr = execute(kinds, params, dim, trace_k=k, token_ids=ids).trace
    return tr if packed else unpack(tr, dim)
