"""Planned execution: a batch of programs as a table of operations ordered by tree height, computed on
the slab ranges where values can be non-zero (no stack, no trace)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..primitives import SIZE
from ..vocab import codes
from .buffers import _POOL, _WORKSPACE, unpack
from .raster import _DRAW_BYTES, _DRAW_MAX, _UNPACK_BYTES, _blocks, _canvas_words, _slab_range, draw_packed
from .stack import Execution, apply_op_
from .tokens import primitive_cache

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
    c = codes()
    for t in range(T):
        k = kinds[:, t]
        stopped |= k == c.stop
        live = ~stopped & ~broken
        is_draw = live & c.is_draw(k)
        is_op = live & c.is_op(k)
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
    op_codes = codes().op
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
        k_flat, p_flat = kinds.reshape(-1), params.reshape(-1, params.shape[-1])
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
        u, i = code == op_codes["+"], code == op_codes["*"]
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
