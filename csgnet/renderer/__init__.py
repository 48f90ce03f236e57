"""The batched stack renderer of CSG programs, in PyTorch (CPU or GPU).

:func:`render_tokens` renders token-index tensors ``(B, T)`` (``$`` or any index after it pads),
:func:`render_programs` :class:`~csgnet.lang.Program` objects or texts with arbitrary integer parameters;
:func:`execute` runs encoded programs (optionally with a trace), :func:`stack_trace` gives the stack
trace CSGNetStack trains on, :class:`StackMachine` steps a batch one token at a time (for decoders).
Canvases are bit-packed int64 words; the result is exact to the pixel and voxel against the
per-program NumPy path (:mod:`csgnet.renderer.reference`). Parts outside the canvas are clipped (3D
never wraps around); invalid programs render all False.

See docs/csgnet.md ("The renderer") for details.
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


def render_tokens(tokens: torch.Tensor, dim: int, lengths: torch.Tensor | None = None,
                  packed: bool = False) -> torch.Tensor:
    """Render token-index programs ``(B, T)`` (padded with ``$``) to bool ``(B, 64, 64[, 64])``
    on the tokens' device; with ``packed``, to int64 words (:func:`unpack` gives the bools)."""
    tokens = torch.as_tensor(tokens)
    kinds, params = encode_tokens(tokens, dim, lengths)
    if packed:
        return _execute_plan(kinds, params, dim, tokens.long()).canvas
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
