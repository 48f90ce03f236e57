"""Rasterisers: primitives to bit-packed canvases, in closed form per row (2D) or per column (3D).

A 2D image is 64 int64 words (one per row, bit = column); a 3D volume is 64x64 int64 words (one per
(x, y) column, bit = z). Every primitive is, per row or column, a union of at most four integer intervals
of the shared geometry of :mod:`csgnet.primitives`. A row of the table of primitives names its
rasteriser here (``raster="circle_rows"``) or carries it as a callable; :func:`draw_packed` dispatches
on the kind codes derived from the table.
"""

from __future__ import annotations

import sys
from functools import lru_cache

import numpy as np
import torch

from .. import primitives as P
from ..primitives import SIZE
from ..vocab import codes

_PREFIX_CACHE: dict = {}


def _prefix(device) -> torch.Tensor:
    """(65,) int64: entry n has the low n bits set (entry 64 is all ones, i.e. -1)."""
    key = str(device)
    if key not in _PREFIX_CACHE:
        vals = [(1 << n) - 1 for n in range(64)] + [-1]
        vals = [v - (1 << 64) if v >= (1 << 63) else v for v in vals]
        _PREFIX_CACHE[key] = torch.tensor(vals, dtype=torch.int64, device=device)
    return _PREFIX_CACHE[key]


def bits(lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Words with bits lo..hi (inclusive) set, clipped to 0..63; empty when hi < lo."""
    prefix = _prefix(lo.device)
    return prefix[(hi + 1).clamp(0, SIZE)] & ~prefix[lo.clamp(0, SIZE)]


def _isqrt(n: torch.Tensor) -> torch.Tensor:
    """Exact integer square root of a non-negative int64 tensor (moderate values)."""
    f = torch.sqrt(n.to(torch.float64)).floor().to(torch.int64)
    f = f - (f * f > n).long()
    return f + ((f + 1) * (f + 1) <= n).long()


def _ceil_div(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return -torch.div(-a, b, rounding_mode="floor")


# ------------------------------------------------------------------------------------------------
# 2D primitives: (P,) parameters -> (P, 64) words (bit c of word r = pixel [r, c])

def _rows(device):
    return torch.arange(SIZE, device=device, dtype=torch.int64)[None, :]


def circle_rows(x, y, r):
    rows = _rows(x.device)
    dy = rows - y[:, None]
    s = (r * r)[:, None] - dy * dy
    w0 = torch.where(s >= 1, _isqrt((s - 1).clamp(min=0)), torch.full_like(s, -1))
    # The float test can only differ from the integer one on exact boundary points (|d| = r).
    rf = r.to(torch.float64)[:, None].clamp(min=1.0)
    extra = P.circle_test(dy.to(torch.float64), (w0 + 1).to(torch.float64), rf)
    w = w0 + extra.long()
    x = x[:, None]
    return torch.where((r > 0)[:, None], bits(x - w, x + w), torch.zeros_like(w))


def square_rows(x, y, r):
    r0, r1, c0, c1 = (v.to(torch.int64)[:, None] for v in
                      P.square_bounds(x.to(torch.float64), y.to(torch.float64), r.to(torch.float64)))
    rows = _rows(x.device)
    on = (rows >= r0) & (rows <= r1)
    return torch.where(on, bits(c0, c1), torch.zeros((), dtype=torch.int64, device=x.device))


def line_rows(r0, c0, r1, c1):
    """Per-row words of the Bresenham line (r0, c0) -> (r1, c1); all (P,) int64, output (P, 64)."""
    rows = _rows(r0.device)
    r0, c0, r1, c1 = r0[:, None], c0[:, None], r1[:, None], c1[:, None]
    dr, dc = (r1 - r0).abs(), (c1 - c0).abs()
    sr = torch.where(r1 - r0 > 0, 1, -1)
    sc = torch.where(c1 - c0 > 0, 1, -1)
    m = (rows - r0) * sr  # steps along the row direction
    on = (m >= 0) & (m <= dr)
    steep = dr > dc
    # steep: one pixel per row, column offset round-half-up of m * dc / dr
    k_steep = torch.div(2 * dc * m + dr, (2 * dr).clamp(min=1), rounding_mode="floor")
    # shallow: a run of column offsets j with floor((2 dr j + dc) / (2 dc)) == m
    two_dr = (2 * dr).clamp(min=1)
    j_lo = _ceil_div(2 * dc * m - dc, two_dr).clamp(min=0)
    j_hi = torch.minimum(_ceil_div(2 * dc * (m + 1) - dc, two_dr) - 1, dc)
    flat = dr == 0  # horizontal (or a single point): the whole run on row r0
    j_lo = torch.where(flat, torch.zeros_like(j_lo), j_lo)
    j_hi = torch.where(flat, dc.expand_as(j_hi), j_hi)
    kmin = torch.where(steep, k_steep, j_lo)
    kmax = torch.where(steep, k_steep, j_hi)
    lo = torch.where(sc > 0, c0 + kmin, c0 - kmax)
    hi = torch.where(sc > 0, c0 + kmax, c0 - kmin)
    return torch.where(on, bits(lo, hi), torch.zeros((), dtype=torch.int64, device=r0.device))


def triangle_rows(x, y, r):
    xf, yf, rf = x.to(torch.float64), y.to(torch.float64), r.to(torch.float64)
    rb, ra, cl, cr = P.triangle_vertices(xf, yf, rf)
    rowsf = _rows(x.device).to(torch.float64)
    rb_, ra_, cl_, cr_, x_ = rb[:, None], ra[:, None], cl[:, None], cr[:, None], xf[:, None]
    # Scan-line fill (crossing-number test): columns between the two slanted edges on rows ra..rb-1.
    cond = (ra_ <= rowsf) & (rowsf < rb_)
    den = torch.where(ra_ == rb_, torch.ones_like(ra_), ra_ - rb_)
    x_left = (x_ - cl_) * (rowsf - rb_) / den + cl_
    x_right = (cr_ - x_) * (rowsf - ra_) / (-den) + x_
    lo = torch.ceil(torch.minimum(x_left, x_right)).to(torch.int64)
    hi = torch.ceil(torch.maximum(x_left, x_right)).to(torch.int64) - 1
    words = torch.where(cond, bits(lo, hi), torch.zeros((), dtype=torch.int64, device=x.device))
    for (a, b) in P.triangle_edges(xf, yf, rf):
        words = words | line_rows(*(v.to(torch.int64) for v in (a[0], a[1], b[0], b[1])))
    return words


# ------------------------------------------------------------------------------------------------
# 3D primitives: (P,) parameters -> (P, 64, 64) words (bit k of word [i, j] = voxel [i, j, k])

def _offsets2(x, y):
    ar = torch.arange(SIZE, device=x.device, dtype=torch.int64)
    dx = ar[None, :, None] - x[:, None, None]
    dy = ar[None, None, :] - y[:, None, None]
    return dx, dy


def sphere_cols(x, y, z, r):
    dx, dy = _offsets2(x, y)
    s = P.sphere_radius2(r)[:, None, None] - dx * dx - dy * dy
    w = _isqrt(s.clamp(min=0))
    z = z[:, None, None]
    return torch.where(s >= 0, bits(z - w, z + w), torch.zeros((), dtype=torch.int64, device=x.device))


def cube_cols(x, y, z, r):
    dx, dy = _offsets2(x, y)
    q = P.cube_half(r)[:, None, None]
    on = (dx.abs() <= q) & (dy.abs() <= q)
    z = z[:, None, None]
    return torch.where(on, bits(z - q, z + q), torch.zeros((), dtype=torch.int64, device=x.device))


def cylinder_cols(x, y, z, r, h):
    dx, dy = _offsets2(x, y)
    on = dx * dx + dy * dy <= P.sphere_radius2(r)[:, None, None]
    hz = P.cylinder_half_height(h.to(torch.float64)).to(torch.int64)[:, None, None]
    z = z[:, None, None]
    return torch.where(on, bits(z - hz, z + hz), torch.zeros((), dtype=torch.int64, device=x.device))


@lru_cache(maxsize=None)
def _drawers(dim: int) -> tuple[tuple[int, object, int], ...]:
    """``(code, rasteriser, parameter count)`` of the table's primitives of ``dim``."""
    here = sys.modules[__name__]
    c = codes()
    return tuple((c.kind[p.kind], p.raster if callable(p.raster) else getattr(here, p.raster), len(p.params))
                 for p in P.primitives(dim))


P.on_change(_drawers.cache_clear)


def _canvas_words(dim: int) -> tuple[int, ...]:
    return (SIZE,) if dim == 2 else (SIZE, SIZE)


def draw_packed(kinds: torch.Tensor, params: torch.Tensor, dim: int) -> torch.Tensor:
    """Packed masks of primitives.

    Args:
        kinds: (N,) int64 kind codes (non-draw codes give empty canvases).
        params: (N, 5) int64 parameters (zero-padded).
        dim: 2 or 3.

    Returns:
        (N, 64) int64 words in 2D, (N, 64, 64) in 3D.
    """
    out = torch.zeros((kinds.shape[0],) + _canvas_words(dim), dtype=torch.int64, device=kinds.device)
    for code, fn, n in _drawers(dim):
        idx = torch.nonzero(kinds == code).flatten()
        if idx.numel():
            p = params[idx]
            out[idx] = fn(*(p[:, i] for i in range(n)))
    return out


# ------------------------------------------------------------------------------------------------


_BLOCK_SLABS = 8
_UNPACK_BYTES = 1 << 19
_DRAW_BYTES = 8 << 20
_DRAW_MAX = 2048


def _blocks(dim: int) -> tuple[int, int]:
    """(blocks per canvas, words per block) of the planned executor: a 2D image is one block, a 3D
    volume 64 / _BLOCK_SLABS blocks of _BLOCK_SLABS x-slabs."""
    return (1, SIZE) if dim == 2 else (SIZE // _BLOCK_SLABS, _BLOCK_SLABS * SIZE)


def _slab_range(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, S) bool "slab is not all zero" -> first and last such slab per row (S and -1 if none)."""
    S = mask.shape[1]
    some = mask.any(axis=1)
    lo = np.where(some, mask.argmax(axis=1), S)
    hi = np.where(some, S - 1 - mask[:, ::-1].argmax(axis=1), -1)
    return lo.astype(np.int64), hi.astype(np.int64)
