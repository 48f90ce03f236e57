"""The one definition of the CSG primitives' geometry, shared by both renderers.

Every function here is written with plain arithmetic so that it evaluates identically on Python numbers,
NumPy arrays (the per-program path, :mod:`csgnet.renderer.reference`) and float64/int64 torch tensors (the batched
path, :mod:`csgnet.renderer`). The float expressions are evaluated in float64 in exactly the order the spec
(``../specs/csg.md`` section (b)) writes them, because the truncations are float-sensitive (for example the
triangle apex row at r = 27).

2D canvases are ``img[row, col]`` with ``row = y`` and ``col = x``; 3D volumes are ``vol[x, y, z]``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "SIZE",
    "trunc",
    "square_bounds",
    "triangle_vertices",
    "triangle_edges",
    "circle_test",
    "sphere_radius2",
    "cube_half",
    "cylinder_half_height",
]

SIZE = 64
"""Side of every canvas in pixels (2D) or voxels (3D): the one definition the csgnet modules import."""


def trunc(a):
    """Truncation toward zero (Python's ``int()``), for numbers, NumPy arrays and torch tensors."""
    if hasattr(a, "trunc") and not isinstance(a, np.ndarray):
        return a.trunc()
    return np.trunc(a)


def square_bounds(x, y, r):
    """Inclusive bounds of the square ``s(x, y, r)`` (r is the circumradius).

    Returns:
        ``(row0, row1, col0, col1)`` as float64 values holding integers; the square is the filled
        rectangle ``[row0, row1] x [col0, col1]`` clipped to the canvas.
    """
    L = r * 1.412
    return trunc(y - L / 2.0), trunc(y + L / 2.0), trunc(x - L / 2.0), trunc(x + L / 2.0)


def triangle_vertices(x, y, r):
    """Integer vertices of the upright triangle ``t(x, y, r)`` (apex up, i.e. toward smaller rows).

    Returns:
        ``(base_row, apex_row, left_col, right_col)``; the vertices are (row, col) = base-left
        ``(base_row, left_col)``, base-right ``(base_row, right_col)`` and apex ``(apex_row, x)``.
    """
    L = 1.732 * r
    base_row = trunc(y + L / (2 * 1.732))
    apex_row = trunc(y - L / 1.732)
    return base_row, apex_row, trunc(x - L / 2.0), trunc(x + L / 2.0)


def triangle_edges(x, y, r):
    """The triangle's outline as three directed segments ``((r0, c0), (r1, c1))``.

    The perimeter is the Bresenham line of each segment, in this order and direction:
    base-left -> base-right -> apex -> base-left (the order scikit-image's ``polygon_perimeter``
    draws the closed polygon in; the direction decides ties of the line algorithm).
    """
    rb, ra, cl, cr = triangle_vertices(x, y, r)
    bl, br, apex = (rb, cl), (rb, cr), (ra, x)
    return (bl, br), (br, apex), (apex, bl)


def circle_test(drow, dcol, r):
    """The circle's inside test at offsets ``(drow, dcol)`` from the centre, in float64.

    ``(drow/r)^2 + (dcol/r)^2 < 1``: scikit-image's ``disk`` test, equal to the integer test
    ``drow^2 + dcol^2 < r^2`` for r <= 40 and differing only on exact boundary points above that.
    Callers exclude r <= 0 (an empty circle).
    """
    return (drow / r) ** 2 + (dcol / r) ** 2 < 1


def sphere_radius2(r):
    """Squared radius of ``sp(x,y,z,r)``: a voxel is on iff its squared distance is <= (r-1)^2."""
    return (r - 1) * (r - 1)


def cube_half(r):
    """Half edge of ``cu(x,y,z,r)``: a voxel is on iff every |offset| <= (r-1)//2 (edge 2q+1)."""
    return (r - 1) // 2


def cylinder_half_height(h):
    """Half height of ``cy(x,y,z,r,h)`` along z: ``int((h-1)/2)`` (truncation, so h = 0 gives 0)."""
    return trunc((h - 1) / 2)
