"""The executable specification: a plain, per-program NumPy renderer.

Readable rather than fast. Each primitive is rasterised pixel by pixel from the shared geometry in
:mod:`csgnet.primitives`, then the postfix program runs on a Python list used as a stack. The batched
renderer (:mod:`csgnet.renderer`) must equal this path on every program; the tests check that.

2D: ``img[row=y, col=x]`` of shape (64, 64); out-of-canvas parts are clipped.
3D: ``vol[x, y, z]`` of shape (64, 64, 64); out-of-canvas parts are clipped (never wrapped).
"""

from __future__ import annotations

import numpy as np

from .. import primitives as P
from ..primitives import SIZE
from ..lang import Draw, Program, is_valid

__all__ = ["draw_np", "render_np", "bresenham", "SIZE"]


def bresenham(r0: int, c0: int, r1: int, c1: int) -> list[tuple[int, int]]:
    """Pixels of the line from (r0, c0) to (r1, c1), in drawing order (the integer Bresenham
    algorithm stepping along the major axis, the minor coordinate advancing when the error term
    reaches zero; the end point is the last pixel)."""
    r, c = r0, c0
    dr, dc = abs(r1 - r0), abs(c1 - c0)
    sr = 1 if r1 - r0 > 0 else -1
    sc = 1 if c1 - c0 > 0 else -1
    steep = dr > dc
    if steep:  # step along rows instead
        r, c, dr, dc, sr, sc = c, r, dc, dr, sc, sr
    d = 2 * dr - dc
    out = []
    for _ in range(dc):
        out.append((c, r) if steep else (r, c))
        while d >= 0:
            r += sr
            d -= 2 * dc
        c += sc
        d += 2 * dr
    out.append((r1, c1))
    return out


def _circle(x, y, r):
    if r <= 0:
        return np.zeros((SIZE, SIZE), bool)
    rows = np.arange(SIZE, dtype=np.float64)[:, None]
    cols = np.arange(SIZE, dtype=np.float64)[None, :]
    return P.circle_test(rows - y, cols - x, float(r))


def _square(x, y, r):
    r0, r1, c0, c1 = (int(v) for v in P.square_bounds(float(x), float(y), float(r)))
    rows = np.arange(SIZE)[:, None]
    cols = np.arange(SIZE)[None, :]
    return (rows >= r0) & (rows <= r1) & (cols >= c0) & (cols <= c1)


def _triangle(x, y, r):
    rb, ra, cl, cr = (int(v) for v in P.triangle_vertices(float(x), float(y), float(r)))
    verts = [(rb, cl), (rb, cr), (ra, x)]  # (row, col): base-left, base-right, apex
    rows = np.arange(SIZE, dtype=np.float64)[:, None]
    cols = np.arange(SIZE, dtype=np.float64)[None, :]
    # Filled part: crossing-number test at integer pixel centres (a horizontal ray toward +col).
    inside = np.zeros((SIZE, SIZE), bool)
    j = len(verts) - 1
    for i in range(len(verts)):
        (ri, ci), (rj, cj) = verts[i], verts[j]
        crosses_row = ((ri <= rows) & (rows < rj)) | ((rj <= rows) & (rows < ri))
        if ri != rj:
            col_at_row = (cj - ci) * (rows - ri) / (rj - ri) + ci
            inside ^= crosses_row & (cols < col_at_row)
        j = i
    # Outline: the Bresenham line of each edge, clipped to the canvas.
    for (a, b) in P.triangle_edges(x, y, r):
        for pr, pc in bresenham(int(a[0]), int(a[1]), int(b[0]), int(b[1])):
            if 0 <= pr < SIZE and 0 <= pc < SIZE:
                inside[pr, pc] = True
    return inside


def _sphere(x, y, z, r):
    i, j, k = np.ogrid[:SIZE, :SIZE, :SIZE]
    return (i - x) ** 2 + (j - y) ** 2 + (k - z) ** 2 <= P.sphere_radius2(r)


def _cube(x, y, z, r):
    i, j, k = np.ogrid[:SIZE, :SIZE, :SIZE]
    q = P.cube_half(r)
    return (abs(i - x) <= q) & (abs(j - y) <= q) & (abs(k - z) <= q)


def _cylinder(x, y, z, r, h):
    i, j, k = np.ogrid[:SIZE, :SIZE, :SIZE]
    hz = int(P.cylinder_half_height(float(h)))
    return ((i - x) ** 2 + (j - y) ** 2 <= P.sphere_radius2(r)) & (abs(k - z) <= hz)


_DRAW = {"c": _circle, "s": _square, "t": _triangle, "p": _sphere, "u": _cube, "y": _cylinder}


def draw_np(draw: Draw) -> np.ndarray:
    """The bool mask of one primitive: (64, 64) in 2D, (64, 64, 64) in 3D."""
    return _DRAW[draw.kind](*draw.params)


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
