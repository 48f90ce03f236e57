"""The executable specification: a plain, per-program NumPy renderer.

Readable rather than fast. Each primitive is drawn pixel by pixel by the reference drawing function
of its row in the table of :mod:`csgnet.primitives` (from the shared geometry), then the postfix
program runs on a Python list used as a stack. The batched renderer (:mod:`csgnet.renderer`) must
equal this path on every program; the tests check that.

2D: ``img[row=y, col=x]`` of shape (64, 64); out-of-canvas parts are clipped.
3D: ``vol[x, y, z]`` of shape (64, 64, 64); out-of-canvas parts are clipped (never wrapped).
"""

from __future__ import annotations

import numpy as np

from .. import primitives as P
from ..lang import Draw, Program, is_valid
from ..primitives import SIZE, bresenham

__all__ = ["draw_np", "render_np", "bresenham", "SIZE"]


def draw_np(draw: Draw) -> np.ndarray:
    """The bool mask of one primitive: (64, 64) in 2D, (64, 64, 64) in 3D."""
    return P.primitive(draw.kind).reference(*draw.params)


def render_np(program: Program, return_stack: bool = False):
    """Render one program.

    Args:
        program: a :class:`~csgnet.lang.Program`.
        return_stack: also return the stack trace.

    Returns:
        The bool canvas ((64, 64) or (64, 64, 64)); all False for an invalid or empty program. With
        ``return_stack``, also the list of T+1 stack states (each a list of masks, top first), where a
        state after an underflow is empty from then on.
    """
    shape = (SIZE,) * program.dim
    stack: list[np.ndarray] = []
    trace = [[]]
    broken = False
    for t in program.tokens:
        if broken:
            trace.append([])
            continue
        if isinstance(t, Draw):
            stack.append(draw_np(t))
        else:
            if len(stack) < 2:
                broken, stack = True, []
                trace.append([])
                continue
            b = stack.pop()
            a = stack.pop()
            stack.append({"+": a | b, "*": a & b, "-": a & ~b}[t.op])
        trace.append(stack[::-1])
    out = stack[-1] if (is_valid(program) and stack) else np.zeros(shape, bool)
    return (out, trace) if return_stack else out
