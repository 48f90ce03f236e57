"""One ShapeAssembly block executed statement by statement, in float64 Python numbers.

The validity-checked decoder (:mod:`shapeprog.vae.decode`) tries every candidate line on the block it
is writing and keeps it only if the geometry stays inside the bbox. Running the batched executor
(:func:`shapeprog.execute`) on the whole block for every candidate would cost milliseconds per line, so
:class:`LocalProgram` keeps the state of one block (every cuboid's centre, extents, axes and attachment
records) and executes one statement at a time on it: the attach rules of :mod:`shapeprog.attach`
(first, second, general, aligned), squeeze, reflect and translate, for a single cuboid at a time.
Copies are cheap (:meth:`LocalProgram.copy` copies one list; the cuboid states are immutable), so a
candidate line runs on a copy that is kept or dropped.

This is a second implementation of the local (per-block) execution of ``docs/shapeassembly.md``; the tests
(``tests/shapeprog/vae/test_local.py``) check it against :func:`shapeprog.execute` on corpus blocks and on
decoded programs, so that the two cannot drift apart. Cuboids are addressed by **slot**: 0 is bbox,
then Cuboid lines in order, then macro copies in creation order (the executor's ``cube<N>`` names).

Example:
    >>> p = LocalProgram((1.0, 1.0, 1.0))
    >>> leg = p.add_cuboid((0.1, 0.5, 0.1), aligned=True)
    >>> p.attach(leg, 0, (0.5, 0.0, 0.5), (0.1, 0.0, 0.1))
    [1]
    >>> [round(x, 6) for x in p.boxes[leg].pos]
    [-0.4, -0.25, -0.4]
    >>> p.reflect(leg, "X"), [round(x, 6) for x in p.boxes[2].pos]
    ([2], [0.4, -0.25, -0.4])
    >>> p.inside([1, 2]), p.inside([1, 2], margin=1.0)  # strictly inside: the legs touch the bbox's bottom
    (True, False)
"""
from __future__ import annotations

import functools
import math
from typing import Sequence

import numpy as np

from ..attach import COS_DIST_THRESH, DIM_ORDER, EPS, GRID, SMALL_EPS
from ..geometry import CORNER_SIGNS
from ..lang import AXES, FACES, Attach, Block, Cuboid, Reflect, Squeeze

__all__ = ["Box", "LocalProgram", "run_block"]

_IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
# face -> (axis index k, "val"): 0 for the positive faces, 1 for the negative ones (spec: squeeze);
# FACES pairs them per axis: right/left, top/bot, front/back
_FACE = {f: divmod(i, 2) for i, f in enumerate(FACES)}
_OPP = {f: FACES[i ^ 1] for i, f in enumerate(FACES)}
_SIGNS = [tuple(s) for s in CORNER_SIGNS.tolist()]

Vec = tuple  # (3,) float


# ----------------------------------------------------------------------------- small vector algebra


def _sub(a: Vec, b: Vec) -> Vec:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _add(a: Vec, b: Vec) -> Vec:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _mul(a: Vec, s: float) -> Vec:
    return (a[0] * s, a[1] * s, a[2] * s)


def _dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a: Vec, b: Vec) -> Vec:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _norm(a: Vec) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _div(a: float, b: float) -> float:
    """IEEE division (inf or nan for a zero divisor, as torch), never an exception."""
    if b != 0.0:
        return a / b
    if a == 0.0 or a != a:
        return math.nan
    return math.copysign(math.inf, a) * math.copysign(1.0, b)


def _matvec(R, v: Vec) -> Vec:
    return (_dot(R[0], v), _dot(R[1], v), _dot(R[2], v))


def _rodrigues(axis: Vec, angle: float):
    """Rotation matrix (rows) about unit ``axis`` by ``angle``."""
    x, y, w = axis
    s, c = math.sin(angle), 1.0 - math.cos(angle)
    K = ((0.0, -w, y), (w, 0.0, -x), (-y, x, 0.0))
    K2 = tuple(tuple(_dot(K[i], (K[0][j], K[1][j], K[2][j])) for j in range(3)) for i in range(3))
    return tuple(tuple((1.0 if i == j else 0.0) + s * K[i][j] + c * K2[i][j] for j in range(3)) for i in range(3))


def _rotate(ax, R):
    """Axis rows turned by R (each row v -> R v)."""
    return tuple(_matvec(R, v) for v in ax)


def _min_rotation(nb: Vec, nc: Vec):
    """The rotation taking direction nb to nc (spec: minimal rotation, with its degenerate case);
    None for the identity."""
    nbh = _mul(nb, 1.0 / _norm(nb))
    nch = _mul(nc, 1.0 / _norm(nc))
    cr = _cross(nbh, nch)
    crn = _norm(cr)
    dot = _dot(nbh, nch)
    if crn == 0.0:
        k = next((i for i in range(3) if nbh[i] != 0.0), None)
        if k is None:
            return None
        e = tuple(1.0 if i == k else 0.0 for i in range(3))
        v = _matvec(_rodrigues(e, math.pi / 2), nbh)
        return _rodrigues(_mul(v, 1.0 / _norm(v)), math.pi)
    if not abs(dot) <= 1.0 or math.acos(dot) == 0.0:
        return None
    return _rodrigues(_mul(cr, 1.0 / crn), math.acos(dot))


# ----------------------------------------------------------------------------- cuboid state


class Box:
    """The state of one cuboid (immutable: every change makes a new Box).

    Attributes:
        pos: (3,) float, the centre.
        dims: (3,) float, extents along the cuboid's right/up/front axes.
        ax: (3, 3) float, rows are the unit right, up and front vectors.
        aligned: the Cuboid line's flag.
        records: every attachment this cuboid took part in, as the moved cuboid or as the target, in
            order: ``(local point on this cuboid (3,), global point g (3,))``.
        moves: the attachments where it was the moved cuboid: ``(local source point (3,), target slot)``
            (what reflect and translate repeat).
    """

    __slots__ = ("pos", "dims", "ax", "aligned", "records", "moves")

    def __init__(self, pos: Vec, dims: Vec, ax=_IDENTITY, aligned: bool = True, records: tuple = (),
                 moves: tuple = ()):
        self.pos, self.dims, self.ax, self.aligned, self.records, self.moves = pos, dims, ax, aligned, records, moves

    def replace(self, **kw) -> "Box":
        new = Box(self.pos, self.dims, self.ax, self.aligned, self.records, self.moves)
        for k, v in kw.items():
            setattr(new, k, v)
        return new

    def point(self, c: Vec) -> Vec:
        """The global point of local coordinates ``c`` (0..1 across each extent)."""
        return _point(self.pos, self.dims, self.ax, c)

    def local(self, p: Vec) -> Vec:
        """Local coordinates of the global point ``p`` (the executor's transpose solve)."""
        r = _sub(p, self.pos)
        d = self.dims
        return tuple(_div(_dot(r, self.ax[k]), d[k]) + 0.5 for k in range(3))

    def corners(self) -> list[Vec]:
        """The 8 corners, in the spec's order."""
        h = [0.5 * x for x in self.dims]
        a = self.ax
        return [tuple(self.pos[j] + s[0] * h[0] * a[0][j] + s[1] * h[1] * a[1][j] + s[2] * h[2] * a[2][j]
                      for j in range(3)) for s in _SIGNS]

    def half_extent(self) -> Vec:
        """Half the extent of the axis-aligned bounding box, per world axis."""
        d, a = self.dims, self.ax
        return tuple(0.5 * (abs(a[0][j] * d[0]) + abs(a[1][j] * d[1]) + abs(a[2][j] * d[2])) for j in range(3))


def _point(pos: Vec, dims: Vec, ax, c: Vec) -> Vec:
    return _point_c(pos, dims, ax, (c[0] - 0.5, c[1] - 0.5, c[2] - 0.5))


def _point_c(pos: Vec, dims: Vec, ax, cc: Vec) -> Vec:
    x, y, z = cc[0] * dims[0], cc[1] * dims[1], cc[2] * dims[2]
    a0, a1, a2 = ax
    return (pos[0] + x * a0[0] + y * a1[0] + z * a2[0],
            pos[1] + x * a0[1] + y * a1[1] + z * a2[1],
            pos[2] + x * a0[2] + y * a1[2] + z * a2[2])


# ----------------------------------------------------------------------------- attach rules


def _rule_first(box: Box, src: Vec, g: Vec) -> Box:
    return box.replace(pos=_add(box.pos, _sub(g, box.point(src))))


def _rule_second(box: Box, src: Vec, g: Vec, p_ap: Vec, a: Vec) -> Box:
    """Non-aligned cuboid with one earlier record (p_ap, a): stretch one dim, turn about a."""
    pos, dims, ax = box.pos, box.dims, box.ax
    src_c = (src[0] - 0.5, src[1] - 0.5, src[2] - 0.5)
    ap_c = (p_ap[0] - 0.5, p_ap[1] - 0.5, p_ap[2] - 0.5)
    b = _point_c(pos, dims, ax, src_c)
    c = g
    if not _norm(_sub(b, c)) >= SMALL_EPS:
        return box
    ca = _sub(c, a)
    dist2 = _dot(ca, ca)
    w = _sub(b, a)
    ww = _dot(w, w)
    nv = [_mul(ax[k], src_c[k]) for k in range(3)]
    qv = [_mul(ax[k], ap_c[k]) for k in range(3)]
    best, s_best = None, math.inf
    for k in DIM_ORDER:
        if sum(map(abs, nv[k])) + sum(map(abs, qv[k])) < SMALL_EPS:
            continue
        m = _sub(nv[k], qv[k])
        A, B, C = _dot(m, m), 2.0 * _dot(w, m), ww - dist2
        disc = B * B - 4.0 * A * C
        if disc > 0.0:
            s = (-B + math.sqrt(disc)) / (2.0 * A + 1e-8)
            if best is None or abs(s) < abs(s_best):
                best, s_best = k, s
    if best is not None:
        dims1 = tuple(dims[k] + s_best if k == best else dims[k] for k in range(3))
    else:  # fallback: all three change vectors at once
        mf = _sub(_add(_add(nv[0], nv[1]), nv[2]), _add(_add(qv[0], qv[1]), qv[2]))
        Af, Bf, Cf = _dot(mf, mf), 2.0 * _dot(w, mf), ww - dist2
        discf = Bf * Bf - 4.0 * Af * Cf
        if discf > 0.0:
            sf = (-Bf + math.sqrt(discf)) / (2.0 * Af + 1e-8)
            dims1 = (dims[0] + sf, dims[1] + sf, dims[2] + sf)
        else:
            dims1 = dims
    pos1 = _add(pos, _sub(a, _point_c(pos, dims1, ax, ap_c)))
    nb = _sub(_point_c(pos1, dims1, ax, src_c), a)
    nc = _sub(c, a)
    ax2 = ax
    if _norm(nb) > 0.0 and _norm(nc) > 0.0 and _norm(_sub(nb, nc)) >= SMALL_EPS:
        R = _min_rotation(nb, nc)
        if R is not None:
            ax2 = _rotate(ax, R)
    pos2 = _add(pos1, _sub(a, _point_c(pos1, dims1, ax2, ap_c)))
    return box.replace(pos=pos2, dims=dims1, ax=ax2)


@functools.lru_cache(maxsize=1)
def _grid() -> np.ndarray:
    """(1000, 3) local grid coordinates i/9, x fastest, then y, then z."""
    t = np.arange(GRID, dtype=np.float64) / (GRID - 1)
    z, y, x = np.meshgrid(t, t, t, indexing="ij")
    return np.stack([x, y, z], -1).reshape(-1, 3)


def _first_min(e: Sequence[float]) -> int:
    """The lowest index whose value is within 1e-9 of the minimum (the executor's tie rule)."""
    lim = min(e) + 1e-9
    return next(i for i, v in enumerate(e) if v <= lim)


def _nearest_grid_points(A: Box, B: Box) -> tuple[Vec, Vec]:
    """Local grid coordinates of the closest pair between the 10x10x10 grids of A and B."""
    if A.ax == _IDENTITY and B.ax == _IDENTITY:  # separable: one 1-D problem per axis
        r, cl = [], []
        for j in range(3):
            p, d, pB, dB = A.pos[j], A.dims[j], B.pos[j], B.dims[j]
            best_e, best = [], []
            for i in range(GRID):
                t = i / (GRID - 1)
                u = _div(p + (t - 0.5) * d - pB, dB) + 0.5
                near = min(max(round(u * (GRID - 1)), 0), GRID - 1) / (GRID - 1) if math.isfinite(u) else u
                best_e.append(((u - near) * dB) ** 2 if math.isfinite(u) else math.inf)
                best.append(near)
            i = _first_min(best_e)
            r.append(i / (GRID - 1))
            cl.append(best[i])
        return tuple(r), tuple(cl)
    G = _grid()
    a, aB = np.array(A.ax), np.array(B.ax)
    pts = np.array(A.pos) + ((G - 0.5) * np.array(A.dims)) @ a
    with np.errstate(all="ignore"):
        u = ((pts - np.array(B.pos)) @ aB.T) / np.array(B.dims) + 0.5
        near = np.clip(np.round(u * (GRID - 1)), 0, GRID - 1) / (GRID - 1)
        d2 = (((u - near) * np.array(B.dims)) ** 2).sum(-1)
    d2 = np.where(np.isnan(d2), np.inf, d2)
    k = int(np.argmax(d2 <= d2.min() + 1e-9))
    return tuple(G[k].tolist()), tuple(near[k].tolist())


def _touch(X: Box, Y: Box) -> bool:
    """Whether a corner of X has local coordinates in Y inside [0, 1]^3 (bounds included)."""
    if X.ax == _IDENTITY and Y.ax == _IDENTITY:
        # the corner coordinates separate per axis: some corner is inside iff on every axis one of
        # X's two faces is (the same arithmetic as the corner-by-corner test)
        for j in range(3):
            h, p, dY, pY = 0.5 * X.dims[j], X.pos[j], Y.dims[j], Y.pos[j]
            if not any(0.0 <= _div(p + s * h - pY, dY) + 0.5 <= 1.0 for s in (1.0, -1.0)):
                return False
        return True
    for corner in X.corners():
        u = Y.local(corner)
        if 0.0 <= u[0] <= 1.0 and 0.0 <= u[1] <= 1.0 and 0.0 <= u[2] <= 1.0:
            return True
    return False


def _rule_aligned(box: Box, B: Box) -> Box:
    """Aligned cuboid with earlier records: grow towards B (the target point is ignored)."""
    if _touch(box, B) or _touch(B, box):
        return box
    r, cl = _nearest_grid_points(box, B)
    b, c = box.point(r), B.point(cl)
    big = max(box.dims + B.dims)
    if not _norm(_sub(b, c)) >= 0.05 * big:
        return box
    rr_c = (0.5 - r[0], 0.5 - r[1], 0.5 - r[2])
    o = _point_c(box.pos, box.dims, box.ax, rr_c)
    d1 = list(box.dims)
    for k in range(3):
        cv = (r[k] - 0.5) * box.ax[k][k]
        if cv != 0.0:
            D = (c[k] - b[k]) / (2.0 * cv)
            if D > 0.0:
                d1[k] += D
    d1 = tuple(d1)
    pos = _add(box.pos, _sub(o, _point_c(box.pos, d1, box.ax, rr_c)))
    return box.replace(pos=pos, dims=d1)


def _cv(ap: Vec, ax, k: int) -> Vec:
    return _mul(ax[k], ap[k] - 0.5)


def _rule_general(box: Box, src: Vec, g: Vec, prev: Sequence[tuple[Vec, Vec]]) -> Box:
    """Non-aligned cuboid with two or more earlier records ``prev`` of (ap, g)."""
    pos, dims, ax = box.pos, box.dims, box.ax
    if len(prev) == 2:
        colinear = True
    else:
        o = prev[0][1]
        line = _sub(prev[1][1], o)
        colinear = all(_norm(_cross(_sub(pg, o), line)) <= EPS for _, pg in prev)
    if colinear:
        a0, a1 = prev[0][1], prev[1][1]
        axis = _mul(_sub(a0, a1), 1.0 / (_norm(_sub(a0, a1)) + 1e-8))
        b = _point(pos, dims, ax, src)
        c = g
        c_p = _sub(c, _mul(axis, _dot(_sub(c, b), axis)))
        a_p = _sub(a0, _mul(axis, _dot(_sub(a0, b), axis)))
        fn = _sub(b, a_p)
        noc = _sub(c_p, a_p)
        s = _div(_norm(noc), _norm(fn)) - 1.0
        if s == s:
            nob = _mul(fn, 1.0 + s)
            n_nob, n_noc = _norm(nob), _norm(noc)
            if n_nob != 0.0 and n_noc != 0.0 and _norm(_sub(nob, noc)) >= EPS:
                nobh, noch = _mul(nob, 1.0 / n_nob), _mul(noc, 1.0 / n_noc)
                angle = math.acos(min(max(_dot(nobh, noch), -1.0), 1.0))
                R = _rodrigues(axis, angle)
                if _norm(_sub(_matvec(R, nobh), noch)) > EPS:
                    R = _rodrigues(_mul(axis, -1.0), angle)
                ax = _rotate(ax, R)
                pos = _add(pos, _sub(a0, _point(pos, dims, ax, prev[0][0])))
    b = _point(pos, dims, ax, src)
    t = _sub(g, b)
    nt = _norm(t)
    if nt >= EPS:
        pick = None
        for k in DIM_ORDER:
            c0 = _cv(prev[0][0], ax, k)
            if all(_norm(_sub(_cv(pa, ax, k), c0)) < EPS for pa, _ in prev):
                cvk = _cv(src, ax, k)
                nrm = _norm(cvk)
                if nrm > 0.0 and _dot(_mul(cvk, 1.0 / nrm), _mul(t, 1.0 / nt)) > COS_DIST_THRESH:
                    pick = k  # the reference keeps the *last* qualifying dim (trap 4)
        if pick is not None:
            cvk = _cv(src, ax, pick)
            d = 1.0 / (_norm(_sub(cvk, _cv(prev[0][0], ax, pick))) + 1e-8)
            s = abs(_dot(t, _mul(cvk, 1.0 / _norm(cvk))))
            dims = tuple(dims[k] + s * d if k == pick else dims[k] for k in range(3))
            pos = _add(pos, _sub(prev[0][1], _point(pos, dims, ax, prev[0][0])))
    return box.replace(pos=pos, dims=dims, ax=ax)


# ----------------------------------------------------------------------------- the block


class LocalProgram:
    """The local program of one block, executed one statement at a time.

    Args:
        bbox_dims: (3,) float, the block's bbox extents (its first Cuboid line).

    Attributes:
        boxes: one :class:`Box` per slot: bbox, then Cuboid lines, then macro copies.
    """

    __slots__ = ("boxes",)

    def __init__(self, bbox_dims: Vec | None = None, boxes: list[Box] | None = None):
        if boxes is None:
            dims = (1.0, 1.0, 1.0) if bbox_dims is None else tuple(float(x) for x in bbox_dims)
            boxes = [Box((0.0, 0.0, 0.0), dims)]
        self.boxes = boxes

    def __len__(self) -> int:
        return len(self.boxes)

    def copy(self) -> "LocalProgram":
        """An independent copy (one list copied; the cuboid states are shared, being immutable)."""
        return LocalProgram(boxes=list(self.boxes))

    def add_cuboid(self, dims: Vec, aligned: bool) -> int:
        """A new cuboid at the origin with identity axes; returns its slot."""
        self.boxes.append(Box((0.0, 0.0, 0.0), tuple(float(x) for x in dims), _IDENTITY, bool(aligned)))
        return len(self.boxes) - 1

    def attach(self, a: int, b: int, src: Vec, tgt: Vec) -> list[int]:
        """``attach(a, b, *src, *tgt)``: move slot ``a`` so that its local point ``src`` meets the local
        point ``tgt`` of slot ``b``. Returns the slots whose geometry may have changed (``[a]``)."""
        if a == 0:
            raise ValueError("bbox cannot be moved")
        boxes = self.boxes
        B = boxes[b]
        g = B.point(tgt)
        boxes[b] = B = B.replace(records=B.records + ((tuple(tgt), g),))
        A = boxes[a]
        n = len(A.records)
        if n == 0:
            A = _rule_first(A, src, g)
        elif A.aligned:
            A = _rule_aligned(A, B)
        elif n == 1:
            A = _rule_second(A, src, g, *A.records[0])
        else:
            A = _rule_general(A, src, g, A.records)
        src = tuple(src)
        boxes[a] = A.replace(records=A.records + ((src, g),), moves=A.moves + ((src, b),))
        return [a]

    def squeeze(self, a: int, b: int, c: int, face: str, u: float, v: float) -> list[int]:
        """``squeeze(a, b, c, face, u, v)``: two attaches (spec: squeeze). Returns ``[a]``."""
        for f, t in ((face, b), (_OPP[face], c)):
            k, val = _FACE[f]
            free = iter((u, v))
            src = tuple(1.0 - val if d == k else 0.5 for d in range(3))
            tgt = tuple((float(1 - val) if t == 0 else float(val)) if d == k else next(free) for d in range(3))
            self.attach(a, t, src, tgt)
        return [a]

    def _copy_of(self, a: int) -> int:
        A = self.boxes[a]
        self.boxes.append(Box((0.0, 0.0, 0.0), A.dims, _IDENTITY, A.aligned))
        return len(self.boxes) - 1

    def reflect(self, a: int, axis: str) -> list[int]:
        """``reflect(a, axis)``: a mirrored copy through the bbox's centre plane. Returns ``[new slot]``."""
        if a == 0:
            raise ValueError("bbox cannot be reflected")
        k = AXES.index(axis)
        A = self.boxes[a]
        new = self._copy_of(a)
        for ap, T in A.moves:
            p = A.point(ap)
            p = tuple(-p[j] if j == k else p[j] for j in range(3))
            tgt = tuple(min(max(x, 0.0), 1.0) for x in self.boxes[T].local(p))
            self.attach(new, T, tuple(1.0 - ap[j] if j == k else ap[j] for j in range(3)), tgt)
        return [new]

    def translate(self, a: int, axis: str, n: int, d: float) -> list[int]:
        """``translate(a, axis, n, d)``: ``n`` copies, the last ``d`` bbox extents along ``axis`` away.
        Returns the new slots."""
        if a == 0:
            raise ValueError("bbox cannot be translated")
        k = AXES.index(axis)
        A = self.boxes[a]
        step = self.boxes[0].dims[k] * d / n
        new_slots = []
        for i in range(1, n + 1):
            new = self._copy_of(a)
            new_slots.append(new)
            for ap, T in A.moves:
                p = A.point(ap)
                p = tuple(p[j] + i * step if j == k else p[j] for j in range(3))
                tgt = tuple(min(max(x, 0.0), 1.0) for x in self.boxes[T].local(p))
                self.attach(new, T, ap, tgt)
        return new_slots

    def inside(self, slots: Sequence[int], margin: float = 1.5) -> bool:
        """Whether every cuboid of ``slots`` has its axis-aligned bounding box strictly inside ``margin``
        times the bbox's (which is centred at the origin); False for a non-finite value."""
        lim = [0.5 * margin * abs(x) for x in self.boxes[0].dims]
        for s in slots:
            box = self.boxes[s]
            h = box.half_extent()
            p = box.pos
            for j in range(3):
                if not (p[j] + h[j] < lim[j] and p[j] - h[j] > -lim[j]):
                    return False
        return True


def run_block(block: Block) -> LocalProgram:
    """Execute the statements of one block (names resolved as the executor does: a Cuboid line with a
    known name only re-dimensions it; macro copies are ``cube<number of cuboids - 1>``)."""
    prog = LocalProgram()
    slots: dict[str, int] = {"bbox": 0}
    for s in block.statements:
        if isinstance(s, Cuboid):
            if s.name in slots:
                k = slots[s.name]
                prog.boxes[k] = prog.boxes[k].replace(dims=(float(s.l), float(s.h), float(s.w)))
            else:
                slots[s.name] = prog.add_cuboid((s.l, s.h, s.w), s.aligned)
        elif isinstance(s, Attach):
            prog.attach(slots[s.a], slots[s.b], (s.x1, s.y1, s.z1), (s.x2, s.y2, s.z2))
        elif isinstance(s, Squeeze):
            prog.squeeze(slots[s.a], slots[s.b], slots[s.c], s.face, s.u, s.v)
        else:
            before = len(prog)
            if isinstance(s, Reflect):
                prog.reflect(slots[s.a], s.axis)
            else:
                prog.translate(slots[s.a], s.axis, int(s.n), s.d)
            for k in range(before, len(prog)):
                name = f"cube{k - 1}"
                if name in slots:  # a name collision re-uses the old slot (never in the corpus)
                    raise ValueError(f"macro copy {name!r} collides with a declared cuboid")
                slots[name] = k
    return prog
