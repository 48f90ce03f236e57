"""The stack machine: a batch of stacks of packed canvases stepped one token position at a time (stack
traces, incremental decoding)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..vocab import codes
from .buffers import _WORKSPACE
from .raster import _canvas_words, draw_packed
from .tokens import primitive_cache


def apply_op_(code: int, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a = a op b`` in place on packed words, for an operator kind code (``b`` is overwritten by a
    subtraction); returns ``a``."""
    op = codes().op
    if code == op["+"]:
        a |= b
    elif code == op["*"]:
        a &= b
    else:
        a &= b.bitwise_not_()
    return a


def _copy_rows(dst: torch.Tensor, rows: torch.Tensor, src: torch.Tensor) -> None:
    """``dst[rows] = src`` for 2D tensors (NumPy's row copies on the CPU: several times faster than
    ``index_copy_`` there)."""
    if dst.device.type == "cpu":
        dst.numpy()[rows.numpy()] = src.numpy()
    else:
        dst.index_copy_(0, rows, src)


class StackMachine:
    """A batch of stacks of packed canvases, stepped one token position at a time.

    Used by :func:`execute` and, incrementally, by decoders that execute predicted prefixes. Only the
    programs that draw (or apply a given operator) at a step are touched at that step. Slots above the
    stack pointer are stale and never read.

    Args:
        batch: B.
        dim: 2 or 3.
        depth: stack capacity S (a push beyond it marks the program broken).
        device: torch device.
        workspace: keep the storage in a per-thread scratch area reused by the next machine created
            with ``workspace=True`` in the same thread (only for a machine whose life ends before the
            next one starts, as in :func:`execute`).
    """

    def __init__(self, batch: int, dim: int, depth: int, device=None, workspace: bool = False):
        self.dim = dim
        self.depth = max(int(depth), 1)
        # Stale slots above the stack pointer are never read, so the storage need not be cleared.
        words = int(np.prod(_canvas_words(dim)))
        alloc = _WORKSPACE.get if workspace else (lambda name, n, dev: torch.empty(n, dtype=torch.int64, device=dev))
        # (B*S + 1, words): the stacks' rows, then one zero row that empty trace slots are gathered from.
        self._rows = alloc("stack", (batch * self.depth + 1) * words, device).view(-1, words)
        self._rows[-1].zero_()
        self._flat = self._rows[:-1]  # (B*S, words): row gathers and row copies are plain row copies
        self.stack = self._flat.view((batch, self.depth) + _canvas_words(dim))
        self._bufa = alloc("a", batch * words, device).view(batch, words)
        self._bufb = alloc("b", batch * words, device).view(batch, words)
        self.sp = torch.zeros(batch, dtype=torch.int64, device=device)
        self.broken = torch.zeros(batch, dtype=torch.bool, device=device)
        self.stopped = torch.zeros(batch, dtype=torch.bool, device=device)
        self._ar = torch.arange(batch, device=device)

    def step(self, kinds: torch.Tensor, params: torch.Tensor | None = None, token_ids: torch.Tensor | None = None,
             prims: torch.Tensor | None = None):
        """Apply one token per program.

        Args:
            kinds: (B,) int64 kind codes (a stop code stops that program for good).
            params: (B, 5) parameters of the draw tokens (drawn with :func:`draw_packed`).
            token_ids: (B,) vocabulary indices; draws then come from the :class:`PrimitiveCache`.
            prims: (B, *C) packed canvases of the draws, if already computed.
        """
        c = codes()
        self.stopped |= kinds == c.stop
        active = ~self.stopped & ~self.broken
        is_draw = active & c.is_draw(kinds)
        is_op = active & c.is_op(kinds)
        sp = self.sp
        bad = (is_op & (sp < 2)) | (is_draw & (sp >= self.depth))
        self.broken |= bad
        is_op &= ~bad
        is_draw &= ~bad
        di = torch.nonzero(is_draw).flatten()
        if di.numel():
            n = di.numel()
            if prims is not None:
                p = torch.index_select(prims.reshape(prims.shape[0], -1), 0, di, out=self._bufa[:n])
            elif token_ids is not None:
                p = primitive_cache(self.dim, kinds.device).get(token_ids[di], out=self._bufa[:n])
            else:
                p = draw_packed(kinds[di], params[di], self.dim)
            _copy_rows(self._flat, di * self.depth + sp[di], p.reshape(n, -1))
        for code in c.op.values():
            oi = torch.nonzero(is_op & (kinds == code)).flatten()
            if oi.numel():
                f1 = oi * self.depth + sp[oi] - 2
                n = oi.numel()
                a = torch.index_select(self._flat, 0, f1, out=self._bufa[:n])
                b = torch.index_select(self._flat, 0, f1 + 1, out=self._bufb[:n])
                _copy_rows(self._flat, f1, apply_op_(code, a, b))
        self.sp = torch.where(self.broken, torch.zeros_like(sp), sp + is_draw.long() - is_op.long())

    def reorder(self, index: torch.Tensor) -> None:
        """Make row ``i`` a copy of row ``index[i]`` (beam search keeps the parents' stacks)."""
        index = index.to(self.sp.device).long()
        if index.shape != self.sp.shape:
            raise ValueError(f"index must have shape {tuple(self.sp.shape)}, got {tuple(index.shape)}")
        rows = (index[:, None] * self.depth + torch.arange(self.depth, device=index.device)[None]).flatten()
        self._flat.copy_(self._flat.index_select(0, rows))
        self.sp, self.broken, self.stopped = self.sp[index], self.broken[index], self.stopped[index]

    def reset(self, rows) -> None:
        """Empty the stacks of ``rows`` (indices or a bool mask) so they start a new program."""
        rows = torch.as_tensor(rows, device=self.sp.device)
        self.sp[rows] = 0
        self.broken[rows] = False
        self.stopped[rows] = False

    def top(self, k: int) -> torch.Tensor:
        """(B, k, *C) packed: slot 0 = top of stack, empty slots zero."""
        return self._top(k)

    def _top(self, k: int, out: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`top`, written into ``out`` (a contiguous (B, k, *C) tensor) if given."""
        slots = self.sp[:, None] - 1 - torch.arange(k, device=self.sp.device)[None, :]
        zero_row = self._rows.shape[0] - 1
        flat = torch.where(slots >= 0, self._ar[:, None] * self.depth + slots.clamp(max=self.depth - 1),
                           zero_row).flatten()
        if out is None:
            out = torch.empty(slots.shape + self.stack.shape[2:], dtype=self.stack.dtype, device=self.stack.device)
        torch.index_select(self._rows, 0, flat, out=out.view(flat.shape[0], -1))
        return out

    @property
    def valid(self) -> torch.Tensor:
        """(B,) bool: not broken and exactly one shape on the stack."""
        return ~self.broken & (self.sp == 1)

    def result(self) -> torch.Tensor:
        """(B, *C) packed: the shape of each program that ended with exactly one shape, else empty."""
        view = (-1,) + (1,) * (self.stack.dim() - 2)
        top = self.stack[:, 0]
        return torch.where(self.valid.view(view), top, torch.zeros((), dtype=top.dtype, device=top.device))


@dataclass
class Execution:
    """Result of :func:`execute` (packed canvases; see :func:`unpack`).

    Attributes:
        canvas: (B, *C) int64 words of the final shapes (empty for invalid programs).
        valid: (B,) bool.
        trace: (T+1, B, K, *C) int64 words of the top-K stack slots after each token, or None.
    """

    canvas: torch.Tensor
    valid: torch.Tensor
    trace: torch.Tensor | None = None


def _max_depth(kinds: torch.Tensor) -> int:
    c = codes()
    delta = torch.where(c.is_draw(kinds), 1, torch.where(kinds < c.stop, -1, 0))
    stopped = torch.cumsum((kinds == c.stop).long(), dim=1) > 0
    delta = torch.where(stopped, torch.zeros_like(delta), delta)
    if delta.numel() == 0:
        return 1
    return max(int(torch.cumsum(delta, dim=1).max()), 1)
