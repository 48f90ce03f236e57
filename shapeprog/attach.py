"""The attach rules of ShapeAssembly as batched tensor functions (spec: attach).

Each rule moves ``n`` cuboids at once: positions ``pos (n, 3)``, extents ``dims (n, 3)`` and
axes ``ax (n, 3, 3)`` (rows right/up/front), given local source points ``src (n, 3)`` on the
moved cuboid and global target points ``g (n, 3)``:

* :func:`rule_first`: the first record translates the source point onto the target;
* :func:`rule_second`: a second record stretches one dimension and turns about the first point;
* :func:`rule_general`: two or more earlier records (one cuboid at a time);
* :func:`rule_aligned`: an aligned cuboid grows towards its target cuboid (nearest grid points).

Value-dependent decisions are masks computed without gradients; see ``docs/shapeassembly.md``.

Example:
    >>> import torch
    >>> pos, dims, ax = torch.zeros(1, 3), torch.ones(1, 3), torch.eye(3)[None]
    >>> rule_first(pos, dims, ax, torch.full((1, 3), 0.5), torch.tensor([[0.0, 1.0, 0.0]]))[0].tolist()
    [[0.0, 1.0, 0.0]]
"""
from __future__ import annotations

import math

import torch

from .geometry import corners_unchecked

__all__ = ["rule_first", "rule_second", "rule_aligned", "rule_general", "point", "to_local"]

EPS = 0.01
SMALL_EPS = 1e-4
COS_DIST_THRESH = 0.9
GRID = 10
DIM_ORDER = (1, 2, 0)  # height, width, length


# ----------------------------------------------------------------------------- tensor helpers


def point(pos, dims, ax, coords):
    """Global point of local ``coords`` (n, 3) on cuboids (n, 3), (n, 3), (n, 3, 3)."""
    return _point_c(pos, dims, ax, coords - 0.5)


def _point_c(pos, dims, ax, centred):
    """:func:`point` of ``centred = coords - 0.5`` (computed once where a point is used often)."""
    return pos + torch.bmm((centred * dims).unsqueeze(1), ax).squeeze(1)


def to_local(pos, dims, ax, pts):
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
            nonzero = (v != 0).nonzero()
            if nonzero.numel() == 0:  # nb overflowed to a zero unit vector: no turn
                continue
            k = int(nonzero[0])
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


def rule_first(pos, dims, ax, src, g):
    """First record: translate each cuboid so that its local point ``src`` lands on ``g``.

    Args:
        pos: (n, 3) float, cuboid centres.
        dims: (n, 3) float, extents along the cuboids' axes.
        ax: (n, 3, 3) float, rows are the unit right/up/front vectors.
        src: (n, 3) float local source points on the moved cuboids.
        g: (n, 3) float global target points.

    Returns:
        (pos, dims, ax) after the move; ``dims`` and ``ax`` are the given tensors.
    """
    return pos + (g - point(pos, dims, ax, src)), dims, ax


def rule_second(pos, dims, ax, src, g, p_ap, a):
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
    order = list(DIM_ORDER)
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
        u = to_local(pB[si], dB[si], aB[si], ptsA)
        near = (u * (GRID - 1)).round().clamp(0, GRID - 1) / (GRID - 1)
        d2 = (((u - near) * dB[si, None, :]) ** 2).sum(-1)
        k = first_min(d2)
        r[si] = G[k]
        cl[si] = near[torch.arange(si.numel()), k]
    return r.to(out_dtype), cl.to(out_dtype)


def rule_aligned(pos, dims, ax, posB, dimsB, axB):
    """Aligned cuboid with earlier records: grow towards B (the target point is ignored)."""
    with torch.no_grad():
        # corners of A in B's frame and of B in A's frame, both directions in one pass
        n = pos.shape[0]
        both = torch.cat([pos, posB]), torch.cat([dims, dimsB]), torch.cat([ax, axB])
        other = torch.cat([posB, pos]), torch.cat([dimsB, dims]), torch.cat([axB, ax])
        u = to_local(*other, corners_unchecked(*both))
        inside = ((u >= 0) & (u <= 1)).all(-1).any(-1)
        idx = (~(inside[:n] | inside[n:])).nonzero().flatten()
    if idx.numel() == 0:
        return pos, dims, ax
    p, d, a = pos[idx], dims[idx], ax[idx]
    pB, dB, aB = posB[idx], dimsB[idx], axB[idx]
    G = _grid(pos.dtype, pos.device)
    with torch.no_grad():
        r, cl = _nearest_grid_points(p, d, a, pB, dB, aB, G)
    b = point(p, d, a, r)
    c = point(pB, dB, aB, cl)
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


def rule_general(pos, dims, ax, src, g, prev):
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
        for k in DIM_ORDER:
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

