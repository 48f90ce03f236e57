"""The table of CSG primitives: one row per primitive, from which every per-kind rule derives.

A row (:class:`Primitive`) says everything about one primitive: its vocabulary letter, its name (and
long 3D name), its dimension and parameters, the grammar values of each parameter, the rule that
decides whether a grammar primitive fits in the canvas (the vocabulary holds those that do), its NumPy
reference drawing function, its OpenSCAD form, its drawing weight in synthetic data, and its batched
torch rasteriser, named (the name of a function of :mod:`csgnet.renderer.raster`) or given as a
callable, so that this module stays free of torch. Kind codes, the vocabulary, the renderers, the
exporter and the synthetic sampler read the table; :func:`register` and :func:`unregister` change it
at run time and invalidate every table derived from it (see docs/csgnet.md, "The language").

The geometry is written with plain arithmetic so that it evaluates identically on Python numbers,
NumPy arrays (the per-program path, :mod:`csgnet.renderer.reference`) and float64/int64 torch tensors
(the batched path, :mod:`csgnet.renderer`). The float expressions are evaluated in float64 in exactly
the order the spec writes them, because the truncations are float-sensitive (for example the triangle
apex row at r = 27). 2D canvases are ``img[row, col]`` with ``row = y`` and ``col = x``; 3D volumes
are ``vol[x, y, z]``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = [
    "SIZE",
    "GRID",
    "SIZES",
    "MAX_PARAMS",
    "Primitive",
    "register",
    "unregister",
    "on_change",
    "primitive",
    "primitives",
    "by_name",
    "grammar_texts",
    "trunc",
    "square_bounds",
    "triangle_vertices",
    "triangle_edges",
    "circle_test",
    "sphere_radius2",
    "cube_half",
    "cylinder_half_height",
    "bresenham",
]

SIZE = 64
"""Side of every canvas in pixels (2D) or voxels (3D): the one definition the csgnet modules import."""
GRID = tuple(range(8, 57, 8))
"""Grammar positions 8, 16, ..., 56."""
SIZES = tuple(range(8, 33, 4))
"""Grammar radii and heights 8, 12, ..., 32. A parameter with this range is a size: never negative."""
MAX_PARAMS = 5
"""Parameters of the largest primitive (the width of the renderers' parameter rows)."""
_LAST = SIZE - 1


# ---------------------------------------------------------------------------------------------
# geometry shared by both renderers

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


# ---------------------------------------------------------------------------------------------
# the NumPy reference drawings: parameters -> bool (64, 64) image or (64, 64, 64) volume

def _circle(x, y, r):
    if r <= 0:
        return np.zeros((SIZE, SIZE), bool)
    rows = np.arange(SIZE, dtype=np.float64)[:, None]
    cols = np.arange(SIZE, dtype=np.float64)[None, :]
    return circle_test(rows - y, cols - x, float(r))


def _square(x, y, r):
    r0, r1, c0, c1 = (int(v) for v in square_bounds(float(x), float(y), float(r)))
    rows = np.arange(SIZE)[:, None]
    cols = np.arange(SIZE)[None, :]
    return (rows >= r0) & (rows <= r1) & (cols >= c0) & (cols <= c1)


def _triangle(x, y, r):
    rb, ra, cl, cr = (int(v) for v in triangle_vertices(float(x), float(y), float(r)))
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
    for (a, b) in triangle_edges(x, y, r):
        for pr, pc in bresenham(int(a[0]), int(a[1]), int(b[0]), int(b[1])):
            if 0 <= pr < SIZE and 0 <= pc < SIZE:
                inside[pr, pc] = True
    return inside


def _sphere(x, y, z, r):
    i, j, k = np.ogrid[:SIZE, :SIZE, :SIZE]
    return (i - x) ** 2 + (j - y) ** 2 + (k - z) ** 2 <= sphere_radius2(r)


def _cube(x, y, z, r):
    i, j, k = np.ogrid[:SIZE, :SIZE, :SIZE]
    q = cube_half(r)
    return (abs(i - x) <= q) & (abs(j - y) <= q) & (abs(k - z) <= q)


def _cylinder(x, y, z, r, h):
    i, j, k = np.ogrid[:SIZE, :SIZE, :SIZE]
    hz = int(cylinder_half_height(float(h)))
    return ((i - x) ** 2 + (j - y) ** 2 <= sphere_radius2(r)) & (abs(k - z) <= hz)


# ---------------------------------------------------------------------------------------------
# "fits in the canvas": the spec's rules for grammar primitives (the vocabulary holds those that fit)

def _inside(lo_row, lo_col, hi_row, hi_col) -> bool:
    return lo_row >= 0 and lo_col >= 0 and hi_row <= _LAST and hi_col <= _LAST


def _circle_fits(x, y, r) -> bool:
    return _inside(y - r, x - r, y + r, x + r)


def _square_fits(x, y, r) -> bool:
    # the square and triangle rules bound the rasteriser's own truncated extents
    lo_row, hi_row, lo_col, hi_col = square_bounds(x, y, r)
    return _inside(lo_row, lo_col, hi_row, hi_col)


def _triangle_fits(x, y, r) -> bool:
    hi_row, lo_row, lo_col, hi_col = triangle_vertices(x, y, r)
    return _inside(lo_row, lo_col, hi_row, hi_col)


def _span_fits(half, *centres) -> bool:
    return all(c - half >= 0 and c + half <= _LAST for c in centres)


def _sphere_fits(x, y, z, r) -> bool:
    return _span_fits(r - 1, x, y, z)


def _cube_fits(x, y, z, r) -> bool:
    return _span_fits(r // 2, x, y, z)


def _cylinder_fits(x, y, z, r, h) -> bool:
    return _span_fits(r - 1, x, y) and _span_fits(h // 2, z)


# ---------------------------------------------------------------------------------------------
# OpenSCAD forms: (params, $fn, label) -> one line of SCAD (see csgnet.export)

def scad_number(v) -> str:
    """A coordinate as OpenSCAD text: an integer without a decimal point, else 6 significant digits."""
    v = float(v)
    return str(int(v)) if v.is_integer() else f"{v:.6g}"


def _circle_scad(p, fn, label):
    x, y, r = p
    return f"translate([{x}, {y}]) circle(r = {r}, $fn = {fn});  // {label}"


def _square_scad(p, fn, label):
    r0, r1, c0, c1 = (int(v) for v in square_bounds(*p))
    return (f"translate([{scad_number(c0 - 0.5)}, {scad_number(r0 - 0.5)}]) square([{c1 - c0 + 1}, {r1 - r0 + 1}]);"
            f"  // {label}: rows {r0}..{r1}, columns {c0}..{c1}")


def _triangle_scad(p, fn, label):
    rb, ra, cl, cr = (int(v) for v in triangle_vertices(*p))
    return f"polygon([[{cl}, {rb}], [{cr}, {rb}], [{p[0]}, {ra}]]);  // {label}: base row {rb}, apex row {ra}"


def _sphere_scad(p, fn, label):
    x, y, z, r = p
    return f"translate([{x}, {y}, {z}]) sphere(r = {max(r - 1, 0)}, $fn = {fn});  // {label}"


def _cube_scad(p, fn, label):
    x, y, z, r = p
    q = cube_half(r)
    if q < 0:
        return f"// {label}: empty"
    corner = ", ".join(scad_number(c - q - 0.5) for c in (x, y, z))
    return f"translate([{corner}]) cube({2 * q + 1});  // {label}"


def _cylinder_scad(p, fn, label):
    x, y, z, r, h = p
    hz = int(cylinder_half_height(h))
    return (f"translate([{x}, {y}, {scad_number(z - hz - 0.5)}]) cylinder(r = {max(r - 1, 0)}, h = {2 * hz + 1}, "
            f"$fn = {fn});  // {label}")


# ---------------------------------------------------------------------------------------------
# the table

@dataclass(frozen=True)
class Primitive:
    """One row of the table of primitives.

    Attributes:
        kind: the vocabulary letter (``c``); the order of the table gives the kind codes.
        name: the long name (``circle``).
        dim: 2 or 3.
        params: parameter names, positions first (``("x", "y", "r")``).
        ranges: the grammar values of each parameter (:data:`GRID` for positions, :data:`SIZES` for
            sizes); a parameter whose range is :data:`SIZES` must not be negative.
        fits: ``fits(*params) -> bool``, whether a grammar primitive lies inside the canvas.
        reference: ``reference(*params)`` -> bool ``(64, 64)`` or ``(64, 64, 64)``, the NumPy drawing.
        scad: ``scad(params, fn, label) -> str``, one line of OpenSCAD (``fn``: the ``$fn`` of round
            shapes; ``label``: the program text of the primitive, for the comment).
        raster: the batched rasteriser, a callable or the name of a function of
            :mod:`csgnet.renderer.raster`: ``(P,)`` int64 tensors per parameter -> ``(P, 64)`` int64 words
            (2D, bit c of word r = pixel [r, c]) or ``(P, 64, 64)`` (3D, bit k of word [i, j] = voxel [i, j, k]).
        long: the dataset text's name of a 3D primitive (``sp``), or None.
        synth_weight: the default drawing weight of the primitive's type in synthetic programs.
    """

    kind: str
    name: str
    dim: int
    params: tuple[str, ...]
    ranges: tuple[tuple[int, ...], ...]
    fits: Callable[..., bool]
    reference: Callable[..., np.ndarray]
    scad: Callable[[tuple, int, str], str]
    raster: "str | Callable"
    long: str | None = None
    synth_weight: float = 1.0

    def __post_init__(self):
        if not (self.kind.isalpha() and self.kind.isascii()):
            raise ValueError(f"a primitive's kind must be ASCII letters, got {self.kind!r}")
        if self.dim not in (2, 3):
            raise ValueError(f"{self.name}: dim must be 2 or 3, got {self.dim}")
        if not 0 < len(self.params) <= MAX_PARAMS or len(self.ranges) != len(self.params):
            raise ValueError(f"{self.name}: 1 to {MAX_PARAMS} parameters with one range each, got "
                             f"{len(self.params)} names and {len(self.ranges)} ranges")
        if self.synth_weight < 0:
            raise ValueError(f"{self.name}: synth_weight must be >= 0, got {self.synth_weight}")

    @property
    def sizes(self) -> tuple[str, ...]:
        """The parameters that must not be negative (those with the range :data:`SIZES`)."""
        return tuple(n for n, r in zip(self.params, self.ranges) if tuple(r) == SIZES)

    def head(self, long: bool = True) -> str:
        """The name a program text uses: the long 3D name if ``long`` and there is one, else the letter."""
        return self.long if (long and self.long) else self.kind


_P2, _P3 = (GRID, GRID, SIZES), (GRID, GRID, GRID, SIZES)
_BUILTIN = (
    Primitive("c", "circle", 2, ("x", "y", "r"), _P2, _circle_fits, _circle, _circle_scad, "circle_rows"),
    Primitive("s", "square", 2, ("x", "y", "r"), _P2, _square_fits, _square, _square_scad, "square_rows"),
    Primitive("t", "triangle", 2, ("x", "y", "r"), _P2, _triangle_fits, _triangle, _triangle_scad, "triangle_rows"),
    Primitive("p", "sphere", 3, ("x", "y", "z", "r"), _P3, _sphere_fits, _sphere, _sphere_scad, "sphere_cols", "sp"),
    Primitive("u", "cube", 3, ("x", "y", "z", "r"), _P3, _cube_fits, _cube, _cube_scad, "cube_cols", "cu"),
    Primitive("y", "cylinder", 3, ("x", "y", "z", "r", "h"), _P3 + (SIZES,), _cylinder_fits, _cylinder,
              _cylinder_scad, "cylinder_cols", "cy"),
)

_TABLE: dict[str, Primitive] = {p.kind: p for p in _BUILTIN}
_NAMES: dict[str, Primitive] = {}  # every head a text may use (letter and long name) -> row
_LISTENERS: list[Callable[[], None]] = []


def _index() -> None:
    _NAMES.clear()
    for p in _TABLE.values():
        _NAMES[p.kind] = p
        if p.long:
            _NAMES[p.long] = p


_index()


def on_change(callback: Callable[[], None]) -> Callable[[], None]:
    """Call ``callback()`` whenever the table changes (modules clear what they derived from it)."""
    _LISTENERS.append(callback)
    return callback


def _changed() -> None:
    _index()
    for fn in _LISTENERS:
        fn()


def register(row: Primitive) -> Primitive:
    """Add a primitive to the table (it takes the next kind code; the operator codes move up).

    Raises:
        ValueError: its letter or long name is taken already.
    """
    if not isinstance(row, Primitive):
        raise TypeError(f"expected a Primitive row, got {type(row).__name__}")
    for head in (row.kind, row.long):
        if head and head in _NAMES:
            raise ValueError(f"primitive name {head!r} is taken by the {_NAMES[head].name}")
    _TABLE[row.kind] = row
    _changed()
    return row


def unregister(kind: str) -> Primitive:
    """Remove the primitive ``kind`` from the table and return its row."""
    try:
        row = _TABLE.pop(kind)
    except KeyError:
        raise KeyError(f"no primitive {kind!r}; the table holds {list(_TABLE)}") from None
    _changed()
    return row


def primitive(kind: str) -> Primitive:
    """The row of the vocabulary letter ``kind``."""
    try:
        return _TABLE[kind]
    except KeyError:
        raise KeyError(f"unknown primitive kind {kind!r}; expected one of {sorted(_TABLE)}") from None


def primitives(dim: int | None = None) -> tuple[Primitive, ...]:
    """The rows in table (kind code) order, all of them or those of ``dim``."""
    return tuple(p for p in _TABLE.values() if dim is None or p.dim == dim)


def by_name(head: str) -> Primitive | None:
    """The row a text's primitive name (the letter, or the long 3D name) stands for, or None."""
    return _NAMES.get(head)


def grammar_texts(row: Primitive) -> list[str]:
    """Vocabulary texts (``c(8,8,8)``) of every grammar primitive of ``row`` that fits in the canvas."""
    return [f"{row.kind}({','.join(map(str, v))})" for v in itertools.product(*row.ranges) if row.fits(*v)]
