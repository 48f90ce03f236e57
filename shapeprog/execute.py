"""Differentiable ShapeAssembly executor (one code path, batched over blocks).

The executor reproduces the reference's ordinary (hierarchical) execution, spec section (b):
cuboid frames, Cuboid re-declaration, the attach rules *first* / *second* / *general* /
*aligned* (grid nearest points, 5% gap), squeeze / reflect / translate expansion, bbox
rules, breadth-first hierarchical placement with per-axis dims scaling (positions not
scaled) and the reflect flip of sub-programs. The same code computes values and, through
autograd, gradients with respect to every continuous number of the program text.

How it works:
    1. *Compile* (static, from the AST): every block becomes a list of primitive ops.
       Which attach rule a statement uses depends only on the program's structure (how many
       attachment records the moved cuboid has, its aligned flag), so it is decided here, as
       are macro names and the sub-program tree.
    2. *Run* the local programs of all blocks (of one or many programs) in lock step: at
       step ``t`` the ``t``-th op of every block runs, grouped by rule, as batched tensor
       ops. Value-dependent decisions (thresholds, roots, nearest points) are masks.
    3. *Place* the local results breadth first (``apply_delta``, reflect flips).

Continuous parameters are one flat tensor in text order (:func:`program_parameters`;
the order of :func:`shapeprog.lang.numbers`), so ``execute(p, params=t)`` is
differentiable in ``t`` and :func:`shapeprog.lang.replace_numbers` writes values back.

Example:
    >>> from shapeprog.lang import parse
    >>> p = parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\\n"
    ...           "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> s = execute(p)
    >>> s.centers.tolist()
    [[0.0, -0.4000000059604645, 0.0]]
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .geometry import corners_unchecked, cuboid_corners, mesh_arrays
from .lang import AXES, NUM_FIELDS, Attach, Cuboid, Program, Reflect, Squeeze, Translate, numbers, statement_lines

__all__ = ["ExecutedShape", "ExecutionPlan", "execute", "execute_batch", "program_parameters", "parameter_names"]

EPS = 0.01
SMALL_EPS = 1e-4
COS_DIST_THRESH = 0.9
GRID = 10

# face -> (axis index k, "val"): val is 0 for the positive faces, 1 for the negative ones.
_FACE = {"right": (0, 0), "left": (0, 1), "top": (1, 0), "bot": (1, 1), "front": (2, 0), "back": (2, 1)}
_OPP = {"right": "left", "left": "right", "top": "bot", "bot": "top", "front": "back", "back": "front"}
_DIM_ORDER = (1, 2, 0)  # height, width, length

FIRST, SECOND, GENERAL, ALIGNED = 0, 1, 2, 3


# ----------------------------------------------------------------------------- result


@dataclass
class ExecutedShape:
    """Leaf cuboids of an executed program (bbox cuboids excluded), in the spec's order:
    breadth-first over program nodes, declared order then macro copies within a node.

    Attributes:
        centers: (L, 3) float, cuboid centres.
        dims: (L, 3) float, extents along the cuboid's right/up/front axes.
        axes: (L, 3, 3) float, rows are the unit right/up/front vectors.
        corners: (L, 8, 3) float, corners in the spec's order.
        node: (L,) int64, index of the program block (``Program_k`` -> k) of each leaf.
        line: (L,) int64, 0-based file line of the statement that created each leaf
            (its Cuboid line, or the reflect/translate line for macro copies).
        root_dims: (3,) float, the root bbox dims.
    """

    centers: torch.Tensor
    dims: torch.Tensor
    axes: torch.Tensor
    corners: torch.Tensor
    node: torch.Tensor
    line: torch.Tensor
    root_dims: torch.Tensor

    def __len__(self) -> int:
        return self.centers.shape[0]

    def mesh(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(vertices (8L, 3) float, faces (12L, 3) int64), the reference's OBJ layout."""
        return mesh_arrays(self.corners)


# ----------------------------------------------------------------------------- compile


@dataclass
class _AttachOp:
    a: int
    b: int
    mode: int
    src: tuple  # affine form (c0 (3,), c1 (3,), idx (3,)), idx into the program's parameters (-1: none)
    tgt: tuple | None  # affine form, or None for a macro (computed at run time)
    prior: list  # list of (op index, role 0=subject 1=target) of a's earlier records
    macro: tuple | None = None  # (orig op j, src slot A, target slot T, kind 'R'|'T', k, i, N, d idx)
    j: int = 0  # index among the block's attach ops (its record row)


@dataclass
class _BlockCode:
    name: str
    slots: list[str]
    init_dims: list  # per slot: 3 param indices (or None -> zeros until copied)
    ops: list  # ('attach', _AttachOp) | ('setdims', slot, idx3) | ('copy', new, src)
    steps: list  # ops grouped by dependency level (ops of one level are independent)
    slot_line: list[int]
    slot_source: list[int | None]  # macro copies: the source slot
    slot_reflect_axis: list[int | None]
    child_names: list[str | None]  # per Cuboid line (bbox first): sub-program name or None


def _aff(consts=(0.0, 0.0, 0.0), scales=(0.0, 0.0, 0.0), idx=(-1, -1, -1)):
    return (tuple(consts), tuple(scales), tuple(idx))


def _compile_block(block, offset: int, lines: list[int]) -> tuple[_BlockCode, int]:
    """Static lowering of one block; ``offset`` is the index of its first parameter in the
    program's parameters. Returns the code and the index after its last parameter."""
    slots: dict[str, int] = {}
    names: list[str] = []
    init_dims: list = []
    aligned: list[bool] = []
    slot_line: list[int] = []
    slot_source: list = []
    slot_axis: list = []
    child_names: list = []
    ops: list = []
    records: list[list[tuple[int, int]]] = []  # per slot: (op index, role)
    move_atts: list[list[int]] = []  # per slot: op indices where it was the subject
    att_ops: list[_AttachOp] = []  # attach op j is att_ops[j]
    p = offset
    levels: list[int] = []
    last_w: dict[int, int] = {}
    last_r: dict[int, int] = {}

    def schedule(write: int, reads: tuple) -> None:
        """Dependency level of the op just appended: after earlier writes and reads of the
        slot it writes and after earlier writes of the slots it reads."""
        lvl = 1 + max([last_w.get(write, -1), last_r.get(write, -1)] + [last_w.get(r, -1) for r in reads])
        last_w[write] = lvl
        for r in reads:
            last_r[r] = max(last_r.get(r, -1), lvl)
        levels.append(lvl)

    def new_slot(name, dims_idx, al, line, source=None, axis=None):
        slots[name] = len(names)
        names.append(name)
        init_dims.append(dims_idx)
        aligned.append(al)
        slot_line.append(line)
        slot_source.append(source)
        slot_axis.append(axis)
        records.append([])
        move_atts.append([])
        return slots[name]

    def attach(a, b, src, tgt, macro=None):
        j = len(att_ops)
        n = len(records[a])
        if aligned[a]:
            mode = FIRST if n == 0 else ALIGNED
        else:
            mode = FIRST if n == 0 else SECOND if n == 1 else GENERAL
        op = _AttachOp(a, b, mode, src, tgt, list(records[a]), macro, j)
        ops.append(("attach", op))
        att_ops.append(op)
        schedule(a, (b,) if macro is None else (b, macro[1], 0))
        records[b].append((j, 1))
        records[a].append((j, 0))
        move_atts[a].append(j)

    new_slot("bbox", None, True, lines[0])
    for si, s in enumerate(block.statements):
        ln = lines[si]
        if isinstance(s, Cuboid):
            idx = (p, p + 1, p + 2)
            p += 3
            child_names.append(s.name if s.name.startswith("Program_") else None)
            if s.name in slots:
                k = slots[s.name]
                if si == 0 and k == 0:
                    init_dims[0] = idx
                else:
                    ops.append(("setdims", k, idx))
                    schedule(k, ())
            else:
                new_slot(s.name, idx, s.aligned, ln)
        elif isinstance(s, Attach):
            a, b = slots[s.a], slots[s.b]
            attach(a, b, _aff(scales=(1, 1, 1), idx=(p, p + 1, p + 2)),
                   _aff(scales=(1, 1, 1), idx=(p + 3, p + 4, p + 5)))
            p += 6
        elif isinstance(s, Squeeze):
            a, b, c = slots[s.a], slots[s.b], slots[s.c]
            iu, iv = p, p + 1
            p += 2
            for face, tgt_slot in ((s.face, b), (_OPP[s.face], c)):
                k, val = _FACE[face]
                src_c = [0.5, 0.5, 0.5]
                src_c[k] = 1.0 - val
                tc = [0.0, 0.0, 0.0]
                ts = [1.0, 1.0, 1.0]
                ti = [-1, -1, -1]
                tc[k] = float(1 - val) if tgt_slot == 0 else float(val)
                ts[k] = 0.0
                free = [d for d in range(3) if d != k]
                ti[free[0]], ti[free[1]] = iu, iv
                attach(a, tgt_slot, _aff(consts=src_c), _aff(tc, ts, ti))
        elif isinstance(s, (Reflect, Translate)):
            A = slots[s.a]
            k = AXES.index(s.axis)
            count = 1 if isinstance(s, Reflect) else s.n
            didx = -1
            if isinstance(s, Translate):
                didx = p
                p += 1
            for i in range(1, count + 1):
                name = f"cube{len(names) - 1}"
                if name in slots:  # a collision re-dimensions the existing cuboid (as the reference)
                    new = slots[name]
                    slot_source[new] = A
                    slot_axis[new] = k if isinstance(s, Reflect) else None
                else:
                    new = new_slot(name, None, aligned[A], ln, A, k if isinstance(s, Reflect) else None)
                ops.append(("copy", new, A))
                schedule(new, (A,))
                for j in list(move_atts[A]):
                    op = att_ops[j]
                    c0, c1, ix = op.src
                    if isinstance(s, Reflect):
                        c0 = tuple(1.0 - c0[d] if d == k else c0[d] for d in range(3))
                        c1 = tuple(-c1[d] if d == k else c1[d] for d in range(3))
                        kind = "R"
                    else:
                        kind = "T"
                    attach(new, op.b, (c0, c1, ix), None, (j, A, op.b, kind, k, i, count, didx))
        else:  # pragma: no cover - the parser only builds the five kinds
            raise TypeError(type(s).__name__)
    steps: list[list] = [[] for _ in range(max(levels, default=-1) + 1)]
    for op, lvl in zip(ops, levels):
        steps[lvl].append(op)
    return _BlockCode(block.name, names, init_dims, ops, steps, slot_line, slot_source, slot_axis, child_names), p


@dataclass
class _Compiled:
    """Static structure of one program."""

    blocks: list[_BlockCode]
    n_params: int
    instances: list  # BFS: (block idx, parent inst, parent slot, flip axis)
    leaf_slots: list  # per block: its slots that are leaves (no bbox, no sub-program)


def _compile(program: Program) -> _Compiled:
    lines = statement_lines(program)
    blocks, off = [], 0
    for b, block_lines in zip(program.blocks, lines):
        code, off = _compile_block(b, off, block_lines)
        blocks.append(code)
    index = {b.name: i for i, b in enumerate(program.blocks)}
    # per block, per slot after the bbox: (sub-program block or None, flip axis)
    children = [[_child_of(c, s, index) for s in range(1, len(c.slots))] for c in blocks]
    leaf_slots = [[s for s, (child, _) in enumerate(ch, 1) if child is None] for ch in children]
    # breadth-first instances; an instance = one placement of a block
    queue = [(0, -1, -1, None)]
    qi = 0
    while qi < len(queue):
        bidx = queue[qi][0]
        queue.extend((child, qi, s, flip) for s, (child, flip) in enumerate(children[bidx], 1) if child is not None)
        qi += 1
    return _Compiled(blocks, off, queue, leaf_slots)


def _child_of(code: _BlockCode, s: int, index: dict) -> tuple[int | None, int | None]:
    """Sub-program block of slot ``s`` (and flip axis for reflected copies)."""
    if s < len(code.child_names):
        name = code.child_names[s]
        return (index[name] if name is not None else None), None
    src = code.slot_source[s]
    if src is None:
        return None, None
    child, _ = _child_of(code, src, index)
    if child is None:
        return None, None
    return child, code.slot_reflect_axis[s]


# ----------------------------------------------------------------------------- params


def program_parameters(program: Program, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """The continuous numbers of ``program`` as a flat (P,) tensor, in text order.

    Order: per block, per statement: Cuboid (l, h, w), attach (x1, y1, z1, x2, y2, z2),
    squeeze (u, v), translate (d). Write values back with
    :func:`shapeprog.lang.replace_numbers`.
    """
    return torch.tensor(numbers(program), dtype=dtype, device=device)


def parameter_names(program: Program) -> list[str]:
    """A readable name per entry of :func:`program_parameters`, e.g. ``'Program_1:3:attach.y2'``
    (block name, 0-based statement index in the block, statement and field)."""
    out = []
    for b in program.blocks:
        for i, s in enumerate(b.statements):
            for f in NUM_FIELDS[type(s)]:
                out.append(f"{b.name}:{i}:{type(s).__name__.lower()}.{f}")
    return out


# ----------------------------------------------------------------------------- tensor helpers


def _point(pos, dims, ax, coords):
    """Global point of local ``coords`` (n, 3) on cuboids (n, 3), (n, 3), (n, 3, 3)."""
    return _point_c(pos, dims, ax, coords - 0.5)


def _point_c(pos, dims, ax, centred):
    """:func:`_point` of ``centred = coords - 0.5`` (computed once where a point is used often)."""
    return pos + torch.bmm((centred * dims).unsqueeze(1), ax).squeeze(1)


def _to_local(pos, dims, ax, pts):
    """Local coordinates of global points ``pts`` (n, m, 3) in cuboids (n, ...)."""
    rel = pts - pos.unsqueeze(1)
    return torch.bmm(rel, ax.transpose(1, 2)) / dims.unsqueeze(1) + 0.5


def _norm(v):
    return torch.linalg.vector_norm(v, dim=-1)


def _rodrigues(axis, angle):
    """(n, 3, 3) rotation matrices about unit ``axis`` (n, 3) by ``angle`` (n,)."""
    n = axis.shape[0]
    z = torch.zeros(n, dtype=axis.dtype, device=axis.device)
    x, y, w = axis.unbind(-1)
    K = torch.stack([z, -w, y, w, z, -x, -y, x, z], -1).reshape(n, 3, 3)
    eye = torch.eye(3, dtype=axis.dtype, device=axis.device).expand(n, 3, 3)
    s = torch.sin(angle)[:, None, None]
    c = torch.cos(angle)[:, None, None]
    return eye + s * K + (1 - c) * torch.bmm(K, K)


def _safe_unit(v, ok, all_ok: bool | None = None):
    """v / |v| where ``ok``; a fixed unit vector elsewhere (keeps gradients finite).
    ``all_ok``: whether every row is ok, when the caller already knows it (None: tested here)."""
    if all_ok is None:
        all_ok = bool(ok.all())
    if all_ok:
        return v / _norm(v)[:, None]
    e = torch.zeros_like(v)
    e[:, 0] = 1.0
    vs = torch.where(ok[:, None], v, e)
    return vs / _norm(vs)[:, None]


def _min_rotation(nb, nc, act):
    """Rotation matrices (n, 3, 3) taking direction nb to nc where ``act``; identity elsewhere.

    The anti-parallel/parallel degenerate case (cross product exactly zero) follows the
    reference: a rotation by pi about nb rotated +90 deg about the first world axis on which
    nb has a non-zero component.
    """
    n = nb.shape[0]
    all_act = bool(act.all())
    nbh = _safe_unit(nb, act, all_act)
    nch = _safe_unit(nc, act, all_act)
    cr = torch.linalg.cross(nbh, nch)
    crn = _norm(cr)
    dot = (nbh * nch).sum(-1)
    with torch.no_grad():
        degenerate = act & (crn == 0)
        # acos of a dot product above 1 is NaN in the reference, which gives the identity
        turn = act & ~degenerate & (dot.abs() <= 1) & (torch.acos(dot.clamp(-1, 1)) != 0)
        all_turn = bool(turn.all())
    if all_turn:
        R = _rodrigues(_safe_unit(cr, turn, True), torch.acos(dot))
    else:
        eye = torch.eye(3, dtype=nb.dtype, device=nb.device).expand(n, 3, 3)
        axis = _safe_unit(cr, turn, False)
        angle = torch.acos(torch.where(turn, dot, torch.zeros_like(dot)))
        R = torch.where(turn[:, None, None], _rodrigues(axis, angle), eye)
    if not all_turn and bool(degenerate.any()):
        for i in degenerate.nonzero().flatten().tolist():
            v = nbh[i]
            k = int((v != 0).nonzero()[0])
            rot90 = _rodrigues(torch.eye(3, dtype=nb.dtype, device=nb.device)[k:k + 1],
                               torch.full((1,), math.pi / 2, dtype=nb.dtype, device=nb.device))[0]
            ax = rot90 @ v
            ax = ax / _norm(ax)
            Ri = _rodrigues(ax[None], torch.full((1,), math.pi, dtype=nb.dtype, device=nb.device))[0]
            R = torch.cat([R[:i], Ri[None], R[i + 1:]])
    return R


def _rotate(ax, R):
    """Apply rotations R (n, 3, 3) to axis rows ax (n, 3, 3)."""
    return torch.bmm(ax, R.transpose(1, 2))


# ----------------------------------------------------------------------------- attach rules


def _rule_first(pos, dims, ax, src, g):
    return pos + (g - _point(pos, dims, ax, src)), dims, ax


def _rule_second(pos, dims, ax, src, g, p_ap, a):
    """Non-aligned cuboid with exactly one earlier record (p_ap, a).

    Value-dependent branches are masks; a branch that no row takes is skipped (same values and
    gradients, fewer operations)."""
    src_c, ap_c = src - 0.5, p_ap - 0.5
    b = _point_c(pos, dims, ax, src_c)
    c = g
    with torch.no_grad():
        act = _norm(b - c) >= SMALL_EPS
        all_act = bool(act.all())
        if not all_act and not bool(act.any()):
            return pos, dims, ax  # every target point is already reached
    dist2 = ((c - a) ** 2).sum(-1)
    nv = src_c[:, :, None] * ax  # (n, 3 dims, 3)
    qv = ap_c[:, :, None] * ax
    m = nv - qv
    w = (b - a)[:, None, :]
    A = (m * m).sum(-1)  # (n, 3)
    B = 2 * (w * m).sum(-1)
    C = (w * w).sum(-1) - dist2[:, None]
    disc = B * B - 4 * A * C
    with torch.no_grad():
        usable = (nv.abs().sum(-1) + qv.abs().sum(-1)) >= SMALL_EPS
        valid = usable & (disc > 0)
    s = (-B + torch.sqrt(torch.where(valid, disc, torch.ones_like(disc)))) / (2 * A + 1e-8)
    order = list(_DIM_ORDER)
    with torch.no_grad():
        score = torch.where(valid, s.abs(), torch.full_like(s, math.inf))[:, order]
        best = torch.tensor(order, device=pos.device)[score.argmin(-1)]
        found = valid.any(-1)
    onehot = torch.nn.functional.one_hot(best, 3).to(dims.dtype)
    s_best = s.gather(1, best[:, None])
    zero = torch.zeros_like(dims)
    if bool(found.all()):
        delta = onehot * s_best
    else:
        # fallback: all three change vectors at once
        mf = nv.sum(1) - qv.sum(1)
        wf = b - a
        Af = (mf * mf).sum(-1)
        Bf = 2 * (wf * mf).sum(-1)
        Cf = (wf * wf).sum(-1) - dist2
        discf = Bf * Bf - 4 * Af * Cf
        with torch.no_grad():
            fvalid = ~found & (discf > 0)
        sf = (-Bf + torch.sqrt(torch.where(fvalid, discf, torch.ones_like(discf)))) / (2 * Af + 1e-8)
        delta = torch.where(found[:, None], onehot * s_best,
                            torch.where(fvalid[:, None], sf[:, None].expand(-1, 3), zero))
    dims1 = dims + (delta if all_act else torch.where(act[:, None], delta, zero))
    pos1 = pos + (a - _point_c(pos, dims1, ax, ap_c))
    nb = _point_c(pos1, dims1, ax, src_c) - a
    nc = c - a
    with torch.no_grad():
        rot = act & (_norm(nb) > 0) & (_norm(nc) > 0) & (_norm(nb - nc) >= SMALL_EPS)
    ax2 = _rotate(ax, _min_rotation(nb, nc, rot)) if bool(rot.any()) else ax
    pos2 = pos1 + (a - _point_c(pos1, dims1, ax2, ap_c))
    if all_act:
        return pos2, dims1, ax2
    return torch.where(act[:, None], pos2, pos), dims1, torch.where(act[:, None, None], ax2, ax)


def _grid(dtype, device):
    """(1000, 3) local grid coordinates i/9, x fastest, then y, then z."""
    t = torch.arange(GRID, dtype=dtype, device=device) / (GRID - 1)
    z, y, x = torch.meshgrid(t, t, t, indexing="ij")
    return torch.stack([x, y, z], -1).reshape(-1, 3)


def _nearest_grid_points(p, d, a, pB, dB, aB, G):
    """Closest pair between the 10x10x10 local grids of cuboids A and B (spec: aligned).

    Returns the local grid coordinates (m, 3) of the A point ``b`` with the smallest distance
    to B's grid (ties: lowest A index, x fastest) and of its nearest B point ``c``.
    B's axes are orthonormal, so the nearest B grid point of any point is found per B axis
    by rounding its local coordinate; no pairwise search is needed. When both frames are
    the identity (the common case) the problem also separates over A's axes.
    """
    m = p.shape[0]
    out_dtype = p.dtype
    # Decided in float64 with near-ties (1e-9 in squared distance) going to the lowest A
    # index, so the choice does not depend on the execution dtype.
    p, d, a, pB, dB, aB, G = (x.double() for x in (p, d, a, pB, dB, aB, G))
    t = G[:GRID, 0]  # the 10 grid values i/9
    eye = torch.eye(3, dtype=a.dtype, device=a.device)
    ident = (a == eye).flatten(1).all(-1) & (aB == eye).flatten(1).all(-1)
    r = torch.empty(m, 3, dtype=p.dtype, device=p.device)
    cl = torch.empty_like(r)
    first_min = lambda e: (e <= e.min(-1, keepdim=True).values + 1e-9).to(torch.int8).argmax(-1)  # noqa: E731
    fi = ident.nonzero().flatten()
    if fi.numel():
        # 1-D problems per axis: A coordinates (m, 3, 10) against B's 10 coordinates.
        xa = p[fi, :, None] + (t - 0.5) * d[fi, :, None]
        u = (xa - pB[fi, :, None]) / dB[fi, :, None] + 0.5
        near = (u * (GRID - 1)).round().clamp(0, GRID - 1) / (GRID - 1)
        e = ((u - near) * dB[fi, :, None]) ** 2  # (m, 3, 10)
        i = first_min(e)  # lowest index per axis among the minima
        r[fi] = t[i]
        cl[fi] = near.gather(2, i[:, :, None])[:, :, 0]
    si = (~ident).nonzero().flatten()
    if si.numel():
        ptsA = p[si, None, :] + torch.bmm((G[None] - 0.5) * d[si, None, :], a[si])  # (m, 1000, 3)
        u = _to_local(pB[si], dB[si], aB[si], ptsA)
        near = (u * (GRID - 1)).round().clamp(0, GRID - 1) / (GRID - 1)
        d2 = (((u - near) * dB[si, None, :]) ** 2).sum(-1)
        k = first_min(d2)
        r[si] = G[k]
        cl[si] = near[torch.arange(si.numel()), k]
    return r.to(out_dtype), cl.to(out_dtype)


def _rule_aligned(pos, dims, ax, posB, dimsB, axB):
    """Aligned cuboid with earlier records: grow towards B (the target point is ignored)."""
    with torch.no_grad():
        # corners of A in B's frame and of B in A's frame, both directions in one pass
        n = pos.shape[0]
        both = torch.cat([pos, posB]), torch.cat([dims, dimsB]), torch.cat([ax, axB])
        other = torch.cat([posB, pos]), torch.cat([dimsB, dims]), torch.cat([axB, ax])
        u = _to_local(*other, corners_unchecked(*both))
        inside = ((u >= 0) & (u <= 1)).all(-1).any(-1)
        idx = (~(inside[:n] | inside[n:])).nonzero().flatten()
    if idx.numel() == 0:
        return pos, dims, ax
    p, d, a = pos[idx], dims[idx], ax[idx]
    pB, dB, aB = posB[idx], dimsB[idx], axB[idx]
    G = _grid(pos.dtype, pos.device)
    with torch.no_grad():
        r, cl = _nearest_grid_points(p, d, a, pB, dB, aB, G)
    b = _point(p, d, a, r)
    c = _point(pB, dB, aB, cl)
    with torch.no_grad():
        big = torch.cat([d, dB], -1).max(-1).values
        grow = _norm(b - c) >= 0.05 * big
    rr_c = (1 - r) - 0.5
    o = _point_c(p, d, a, rr_c)
    cv = (r - 0.5) * torch.diagonal(a, dim1=1, dim2=2)
    with torch.no_grad():
        nz = cv != 0
    D = (c - b) / (2 * torch.where(nz, cv, torch.ones_like(cv)))
    with torch.no_grad():
        use = nz & (D > 0) & grow[:, None]
    d1 = d + torch.where(use, D, torch.zeros_like(D))
    p1 = p + (o - _point_c(p, d1, a, rr_c))
    p1 = torch.where(grow[:, None], p1, p)
    pos = pos.index_copy(0, idx, p1)
    dims = dims.index_copy(0, idx, d1)
    return pos, dims, ax


def _cv(ap, ax, k):
    return (ap[k] - 0.5) * ax[k]


def _val(x: torch.Tensor) -> float:
    """A decision value (no gradient)."""
    return float(x.detach())


def _rule_general(pos, dims, ax, src, g, prev):
    """Non-aligned cuboid with two or more earlier records ``prev``: list of (ap (3,), g (3,)).

    One cuboid at a time (no corpus program reaches this rule)."""
    pos, dims, ax, src, g = pos[0], dims[0], ax[0], src[0], g[0]
    P = lambda pp, dd, aa, cc: pp + ((cc - 0.5) * dd) @ aa  # noqa: E731
    if len(prev) == 2:
        colinear = True
    else:
        o = prev[0][1]
        l = prev[1][1] - o
        colinear = all(_val(_norm(torch.linalg.cross(pg - o, l))) <= EPS for _, pg in prev)
    if colinear:
        a0, a1 = prev[0][1], prev[1][1]
        axis = (a0 - a1) / (_norm(a0 - a1) + 1e-8)
        b = P(pos, dims, ax, src)
        c = g
        c_p = c - ((c - b) @ axis) * axis
        a_p = a0 - ((a0 - b) @ axis) * axis
        fn = b - a_p
        noc = c_p - a_p
        s = _norm(noc) / _norm(fn) - 1
        if not bool(torch.isnan(s.detach())):
            nob = fn * (1 + s)
            if _val(_norm(nob)) != 0 and _val(_norm(noc)) != 0 and _val(_norm(nob - noc)) >= EPS:
                nobh, noch = nob / _norm(nob), noc / _norm(noc)
                angle = torch.acos((nobh @ noch).clamp(-1, 1))
                R = _rodrigues(axis[None], angle[None])[0]
                if _val(_norm(R @ nobh - noch)) > EPS:
                    R = _rodrigues(-axis[None], angle[None])[0]
                ax = ax @ R.T
                pos = pos + (a0 - P(pos, dims, ax, prev[0][0]))
    b = P(pos, dims, ax, src)
    t = g - b
    if _val(_norm(t)) >= EPS:
        pick = None
        for k in _DIM_ORDER:
            c0 = _cv(prev[0][0], ax, k)
            if all(_val(_norm(_cv(pa, ax, k) - c0)) < EPS for pa, _ in prev):
                cvk = _cv(src, ax, k)
                nrm = _norm(cvk)
                if _val(nrm) > 0 and _val((cvk / nrm) @ (t / _norm(t))) > COS_DIST_THRESH:
                    pick = k  # the reference keeps the *last* qualifying dim (trap 4)
        if pick is not None:
            cvk = _cv(src, ax, pick)
            d = 1 / (_norm(cvk - _cv(prev[0][0], ax, pick)) + 1e-8)
            s = (t @ (cvk / _norm(cvk))).abs()
            dims = dims + torch.nn.functional.one_hot(torch.tensor(pick, device=dims.device), 3).to(dims.dtype) * (s * d)
            pos = pos + (prev[0][1] - P(pos, dims, ax, prev[0][0]))
    return pos[None], dims[None], ax[None]


# ----------------------------------------------------------------------------- plan


@dataclass
class _GroupPlan:
    """The attach ops of one rule at one step, over all blocks, as index tensors and constants.

    The state is kept in flat rows: cuboid slot ``s`` of block row ``k`` is row ``k * S + s`` of
    the pos / dims / axes tensors; attachment record ``j`` of block row ``k`` holds its src, tgt
    and global points in rows ``(k * J + j) * 3 + (0, 1, 2)`` of the record tensor."""

    mode: int
    n: int
    row_a: torch.Tensor  # (n,) state row of the moved cuboid
    row_b: torch.Tensor  # (n,) state row of the target cuboid
    c0: torch.Tensor  # (2n, 3) affine constants: the n src rows, then the n tgt rows
    c1: torch.Tensor  # (2n, 3) affine scales
    ix: torch.Tensor  # (2n, 3) parameter indices (-1: the trailing zero)
    macro: dict | None  # reflect / translate copies, see _macro_points
    prior: tuple | None  # SECOND: record rows of the earlier record's point on A and of its global point
    general: list | None  # GENERAL: per row, [(record row of the point on A, record row of the global point)]
    keep: torch.Tensor | None  # group rows whose record a later op reads (None: every row)
    rec_rows: torch.Tensor | None  # record rows written (None: no record of the group is read later)


@dataclass
class _StepPlan:
    setdims: tuple | None  # (state rows, parameter indices (n, 3))
    copy: tuple | None  # (new state rows, source state rows)
    groups: list  # of _GroupPlan


@dataclass
class _LevelPlan:
    """Placement of the block instances at one depth of the sub-program trees."""

    rows: torch.Tensor  # (m,) block row of each instance
    parent: torch.Tensor | None  # (m,) row parent instance * S + parent slot in the previous level (None: roots)
    root_ix: torch.Tensor | None  # roots: (m, 3) parameter indices of the root bbox dims
    pos_sign: torch.Tensor | None  # (m, 1, 3) reflect flip of positions (None: no flip at this level)
    ax_sign: torch.Tensor | None  # (m, 1, 1, 3) reflect flip (180 deg turn) of the axes


def _shift(form, off):
    return (form[0], form[1], tuple(i + off if i >= 0 else -1 for i in form[2]))


def _plan_group(mode, items, offsets, S, J, dtype, device, read: set) -> _GroupPlan:
    """Index tensors and constants of one attach group; ``items``: (block row, record index, op);
    ``read``: the (block row, record index) pairs that later ops read.

    The integers, the floats and the flags each go into one tensor, split into views (building
    the plan is part of every :func:`execute` call)."""
    rec_row = lambda blk, j, role: (blk * J + j) * 3 + role  # noqa: E731
    n = len(items)
    ints: list = []  # (name, values, shape)
    floats: list = []
    flags: list = []
    ints.append(("row_a", [blk * S + o.a for blk, _, o in items], (n,)))
    ints.append(("row_b", [blk * S + o.b for blk, _, o in items], (n,)))
    none = ((0.0,) * 3, (0.0,) * 3, (-1, -1, -1))
    src_forms, tgt_forms, macro_rows = [], [], []
    for r, (blk, _, o) in enumerate(items):
        if o.macro is None:
            src_forms.append(_shift(o.src, offsets[blk]))
            tgt_forms.append(_shift(o.tgt, offsets[blk]))
        else:  # computed at run time from the original record (_macro_points)
            src_forms.append(none)
            tgt_forms.append(none)
            macro_rows.append(r)
    forms = src_forms + tgt_forms
    floats.append(("c0", [x for f in forms for x in f[0]], (2 * n, 3)))
    floats.append(("c1", [x for f in forms for x in f[1]], (2 * n, 3)))
    ints.append(("ix", [x for f in forms for x in f[2]], (2 * n, 3)))
    if macro_rows:
        ms = [(items[r][0], items[r][2].macro) for r in macro_rows]
        m = len(ms)
        ints.append(("r_idx", macro_rows, (m,)))
        ints.append(("ap", [rec_row(blk, mc[0], 0) for blk, mc in ms], (m,)))  # the original record's point on A
        ints.append(("A", [blk * S + mc[1] for blk, mc in ms], (m,)))
        ints.append(("T", [blk * S + mc[2] for blk, mc in ms], (m,)))
        ints.append(("box", [blk * S for blk, _ in ms], (m,)))
        ints.append(("didx", [offsets[blk] + mc[7] if mc[7] >= 0 else -1 for blk, mc in ms], (m,)))
        e = [[1.0 if k == mc[4] else 0.0 for k in range(3)] for _, mc in ms]
        floats.append(("e", [x for row in e for x in row], (m, 3)))
        floats.append(("ii", [float(mc[5]) for _, mc in ms], (m,)))
        floats.append(("N", [float(mc[6]) for _, mc in ms], (m,)))
        is_ref = [mc[3] == "R" for _, mc in ms]
        flags.append(("is_ref", is_ref, (m,)))
        flags.append(("flip", [r and k == mc[4] for r, (_, mc) in zip(is_ref, ms) for k in range(3)], (m, 3)))
    if mode == SECOND:
        ints.append(("prior_ap", [rec_row(blk, *o.prior[0]) for blk, _, o in items], (n,)))
        ints.append(("prior_g", [rec_row(blk, o.prior[0][0], 2) for blk, _, o in items], (n,)))
    rows = [r for r, (blk, j, _) in enumerate(items) if (blk, j) in read]
    if rows and len(rows) < n:
        ints.append(("keep", rows, (len(rows),)))
    if rows:
        ints.append(("rec_rows", [rec_row(items[r][0], items[r][1], role) for r in rows for role in range(3)],
                     (3 * len(rows),)))

    def pack(entries, **kw):
        flat_vals = [x for _, vals, _ in entries for x in vals]
        t = torch.tensor(flat_vals, **kw)
        parts = t.split([len(vals) for _, vals, _ in entries])
        return {name: part.view(shape) for (name, _, shape), part in zip(entries, parts)}

    iv = pack(ints, dtype=torch.int64, device=device)
    fv = pack(floats, dtype=dtype, device=device)
    bv = pack(flags, dtype=torch.bool, device=device) if flags else {}
    macro = None
    if macro_rows:
        macro = dict(r_idx=iv["r_idx"], ap=iv["ap"], A=iv["A"], T=iv["T"], box=iv["box"], didx=iv["didx"],
                     ii=fv["ii"], N=fv["N"], e=fv["e"], is_ref=bv["is_ref"], flip=bv["flip"],
                     any_ref=any(is_ref), any_tr=not all(is_ref))
    prior = (iv["prior_ap"], iv["prior_g"]) if mode == SECOND else None
    general = None
    if mode == GENERAL:
        general = [[(rec_row(blk, j, role), rec_row(blk, j, 2)) for j, role in o.prior] for blk, _, o in items]
    return _GroupPlan(mode, n, iv["row_a"], iv["row_b"], fv["c0"], fv["c1"], iv["ix"], macro, prior, general,
                      iv.get("keep"), iv.get("rec_rows"))


def _plan_steps(codes: list[_BlockCode], offsets: list[int], S: int, J: int, dtype, device) -> list[_StepPlan]:
    """Lock-step schedule: step ``t`` runs the ``t``-th dependency level of every block."""
    read = set()  # attachment records that some op reads: second / general priors, macro sources
    for bi, c in enumerate(codes):
        for op in c.ops:
            if op[0] == "attach":
                o = op[1]
                if o.mode in (SECOND, GENERAL):
                    read.update((bi, j) for j, _ in o.prior)
                if o.macro is not None:
                    read.add((bi, o.macro[0]))
    steps = []
    for t in range(max(len(c.steps) for c in codes)):
        groups: dict = {}
        setd, copy = [], []
        for bi, c in enumerate(codes):
            if t >= len(c.steps):
                continue
            for op in c.steps[t]:
                if op[0] == "attach":
                    o = op[1]
                    groups.setdefault(o.mode, []).append((bi, o.j, o))
                elif op[0] == "setdims":
                    setd.append((bi * S + op[1],) + tuple(offsets[bi] + i for i in op[2]))
                else:
                    copy.append((bi * S + op[1], bi * S + op[2]))
        sd = cp = None
        if setd:
            t_ = torch.tensor(setd, device=device)
            sd = (t_[:, 0], t_[:, 1:])
        if copy:
            cp = torch.tensor(copy, device=device).unbind(1)
        plans = [_plan_group(m, it, offsets, S, J, dtype, device, read) for m, it in groups.items()]
        steps.append(_StepPlan(sd, cp, plans))
    return steps


def _plan_levels(comps: list[_Compiled], block_base: list[int], param_base: list[int], S: int, dtype, device):
    """Placement levels and the leaf gather of a batch of programs.

    Returns the levels, the row (instance * S + slot) of every leaf in output order (instances
    numbered level after level), and the leaf count, node and line tensors per program.
    """
    per_level: list[list] = []  # per depth: (program, local instance)
    where: list[dict] = []  # per program: local instance -> (depth, index in level)
    for pi, comp in enumerate(comps):
        depth = []
        loc = {}
        for li, (_, parent, _, _) in enumerate(comp.instances):
            d = 0 if parent < 0 else depth[parent] + 1
            depth.append(d)
            while len(per_level) <= d:
                per_level.append([])
            loc[li] = (d, len(per_level[d]))
            per_level[d].append((pi, li))
        where.append(loc)
    level_base = [0]
    for lv in per_level:
        level_base.append(level_base[-1] + len(lv))
    lt = lambda v: torch.tensor(v, dtype=torch.int64, device=device)  # noqa: E731
    levels = []
    for d, lv in enumerate(per_level):
        rows, parent, root_ix, pos_sign, ax_sign = [], [], [], [], []
        for pi, li in lv:
            bidx, par, ps, flip = comps[pi].instances[li]
            rows.append(block_base[pi] + bidx)
            if d == 0:
                root_ix.append([param_base[pi] + k for k in range(3)])
            else:
                parent.append(where[pi][par][1] * S + ps)
            sign = [1.0, 1.0, 1.0]
            if flip is not None:
                sign[flip] = -1.0
            pos_sign.append(sign)
            # a reflected copy's axes: -(axes * sign), a 180 degree turn
            ax_sign.append([-x for x in sign] if flip is not None else sign)
        flips = any(comps[pi].instances[li][3] is not None for pi, li in lv)
        levels.append(_LevelPlan(
            rows=lt(rows),
            parent=lt(parent) if d else None,
            root_ix=lt(root_ix) if d == 0 else None,
            pos_sign=torch.tensor(pos_sign, dtype=dtype, device=device)[:, None] if flips else None,
            ax_sign=torch.tensor(ax_sign, dtype=dtype, device=device)[:, None, None] if flips else None,
        ))
    leaf_rows, counts, nodes, lines = [], [], [], []
    for pi, comp in enumerate(comps):
        node, line = [], []
        for li, (bidx, _, _, _) in enumerate(comp.instances):
            code = comp.blocks[bidx]
            keep = comp.leaf_slots[bidx]
            d, k = where[pi][li]
            leaf_rows.extend((level_base[d] + k) * S + s for s in keep)
            node.extend([int(code.name.split("_")[1]) if code.name.startswith("Program_") else bidx] * len(keep))
            line.extend(code.slot_line[s] for s in keep)
        counts.append(len(node))
        nodes.append(lt(node))
        lines.append(lt(line))
    return levels, lt(leaf_rows), counts, nodes, lines


class ExecutionPlan:
    """Programs compiled for execution, reusable: static structure, index tensors and constants.

    Building a plan does everything that does not depend on the parameter values (the rule of
    every attach, macro expansion, the lock-step schedule, the sub-program tree, the leaf order);
    :meth:`run` then only does tensor arithmetic. :func:`execute` and :func:`execute_batch` build
    a plan per call; a caller that executes the same programs many times (fitting, a training
    loop with fixed structure) builds it once.

    Example:
        >>> from shapeprog.lang import parse
        >>> p = parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\\n"
        ...           "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
        >>> plan = ExecutionPlan([p])
        >>> x = program_parameters(p).requires_grad_(True)
        >>> plan.run([x])[0].centers.tolist()
        [[0.0, -0.4000000059604645, 0.0]]
    """

    def __init__(self, programs: list[Program], dtype: torch.dtype = torch.float32, device=None):
        if isinstance(programs, Program):
            raise TypeError("`programs` must be a list of programs; use ExecutionPlan([program])")
        self.programs = list(programs)
        self.dtype = dtype
        self.device = torch.device("cpu") if device is None else torch.device(device)
        comps = [_compile(p) for p in self.programs]
        self.n_params = [c.n_params for c in comps]
        codes, offsets, block_base, param_base = [], [], [], []
        poff = 0
        for c in comps:
            block_base.append(len(codes))
            param_base.append(poff)
            codes.extend(c.blocks)
            offsets.extend([poff] * len(c.blocks))
            poff += c.n_params
        self._param_base = param_base
        if not codes:
            return
        dev = self.device
        S = max(len(c.slots) for c in codes)
        init = []
        for c, off in zip(codes, offsets):
            rows = [(-1, -1, -1) if d is None else tuple(off + i for i in d) for d in c.init_dims]
            init.append(rows + [(-1, -1, -1)] * (S - len(rows)))
        self._nb, self._S = len(codes), S
        self._init_ix = torch.tensor(init, dtype=torch.int64, device=dev).reshape(-1, 3)  # (nb * S, 3)
        self._n_rec = max([sum(1 for o in c.ops if o[0] == "attach") for c in codes] + [1])
        self._steps = _plan_steps(codes, offsets, S, self._n_rec, dtype, dev)
        self._levels, self._leaves, self._counts, self._nodes, self._lines = _plan_levels(
            comps, block_base, param_base, S, dtype, dev)

    def __len__(self) -> int:
        return len(self.programs)

    def parameters(self) -> list[torch.Tensor]:
        """The programs' own numbers, one (P_i,) tensor each (see :func:`program_parameters`)."""
        return [program_parameters(p, self.dtype, self.device) for p in self.programs]

    def run(self, params: list[torch.Tensor | None] | None = None) -> list[ExecutedShape]:
        """Execute the programs, with their own numbers or with ``params`` (one (P_i,) tensor or
        None per program); the result is differentiable in the given tensors."""
        if not self.programs:
            return []
        if params is not None and len(params) != len(self.programs):
            raise ValueError(f"`params` must hold {len(self.programs)} tensors, got {len(params)}")
        flats = []
        for i, p in enumerate(self.programs):
            t = None if params is None else params[i]
            if t is None:
                t = program_parameters(p, self.dtype, self.device)
            else:
                if t.dim() != 1 or t.shape[0] != self.n_params[i]:
                    raise ValueError(
                        f"`params` for program {i} must have shape ({self.n_params[i]},), got {tuple(t.shape)}")
                t = t.to(dtype=self.dtype, device=self.device)
            flats.append(t)
        flat = torch.cat(flats + [torch.zeros(1, dtype=self.dtype, device=self.device)])  # index -1 -> 0
        pos, dims, ax = self._run_steps(flat)
        return self._place(flat, pos, dims, ax)

    def _run_steps(self, flat: torch.Tensor):
        """Local programs of all blocks in lock step. State in flat rows (block row * S + slot):
        pos (R, 3), dims (R, 3), axes (R, 3, 3)."""
        dtype, device = self.dtype, self.device
        dims = flat[self._init_ix]  # dims from the declaring lines
        R = dims.shape[0]
        pos = torch.zeros(R, 3, dtype=dtype, device=device)
        ax = torch.eye(3, dtype=dtype, device=device).repeat(R, 1, 1)
        rec = torch.zeros(self._nb * self._n_rec * 3, 3, dtype=dtype, device=device)  # src, tgt, g per attach
        for step in self._steps:
            if step.setdims is not None:
                rows, ix = step.setdims
                dims.index_copy_(0, rows, flat[ix])
            if step.copy is not None:
                new, src = step.copy
                n = new.shape[0]
                dims.index_copy_(0, new, dims[src])
                pos.index_fill_(0, new, 0.0)
                ax.index_copy_(0, new, torch.eye(3, dtype=dtype, device=device).expand(n, 3, 3))
            for grp in step.groups:
                _run_attach_group(grp, flat, pos, dims, ax, rec)
        return pos, dims, ax

    def _place(self, flat, pos, dims, ax) -> list[ExecutedShape]:
        """Breadth-first placement, one batched pass per depth (apply_delta and reflect flips)."""
        S = self._S
        pos, dims, ax = pos.view(-1, S, 3), dims.view(-1, S, 3), ax.view(-1, S, 3, 3)
        wps, wds, was = [], [], []
        prev = None
        for lv in self._levels:
            lp, ld, la = pos[lv.rows], dims[lv.rows], ax[lv.rows]
            if lv.pos_sign is not None:
                lp = lp * lv.pos_sign
                la = la * lv.ax_sign
            rdims = ld[:, 0]
            if prev is None:  # roots: the identity frame at the origin, dims from the root bbox line
                wd = ld * (flat[lv.root_ix] / rdims)[:, None]
                wp, wa = lp, la
            else:
                pp, pd, pa = prev
                apos = pp.reshape(-1, 3)[lv.parent]
                adims = pd.reshape(-1, 3)[lv.parent]
                aax = pa.reshape(-1, 3, 3)[lv.parent]
                # apply_delta: scale dims per local axis index, rotate positions (not scaled)
                wd = ld * (adims / rdims)[:, None]
                wp = torch.bmm(lp, aax) + apos[:, None]
                wa = torch.matmul(la, aax[:, None])
            prev = (wp, wd, wa)
            wps.append(wp)
            wds.append(wd)
            was.append(wa)
        if len(wps) == 1:
            wp, wd, wa = wps[0], wds[0], was[0]
        else:
            wp, wd, wa = torch.cat(wps), torch.cat(wds), torch.cat(was)
        rows = self._leaves
        centers = wp.reshape(-1, 3)[rows]
        dd = wd.reshape(-1, 3)[rows]
        aa = wa.reshape(-1, 3, 3)[rows]
        corners = cuboid_corners(centers, dd, aa)
        out = []
        parts = [x.split(self._counts) for x in (centers, dd, aa, corners)]
        for i, (c, d, a, k) in enumerate(zip(*parts)):
            base = self._param_base[i]
            out.append(ExecutedShape(centers=c, dims=d, axes=a, corners=k, node=self._nodes[i],
                                     line=self._lines[i], root_dims=flat[base:base + 3].clone()))
        return out


# ----------------------------------------------------------------------------- run


def _run_attach_group(grp: _GroupPlan, flat, pos, dims, ax, rec) -> None:
    """One attach group: move the subjects (state updated in place) and keep the records."""
    n = grp.n
    vals = grp.c0 + grp.c1 * flat[grp.ix]
    src, tgt = vals[:n], vals[n:]
    if grp.macro is not None:
        src, tgt = _macro_points(grp.macro, flat, pos, dims, ax, rec, src, tgt)
    rb, ra = grp.row_b, grp.row_a
    posB, dimsB, axB = pos[rb], dims[rb], ax[rb]
    g = _point(posB, dimsB, axB, tgt)
    posA, dimsA, axA = pos[ra], dims[ra], ax[ra]
    mode = grp.mode
    if mode == FIRST:
        posA, dimsA, axA = _rule_first(posA, dimsA, axA, src, g)
    elif mode == SECOND:
        r_ap, r_g = grp.prior
        posA, dimsA, axA = _rule_second(posA, dimsA, axA, src, g, rec[r_ap], rec[r_g])
    elif mode == ALIGNED:
        posA, dimsA, axA = _rule_aligned(posA, dimsA, axA, posB, dimsB, axB)
    else:
        outs = []
        for r, prior in enumerate(grp.general):
            prev = [(rec[r_ap], rec[r_g]) for r_ap, r_g in prior]
            outs.append(_rule_general(posA[r:r + 1], dimsA[r:r + 1], axA[r:r + 1], src[r:r + 1], g[r:r + 1], prev))
        posA = torch.cat([o[0] for o in outs])
        dimsA = torch.cat([o[1] for o in outs])
        axA = torch.cat([o[2] for o in outs])
    pos.index_copy_(0, ra, posA)
    if mode != FIRST:  # the first rule only translates
        dims.index_copy_(0, ra, dimsA)
        if mode != ALIGNED:  # the aligned rule never turns a cuboid
            ax.index_copy_(0, ra, axA)
    if grp.rec_rows is not None:  # only records that a later op reads
        recs = torch.stack([src, tgt, g], 1)
        if grp.keep is not None:
            recs = recs[grp.keep]
        rec.index_copy_(0, grp.rec_rows, recs.reshape(-1, 3))


def _macro_points(m: dict, flat, pos, dims, ax, rec, src, tgt):
    """Source/target local points of reflect/translate copies (spec: reflect, translate)."""
    A, T, e = m["A"], m["T"], m["e"]
    ap = rec[m["ap"]]  # the original record's source point on A
    src_m = torch.where(m["flip"], 1 - ap, ap)
    p = _point(pos[A], dims[A], ax[A], ap)
    pg = None
    if m["any_ref"]:
        # reflect through the plane through the bbox centre (origin) normal to world axis k
        pg = p - 2 * e * p
    if m["any_tr"]:
        # translate: p + i * (L * d / N) * e, L = local bbox extent along k
        L = (dims[m["box"]] * e).sum(-1)
        step = L * flat[m["didx"]] / m["N"]
        p_tr = p + (m["ii"] * step)[:, None] * e
        pg = p_tr if pg is None else torch.where(m["is_ref"][:, None], pg, p_tr)
    loc = _to_local(pos[T], dims[T], ax[T], pg[:, None, :])[:, 0]
    tgt_m = loc.clamp(0.0, 1.0)
    src = src.index_copy(0, m["r_idx"], src_m)
    tgt = tgt.index_copy(0, m["r_idx"], tgt_m)
    return src, tgt


# ----------------------------------------------------------------------------- public API


def execute_batch(programs: list[Program], dtype: torch.dtype = torch.float32, device=None,
                  params: list[torch.Tensor] | None = None) -> list[ExecutedShape]:
    """Execute several programs together (their blocks run in lock step).

    Args:
        programs: parsed programs.
        dtype: float32 (the reference precision) or float64.
        device: torch device (default: that of the first given ``params`` tensor, else CPU).
        params: optional list of (P_i,) tensors (or None), one per program (see
            :func:`program_parameters`); gradients flow to them.

    Returns:
        One :class:`ExecutedShape` per program; equal to calling :func:`execute` on each.
    """
    if not programs:
        return []
    if device is None and params is not None:
        device = next((t.device for t in params if t is not None), None)
    return ExecutionPlan(programs, dtype, device).run(params)


def execute(program: Program, dtype: torch.dtype = torch.float32, device=None,
            params: torch.Tensor | None = None) -> ExecutedShape:
    """Execute a ShapeAssembly program (the reference's hierarchical execution).

    Args:
        program: a parsed :class:`~shapeprog.lang.Program`.
        dtype: float32 (the reference precision, default) or float64.
        device: torch device (default: that of ``params``, else CPU).
        params: optional (P,) tensor replacing the program's continuous numbers (text order,
            see :func:`program_parameters`); the result is differentiable in it.

    Returns:
        The :class:`ExecutedShape` of the leaf cuboids.
    """
    return execute_batch([program], dtype, device, None if params is None else [params])[0]
