"""The batched stack renderer of CSG programs, in PyTorch (CPU or GPU).

Programs arrive as token-index tensors ``(B, T)`` of mixed lengths (``$`` or any index after it pads), or
as :class:`~csgnet.lang.Program` objects with arbitrary integer parameters. The result is exact to the
pixel and voxel against the per-program NumPy path (:mod:`csgnet.render_np`), because both evaluate the
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

import sys
import threading
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from . import primitives as P
from .primitives import SIZE
from .lang import Program, parse
from .vocab import KIND_CODES, OP_CODES, PAD_CODE, vocabulary, write_codes

__all__ = [
    "encode_programs",
    "encode_tokens",
    "execute",
    "render_tokens",
    "render_programs",
    "stack_trace",
    "StackMachine",
    "PrimitiveCache",
    "primitive_cache",
    "draw_packed",
    "pack",
    "popcount",
    "unpack",
    "SIZE",
]

_UNION, _INTER, _SUB = OP_CODES["+"], OP_CODES["*"], OP_CODES["-"]

_PREFIX_CACHE: dict = {}


def _prefix(device) -> torch.Tensor:
    """(65,) int64: entry n has the low n bits set (entry 64 is all ones, i.e. -1)."""
    key = str(device)
    if key not in _PREFIX_CACHE:
        vals = [(1 << n) - 1 for n in range(64)] + [-1]
        vals = [v - (1 << 64) if v >= (1 << 63) else v for v in vals]
        _PREFIX_CACHE[key] = torch.tensor(vals, dtype=torch.int64, device=device)
    return _PREFIX_CACHE[key]


def _bits(lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
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


def _circle_rows(x, y, r):
    rows = _rows(x.device)
    dy = rows - y[:, None]
    s = (r * r)[:, None] - dy * dy
    w0 = torch.where(s >= 1, _isqrt((s - 1).clamp(min=0)), torch.full_like(s, -1))
    # The float test can only differ from the integer one on exact boundary points (|d| = r).
    rf = r.to(torch.float64)[:, None].clamp(min=1.0)
    extra = P.circle_test(dy.to(torch.float64), (w0 + 1).to(torch.float64), rf)
    w = w0 + extra.long()
    x = x[:, None]
    return torch.where((r > 0)[:, None], _bits(x - w, x + w), torch.zeros_like(w))


def _square_rows(x, y, r):
    r0, r1, c0, c1 = (v.to(torch.int64)[:, None] for v in
                      P.square_bounds(x.to(torch.float64), y.to(torch.float64), r.to(torch.float64)))
    rows = _rows(x.device)
    on = (rows >= r0) & (rows <= r1)
    return torch.where(on, _bits(c0, c1), torch.zeros((), dtype=torch.int64, device=x.device))


def _line_rows(r0, c0, r1, c1):
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
    return torch.where(on, _bits(lo, hi), torch.zeros((), dtype=torch.int64, device=r0.device))


def _triangle_rows(x, y, r):
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
    words = torch.where(cond, _bits(lo, hi), torch.zeros((), dtype=torch.int64, device=x.device))
    for (a, b) in P.triangle_edges(xf, yf, rf):
        words = words | _line_rows(*(v.to(torch.int64) for v in (a[0], a[1], b[0], b[1])))
    return words


# ------------------------------------------------------------------------------------------------
# 3D primitives: (P,) parameters -> (P, 64, 64) words (bit k of word [i, j] = voxel [i, j, k])

def _offsets2(x, y):
    ar = torch.arange(SIZE, device=x.device, dtype=torch.int64)
    dx = ar[None, :, None] - x[:, None, None]
    dy = ar[None, None, :] - y[:, None, None]
    return dx, dy


def _sphere_cols(x, y, z, r):
    dx, dy = _offsets2(x, y)
    s = P.sphere_radius2(r)[:, None, None] - dx * dx - dy * dy
    w = _isqrt(s.clamp(min=0))
    z = z[:, None, None]
    return torch.where(s >= 0, _bits(z - w, z + w), torch.zeros((), dtype=torch.int64, device=x.device))


def _cube_cols(x, y, z, r):
    dx, dy = _offsets2(x, y)
    q = P.cube_half(r)[:, None, None]
    on = (dx.abs() <= q) & (dy.abs() <= q)
    z = z[:, None, None]
    return torch.where(on, _bits(z - q, z + q), torch.zeros((), dtype=torch.int64, device=x.device))


def _cylinder_cols(x, y, z, r, h):
    dx, dy = _offsets2(x, y)
    on = dx * dx + dy * dy <= P.sphere_radius2(r)[:, None, None]
    hz = P.cylinder_half_height(h.to(torch.float64)).to(torch.int64)[:, None, None]
    z = z[:, None, None]
    return torch.where(on, _bits(z - hz, z + hz), torch.zeros((), dtype=torch.int64, device=x.device))


_DRAWERS = {
    KIND_CODES["c"]: (_circle_rows, 3),
    KIND_CODES["s"]: (_square_rows, 3),
    KIND_CODES["t"]: (_triangle_rows, 3),
    KIND_CODES["p"]: (_sphere_cols, 4),
    KIND_CODES["u"]: (_cube_cols, 4),
    KIND_CODES["y"]: (_cylinder_cols, 5),
}


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
    for code, (fn, n) in _DRAWERS.items():
        if (code < 3) != (dim == 2):
            continue
        idx = torch.nonzero(kinds == code).flatten()
        if idx.numel():
            p = params[idx]
            out[idx] = fn(*(p[:, i] for i in range(n)))
    return out


# ------------------------------------------------------------------------------------------------
# recycled CPU output buffers

class _BufferPool:
    """Large CPU output tensors backed by recycled memory.

    A fresh multi-megabyte allocation is a fresh ``mmap``: every page is faulted in (and zeroed by the
    kernel) on first touch, which for a 64 MiB batch of 3D volumes costs more than computing it. Small
    arrays do not pay this, because ``malloc`` recycles freed heap memory; this pool does the same for
    the renderer's large results. Each result is an ordinary tensor over a NumPy buffer held by the
    pool; a buffer is handed out again only once nothing refers to it any more (its reference count
    says that the pool is its only holder: the returned tensor, its views, and arrays made from it all
    keep it alive). At most ``max_bytes`` of buffers are remembered; older ones are forgotten (and freed
    by their last user). Disabled where reference counts cannot be relied on (free-threaded Python).
    """

    def __init__(self, min_bytes: int = 1 << 20, max_bytes: int = 256 << 20):
        self.min_bytes, self.max_bytes = min_bytes, max_bytes
        self._lock = threading.Lock()
        self._bufs: list[np.ndarray] = []
        probe = [np.empty(1, np.uint8)]
        self._idle_refs = self._refs(probe, 0)
        gil = getattr(sys, "_is_gil_enabled", None)
        self.enabled = gil is None or gil()

    @staticmethod
    def _refs(bufs: list, i: int) -> int:
        return sys.getrefcount(bufs[i])

    def empty(self, shape: tuple, dtype) -> torch.Tensor:
        """An uninitialised CPU tensor of ``shape`` and NumPy ``dtype``."""
        dtype = np.dtype(dtype)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if not self.enabled or nbytes < self.min_bytes or nbytes > self.max_bytes:
            return torch.from_numpy(np.empty(shape, dtype))
        with self._lock:
            bufs = self._bufs
            for i in range(len(bufs) - 1, -1, -1):
                if bufs[i].nbytes == nbytes and self._refs(bufs, i) == self._idle_refs:
                    buf = bufs.pop(i)
                    break
            else:
                buf = np.empty(nbytes, np.uint8)
                total = nbytes + sum(b.nbytes for b in bufs)
                while bufs and total > self.max_bytes:
                    total -= bufs.pop(0).nbytes
            bufs.append(buf)
            return torch.from_numpy(buf.view(dtype).reshape(shape))


_POOL = _BufferPool()


# ------------------------------------------------------------------------------------------------
# packing

def unpack(words: torch.Tensor, dim: int) -> torch.Tensor:
    """Packed words ``(..., 64)`` (2D) or ``(..., 64, 64)`` (3D) -> bool ``(..., 64, 64[, 64])``."""
    words = words.contiguous()
    shape = words.shape + (SIZE,)
    if words.device.type != "cpu":
        by = words.view(torch.uint8)
        shifts = torch.arange(8, dtype=torch.uint8, device=words.device)
        bits = (by.unsqueeze(-1) >> shifts) & 1
        return bits.reshape(shape).bool()
    # Larger than the pool keeps: a fresh allocation, zeroed by the OS page by page on first touch
    # (calloc), so the all-zero rows (the empty slots of a 3D stack trace) cost nothing here.
    zeroed = int(np.prod(shape, dtype=np.int64)) > _POOL.max_bytes
    out = torch.from_numpy(np.zeros(shape, np.bool_)) if zeroed else _POOL.empty(shape, np.bool_)
    if words.numel():
        _unpack_rows(words.numpy().reshape(-1, SIZE), out.numpy().reshape(-1, SIZE * SIZE).view(np.uint8),
                     zeroed=zeroed)
    return out


def _unpack_rows(w: np.ndarray, out: np.ndarray, chunk: int = 256, zeroed: bool = False) -> None:
    """Unpack rows of 64 words (a 2D image, or one x-slab of a 3D volume) into ``out`` ``(R, 4096)``.

    All-zero rows (most of a typical 3D volume) are cleared with ``memset``-speed writes (or left
    alone if ``out`` is ``zeroed`` already); only the other rows go through ``np.unpackbits`` (in
    chunks, so its temporary stays in cache).
    """
    nz = w.view(np.uint64).max(axis=1) != 0
    rows = np.flatnonzero(nz)
    if zeroed or len(rows) * 4 < len(nz) * 3:
        if not zeroed:  # clear the zero rows run by run (contiguous slices)
            edges = np.flatnonzero(np.diff(nz.view(np.int8), prepend=1, append=1))
            for a, b in zip(edges[0::2].tolist(), edges[1::2].tolist()):
                out[a:b] = 0
        for i in range(0, len(rows), chunk):  # then fill in the others
            r = rows[i:i + chunk]
            out[r] = np.unpackbits(w[r].view(np.uint8), axis=-1, bitorder="little")
    else:
        for i in range(0, len(w), chunk):
            out[i:i + chunk] = np.unpackbits(w[i:i + chunk].view(np.uint8), axis=-1, bitorder="little")


def popcount(words: torch.Tensor) -> np.ndarray:
    """ON pixels (voxels) of packed canvases ``(N, *C)`` int64 -> ``(N,)`` int64 (NumPy, on the CPU)."""
    w = words.detach().cpu().numpy().view(np.uint64)  # bitwise_count of a signed word counts |w|'s bits
    return np.bitwise_count(w).reshape(w.shape[0], -1).sum(axis=1, dtype=np.int64)


def pack(canvas: torch.Tensor | np.ndarray) -> torch.Tensor:
    """Bool ``(..., 64)`` -> int64 words ``(...)`` (inverse of :func:`unpack`, on the last axis)."""
    if isinstance(canvas, torch.Tensor):
        dev = canvas.device
        arr = canvas.detach().cpu().numpy()
    else:
        dev, arr = torch.device("cpu"), np.asarray(canvas)
    if arr.shape[-1] != SIZE:
        raise ValueError(f"pack expects a last axis of {SIZE}, got shape {arr.shape}")
    by = np.packbits(arr.astype(bool), axis=-1, bitorder="little")
    return torch.from_numpy(np.ascontiguousarray(by).view(np.int64)[..., 0]).to(dev)


# ------------------------------------------------------------------------------------------------
# encoding programs

def encode_programs(programs: Sequence[Program | str], dim: int, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Programs (objects or text) -> ``kinds (B, T) int64`` and ``params (B, T, 5) int64``.

    Text is parsed non-strictly, so structurally invalid programs encode (and render empty).
    """
    progs = [parse(p, dim, strict=False) if isinstance(p, str) else p for p in programs]
    T = max([len(p) for p in progs] + [1])
    kinds = np.full((len(progs), T), PAD_CODE, dtype=np.int64)
    params = np.zeros((len(progs), T, 5), dtype=np.int64)
    for b, p in enumerate(progs):
        if p.dim != dim:
            raise ValueError(f"program {b} is {p.dim}D, expected {dim}D: {p.text()!r}")
        write_codes(p.tokens, kinds[b], params[b])
    return torch.from_numpy(kinds).to(device), torch.from_numpy(params).to(device)


def encode_tokens(tokens: torch.Tensor, dim: int, lengths: torch.Tensor | None = None):
    """Token indices ``(B, T)`` -> ``kinds (B, T)`` and ``params (B, T, 5)`` on the same device.

    Positions at or after ``lengths`` (if given) or after the first ``$`` become padding.
    """
    tokens = torch.as_tensor(tokens)
    if tokens.dim() != 2:
        raise ValueError(f"tokens must be (B, T), got shape {tuple(tokens.shape)}")
    vocab = vocabulary(dim)
    if tokens.numel() and (int(tokens.min()) < 0 or int(tokens.max()) >= len(vocab)):
        raise ValueError(f"token indices must lie in [0, {len(vocab)}) for the {dim}D vocabulary, "
                         f"got range [{int(tokens.min())}, {int(tokens.max())}]")
    cache = primitive_cache(dim, tokens.device)
    tokens = tokens.long()
    flat = tokens.reshape(-1)
    kinds = cache.kinds.index_select(0, flat).view(tokens.shape)
    params = cache.params.index_select(0, flat).view(tokens.shape + (5,))
    if lengths is not None:
        pos = torch.arange(tokens.shape[1], device=tokens.device)[None, :]
        kinds = torch.where(pos < torch.as_tensor(lengths, device=tokens.device)[:, None], kinds, PAD_CODE)
    return kinds, params


# ------------------------------------------------------------------------------------------------
# the stack machine

class _Workspace(threading.local):
    """Per-thread scratch buffers reused across calls.

    Fresh multi-megabyte CPU allocations are returned to the OS when freed, so every new one pays page
    faults on first touch (more than the copies themselves cost); reusing the buffers avoids that.
    """

    def __init__(self):
        self.buffers: dict = {}

    def get(self, name: str, numel: int, device) -> torch.Tensor:
        key = (name, str(device))
        buf = self.buffers.get(key)
        if buf is None or buf.numel() < numel:
            buf = torch.empty(max(numel, 1), dtype=torch.int64, device=device)
            self.buffers[key] = buf
        return buf[:numel]


_WORKSPACE = _Workspace()


class PrimitiveCache:
    """Packed canvases of vocabulary primitives, computed on first use from the shared geometry.

    Nothing is read from disk: an entry is drawn by :func:`draw_packed` the first time a token is seen
    on a device and kept for the life of the process (2D: 200 KB for all 396 primitives; 3D: 32 KB per
    primitive, at most 217 MB if every one of the 6631 is used).
    """

    def __init__(self, dim: int, device):
        vocab = vocabulary(dim)
        k, p = vocab.table()
        self.dim = dim
        self.kinds = torch.from_numpy(k).to(device)
        self.params = torch.from_numpy(p).to(device)
        self.words = torch.empty((len(vocab),) + _canvas_words(dim), dtype=torch.int64, device=device)
        self.have = torch.zeros(len(vocab), dtype=torch.bool, device=device)
        # first and last non-empty block (see _blocks) of each cached entry, on the CPU
        self.lo = np.full(len(vocab), _blocks(dim)[0], np.int64)
        self.hi = np.full(len(vocab), -1, np.int64)

    def _ensure(self, ids) -> None:
        """Draw the entries of ``ids`` (token indices, NumPy or torch) that are not cached yet."""
        if self.have.device.type == "cpu":
            ids = np.unique(ids.numpy() if isinstance(ids, torch.Tensor) else ids)
            missing = ids[~self.have.numpy()[ids]]
            if not len(missing):
                return
            missing = torch.from_numpy(missing)
        else:
            ids = torch.unique(torch.as_tensor(ids, device=self.have.device))
            missing = ids[~self.have[ids]]
            if not missing.numel():
                return
        words = draw_packed(self.kinds[missing], self.params[missing], self.dim)
        self.words[missing] = words
        self.have[missing] = True
        m = missing.cpu().numpy()
        n_sl, bw = _blocks(self.dim)
        self.lo[m], self.hi[m] = _slab_range((words.view(len(m), n_sl, bw) != 0).any(-1).cpu().numpy())

    def get(self, ids: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
        """(N,) token indices of primitives -> (N, *C) packed canvases (``out``: a (N, words) buffer)."""
        if ids.numel() == 0:
            return self.words[ids]
        self._ensure(ids)
        flat = self.words.view(self.words.shape[0], -1)
        if out is not None:
            return torch.index_select(flat, 0, ids, out=out)
        return flat.index_select(0, ids).view((-1,) + self.words.shape[1:])


_PRIM_CACHES: dict = {}


def primitive_cache(dim: int, device) -> PrimitiveCache:
    """The process-wide :class:`PrimitiveCache` of ``dim`` on ``device``."""
    key = (dim, str(torch.device(device)))
    if key not in _PRIM_CACHES:
        _PRIM_CACHES[key] = PrimitiveCache(dim, device)
    return _PRIM_CACHES[key]


def apply_op_(code: int, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a = a op b`` in place on packed words, for an operator kind code (``b`` is overwritten by a
    subtraction); returns ``a``."""
    if code == _UNION:
        a |= b
    elif code == _INTER:
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
        self.stopped |= kinds == PAD_CODE
        active = ~self.stopped & ~self.broken
        is_draw = active & (kinds < 6)
        is_op = active & (kinds >= 6) & (kinds <= 8)
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
        for code in (_UNION, _INTER, _SUB):
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
    delta = torch.where(kinds < 6, 1, torch.where(kinds <= 8, -1, 0))
    stopped = torch.cumsum((kinds == PAD_CODE).long(), dim=1) > 0
    delta = torch.where(stopped, torch.zeros_like(delta), delta)
    if delta.numel() == 0:
        return 1
    return max(int(torch.cumsum(delta, dim=1).max()), 1)


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
    if kinds.dim() != 2 or params.shape[:2] != kinds.shape or params.shape[-1] != 5:
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


# ------------------------------------------------------------------------------------------------
# planned execution (no stack, no trace)

@dataclass
class _Plan:
    """A batch of postfix programs as a table of operations (see :func:`_plan`).

    Row ``i`` of the table is ``A op B``; an operand is an earlier row (``*_op`` True) or a draw, an
    index into ``draws``. Rows are ordered by (tree height, operator, operand sources), so each
    ``group`` ``(r0, r1, code, subs)`` is filled by contiguous gathers (one pair per sub-range
    ``(s0, s1, a_op, b_op)`` of uniform sources) and one word-wise operation, reading only rows < r0.
    """

    valid: np.ndarray  # (B,) bool
    final: np.ndarray  # (B,) row of the result of each valid program, or -1
    final_draw: np.ndarray  # (B,) index into draws of a valid program that is one draw, or -1
    draws: np.ndarray  # (D,) flat token positions b * T + t of the draws the results use
    code: np.ndarray  # (R,) operator codes
    height: np.ndarray  # (R,) tree heights (1: both operands are draws), non-decreasing
    a_op: np.ndarray  # (R,) bool
    a_idx: np.ndarray  # (R,) int64
    b_op: np.ndarray
    b_idx: np.ndarray
    groups: list


def _plan(kinds: np.ndarray) -> _Plan:
    """Simulate the stack of every program on references (no canvases) and list the operations that
    contribute to the result of a valid program. Same semantics as :class:`StackMachine`."""
    B, T = kinds.shape
    ref = np.zeros((B, T + 1), np.int64)  # stack slots: operation id >= 0, or -(draw position + 1)
    height = np.zeros((B, T + 1), np.int64)
    sp = np.zeros(B, np.int64)
    broken = np.zeros(B, bool)
    stopped = np.zeros(B, bool)
    ops = []
    n_op = 0
    for t in range(T):
        k = kinds[:, t]
        stopped |= k == PAD_CODE
        live = ~stopped & ~broken
        is_draw = live & (k < 6)
        is_op = live & (k >= 6) & (k <= 8)
        bad = is_op & (sp < 2)
        broken |= bad
        is_op &= ~bad
        d = np.flatnonzero(is_draw)
        if len(d):
            ref[d, sp[d]] = -(d * T + t) - 1
            height[d, sp[d]] = 0
        o = np.flatnonzero(is_op)
        if len(o):
            s = sp[o]
            h = np.maximum(height[o, s - 2], height[o, s - 1]) + 1
            ops.append((k[o], ref[o, s - 2], ref[o, s - 1], h))
            ref[o, s - 2] = np.arange(n_op, n_op + len(o))
            height[o, s - 2] = h
            n_op += len(o)
        sp += is_draw
        sp -= is_op
        sp[broken] = 0
    valid = ~broken & (sp == 1)
    res = np.where(valid, ref[:, 0], 0)
    final = np.where(valid & (res >= 0), res, -1)
    fdraw = np.where(valid & (res < 0), -res - 1, -1)

    if ops:
        code, oa, ob, oh = (np.concatenate(c) for c in zip(*ops))
    else:
        code = oa = ob = oh = np.zeros(0, np.int64)
    # operations some valid result depends on, from the top of the trees down
    need = np.zeros(n_op, bool)
    need[final[final >= 0]] = True
    for level in range(int(oh.max()) if n_op else 0, 1, -1):
        sel = np.flatnonzero(need & (oh == level))
        for x in (oa[sel], ob[sel]):
            need[x[x >= 0]] = True
    keep = np.flatnonzero(need)
    a_op, b_op = oa[keep] >= 0, ob[keep] >= 0
    order = np.lexsort((b_op, a_op, code[keep], oh[keep]))
    keep, a_op, b_op = keep[order], a_op[order], b_op[order]
    row = np.full(n_op + 1, -1, np.int64)  # one spare entry: index 0 is safe without operations
    row[keep] = np.arange(len(keep))
    oa, ob, code, oh = oa[keep], ob[keep], code[keep], oh[keep]
    # every draw feeds exactly one operation or result, so these positions are distinct
    draws = np.sort(np.concatenate([-oa[~a_op] - 1, -ob[~b_op] - 1, fdraw[fdraw >= 0]]))
    dmap = np.zeros(B * T + 1, np.int64)  # draw position -> index into draws
    dmap[draws] = np.arange(len(draws))
    a_idx = np.where(a_op, row[np.maximum(oa, 0)], dmap[np.maximum(-oa - 1, 0)])
    b_idx = np.where(b_op, row[np.maximum(ob, 0)], dmap[np.maximum(-ob - 1, 0)])
    final = np.where(final >= 0, row[np.maximum(final, 0)], -1)
    fdraw = np.where(fdraw >= 0, dmap[np.maximum(fdraw, 0)], -1)

    groups = []
    R = len(keep)
    if R:
        gkey = oh * 16 + code
        skey = gkey * 4 + a_op * 2 + b_op
        g_starts = np.flatnonzero(np.diff(gkey, prepend=-1)).tolist() + [R]
        s_starts = np.flatnonzero(np.diff(skey, prepend=-1)).tolist() + [R]
        si = 0
        for r0, r1 in zip(g_starts[:-1], g_starts[1:]):
            subs = []
            while s_starts[si] < r1:
                s0, s1 = s_starts[si], s_starts[si + 1]
                subs.append((s0, s1, bool(a_op[s0]), bool(b_op[s0])))
                si += 1
            groups.append((r0, r1, int(code[r0]), subs))
    return _Plan(valid, final, fdraw, draws, code, oh, a_op, a_idx, b_op, b_idx, groups)


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


def _pick(is_op: np.ndarray, idx: np.ndarray, op_vals: np.ndarray, draw_vals: np.ndarray) -> np.ndarray:
    """``op_vals[idx]`` where ``is_op``, else ``draw_vals[idx]``."""
    out = np.empty(len(idx), np.int64)
    out[is_op] = op_vals[idx[is_op]]
    out[~is_op] = draw_vals[idx[~is_op]]
    return out


def _execute_plan(kinds: torch.Tensor, params: torch.Tensor, dim: int, token_ids: torch.Tensor | None,
                  as_bool: bool = False):
    """:func:`execute` without a trace.

    A canvas is a column of slabs of 64 words (3D: the 64 x-slabs of a volume; 2D: one slab, the
    image). Every value (a primitive or an operation's result) is known to be zero outside a range of
    slabs: a primitive's first to last non-empty slab, the hull of the operands' ranges for a union,
    their intersection for an intersection, the first operand's range for a difference. Each
    operation is computed on its range only, into a table of slabs whose row 0 is all zeros (what an
    operand reads outside its own range); operations with an empty range cost nothing. (On the random
    3D length-7 vocabulary programs of ``bench/bench_csg_render.py`` the operations covered about 40%
    of the dense slabs in a one-off count; no script prints it.)

    Returns an :class:`Execution`, or with ``as_bool`` the bool canvases (unpacking only the result
    slabs that hold something).
    """
    device = kinds.device
    B, T = kinds.shape
    C = _canvas_words(dim)
    n_sl, bw = _blocks(dim)
    plan = _plan(kinds.cpu().numpy())
    # primitive canvases: rows of the primitive cache, or drawn now; and their slab ranges
    if token_ids is not None:
        prow = token_ids.reshape(-1).cpu().numpy()[plan.draws]
        cache = primitive_cache(dim, device)
        cache._ensure(prow)
        prims = cache.words
        d_lo, d_hi = cache.lo[prow], cache.hi[prow]
    else:
        D = len(plan.draws)
        prow = np.arange(D)
        sel = torch.from_numpy(plan.draws).to(device)
        k_flat, p_flat = kinds.reshape(-1), params.reshape(-1, 5)
        prims = _WORKSPACE.get("prims", D * n_sl * bw, device).view((D,) + C)
        step = max(1, min(_DRAW_MAX, _DRAW_BYTES // (n_sl * bw * 8)))  # draws per call: moderate temporaries
        for c in range(0, D, step):
            prims[c:c + step] = draw_packed(k_flat[sel[c:c + step]], p_flat[sel[c:c + step]], dim)
        d_lo, d_hi = _slab_range((prims.view(D, n_sl, bw) != 0).any(-1).cpu().numpy())
    prim_slabs = prims.view(-1, bw)

    # slab ranges of the operations, one tree height at a time
    R = len(plan.code)
    lo = np.empty(R, np.int64)
    hi = np.empty(R, np.int64)
    bounds = np.flatnonzero(np.diff(plan.height, prepend=-1)).tolist() + [R]
    for l0, l1 in zip(bounds[:-1], bounds[1:]):
        sl = slice(l0, l1)
        alo = _pick(plan.a_op[sl], plan.a_idx[sl], lo, d_lo)
        ahi = _pick(plan.a_op[sl], plan.a_idx[sl], hi, d_hi)
        blo = _pick(plan.b_op[sl], plan.b_idx[sl], lo, d_lo)
        bhi = _pick(plan.b_op[sl], plan.b_idx[sl], hi, d_hi)
        code = plan.code[sl]
        u, i = code == _UNION, code == _INTER
        rlo = np.where(u, np.minimum(alo, blo), np.where(i, np.maximum(alo, blo), alo))
        rhi = np.where(u, np.maximum(ahi, bhi), np.where(i, np.minimum(ahi, bhi), ahi))
        empty = rlo > rhi
        lo[sl] = np.where(empty, n_sl, rlo)
        hi[sl] = np.where(empty, -1, rhi)
    n = np.maximum(hi - lo + 1, 0)
    fstart = np.concatenate([[0], np.cumsum(n)])  # table slabs of row r: 1 + fstart[r] ... 1 + fstart[r+1]
    total = int(fstart[-1])

    # operand slab of every table slab: a table slab (0 outside the operand's range) or a primitive slab
    owner = np.repeat(np.arange(R), n)
    x = lo[owner] + np.arange(total) - fstart[owner]

    def sources(is_op, idx):
        is_op, idx = is_op[owner], idx[owner]
        out = np.empty(total, np.int64)
        r, xo = idx[is_op], x[is_op]
        out[is_op] = np.where((xo >= lo[r]) & (xo <= hi[r]), 1 + fstart[r] + xo - lo[r], 0)
        out[~is_op] = prow[idx[~is_op]] * n_sl + x[~is_op]
        return torch.from_numpy(out).to(device)

    a_src, b_src = sources(plan.a_op, plan.a_idx), sources(plan.b_op, plan.b_idx)
    table = _WORKSPACE.get("ops", (1 + total) * bw, device).view(1 + total, bw)
    table[0].zero_()
    widest = max([int(fstart[r1] - fstart[r0]) for r0, r1, _, _ in plan.groups] + [0])
    tmp = _WORKSPACE.get("b", widest * bw, device).view(widest, bw)
    for r0, r1, code, subs in plan.groups:
        g0, g1 = int(fstart[r0]), int(fstart[r1])
        if g0 == g1:
            continue
        done = table[:1 + g0]
        for s0, s1, a_op, b_op in subs:
            f0, f1 = int(fstart[s0]), int(fstart[s1])
            if f0 < f1:
                torch.index_select(done if a_op else prim_slabs, 0, a_src[f0:f1], out=table[1 + f0:1 + f1])
                torch.index_select(done if b_op else prim_slabs, 0, b_src[f0:f1], out=tmp[f0 - g0:f1 - g0])
        apply_op_(code, table[1 + g0:1 + g1], tmp[:g1 - g0])

    # results: the slabs of each program's range (the rest of a canvas is zero)
    has = np.flatnonzero(plan.final >= 0)
    single = np.flatnonzero(plan.final_draw >= 0)
    parts = [(table, *_range_rows(has, plan.final[has], lo, hi, 1 + fstart[:-1], n_sl)),
             (prim_slabs, *_range_rows(single, plan.final_draw[single], d_lo, d_hi, prow * n_sl + d_lo, n_sl))]
    cpu = device.type == "cpu"
    if as_bool and cpu:
        out = _POOL.empty((B,) + C + (SIZE,), np.bool_)
        rows = out.numpy().reshape(B * n_sl, bw * SIZE).view(np.uint8)
        rows.fill(0)  # one large memset: faster than clearing only the blocks left empty
        step = max(1, _UNPACK_BYTES // (bw * SIZE))  # blocks per unpack: its temporary stays in cache
        spb = bw // SIZE  # x-slabs per block
        slab_rows = rows.reshape(-1, SIZE * SIZE)
        for src, s_idx, d_idx in parts:
            src = src.numpy()
            for i in range(0, len(s_idx), step):
                g = src[s_idx[i:i + step]].reshape(-1, SIZE)  # x-slabs
                nz = np.flatnonzero(g.view(np.uint64).max(axis=1))
                dst = (d_idx[i:i + step, None] * spb + np.arange(spb)).reshape(-1)[nz]
                slab_rows[dst] = np.unpackbits(g[nz].view(np.uint8), axis=-1, bitorder="little")
        return out
    if cpu:
        out = _POOL.empty((B * n_sl, bw), np.int64)
        o = out.numpy()
        o.fill(0)
        for src, s_idx, d_idx in parts:
            o[d_idx] = src.numpy()[s_idx]
    else:
        out = torch.zeros((B * n_sl, bw), dtype=torch.int64, device=device)
        for src, s_idx, d_idx in parts:
            out.index_copy_(0, torch.from_numpy(d_idx).to(device),
                            src.index_select(0, torch.from_numpy(s_idx).to(device)))
    out = out.view((B,) + C)
    if as_bool:
        return unpack(out, dim)
    return Execution(out, torch.from_numpy(plan.valid).to(device), None)


def _range_rows(progs: np.ndarray, vals: np.ndarray, lo: np.ndarray, hi: np.ndarray, first: np.ndarray,
                n_sl: int) -> tuple[np.ndarray, np.ndarray]:
    """Source and output slab rows of the ranges of values ``vals`` (whose slab ``lo[v]`` is source row
    ``first[v]``) that are the results of programs ``progs``."""
    lo, n = lo[vals], np.maximum(hi[vals] - lo[vals] + 1, 0)
    step = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    src = np.repeat(first[vals], n) + step
    dst = np.repeat(progs * n_sl + lo, n) + step
    return src, dst


def render_tokens(tokens: torch.Tensor, dim: int, lengths: torch.Tensor | None = None) -> torch.Tensor:
    """Render token-index programs ``(B, T)`` (padded with ``$``) to bool ``(B, 64, 64[, 64])``
    on the tokens' device."""
    tokens = torch.as_tensor(tokens)
    kinds, params = encode_tokens(tokens, dim, lengths)
    return _execute_plan(kinds, params, dim, tokens.long(), as_bool=True)


def render_programs(programs: Sequence[Program | str], dim: int, device=None) -> torch.Tensor:
    """Render programs (objects or text, any integer parameters) to bool ``(B, 64, 64[, 64])``."""
    kinds, params = encode_programs(programs, dim, device)
    return _execute_plan(kinds, params, dim, None, as_bool=True)


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
        kinds, params = encode_programs(programs, dim)
    k = k or _max_depth(kinds)
    tr = execute(kinds, params, dim, trace_k=k, token_ids=ids).trace
    return tr if packed else unpack(tr, dim)
