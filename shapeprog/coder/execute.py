"""The ShapeCoder executor: a program to its parts, and parts to primitives. NumPy only.

:func:`run` evaluates an expression of a :class:`~shapeprog.coder.lang.Library` (abstractions are
evaluated through their bodies, with the arguments bound to the parameters) into an :class:`Execution`:
the :class:`Part` s of the shape plus the *hard* errors (a dimension <= 0, a division by zero, a non-finite
value: the program is invalid) and *soft* errors (a reflection from the positive side, a translation
distance <= 0: allowed, but a dream with one is rejected). :func:`execute` runs and returns the
primitives, raising :class:`ExecutionError` on a hard error.

Semantics (3D; the 2D domain is the same with two coordinates, no rotation):

* ``Cuboid(w,h,d)``: a box centred at the origin, identity rotation.
* ``Move(S,x,y,z)``: adds (x, y, z) to every part's centre.
* ``Rotate(S,A,t)``: left-multiplies every part's rotation by the rotation of t radians about world
  axis A; the centres do not change (parts turn about their own centres).
* ``Union(A,B)``: the parts of A, then those of B.
* ``SymRef(S,A)``: every part, then a mirrored copy of each (A-coordinate negated, row A of the rotation
  negated, then :func:`reorient` ed to a proper frame).
* ``SymTrans(S,A,INT#K#,D)``: every part, then K copies of each moved by k/K * D along A, k = 1..K.
* ``Add Sub Mul Div Inv``: float arithmetic (``Inv`` negates; ``Div`` by 0 gives 0 and a hard error).

A primitive is a tuple of floats: ``(W, H, D, X, Y, Z, RX, RY, RZ)`` in 3D (dimensions, centre, and
the extrinsic x-y-z Euler angles of the rotation, i.e. ``R = Rz(RZ) @ Ry(RY) @ Rx(RX)``, in radians) or
``(W, H, X, Y)`` in 2D; :func:`primitives` re-orients, rounds (2 decimals) and orders them by the
position key. See docs/shapecoder.md ("Language").

Example:
    >>> from shapeprog.coder.lang import parse
    >>> execute(parse("SymRef(Move(Cuboid(0.1,0.5,0.1),-0.4,-0.25,0.3),AX)"))
    ((0.1, 0.5, 0.1, -0.4, -0.25, 0.3, 0.0, 0.0, 0.0), (0.1, 0.5, 0.1, 0.4, -0.25, 0.3, 0.0, 0.0, 0.0))
    >>> ex = run(parse("SymRef(Move(Cuboid(0.1,0.5,0.1),0.4,-0.25,0.3),AX)"))
    >>> ex.soft_errors
    ('SymRef(Move(Cuboid(0.1,0.5,0.1),0.4,-0.25,0.3),AX): a part with X >= 0 is reflected',)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from ..errors import ExecutionError as _BaseExecutionError
from . import limits
from .lang import as_expr, AXES, AxisConst, Call, Expr, IntConst, Lang, Library, Num, Type, Var, _library, _short, check

__all__ = [
    "ExecutionError",
    "Execution",
    "Part",
    "Prim",
    "corners",
    "euler_xyz",
    "execute",
    "order",
    "position_key",
    "primitives",
    "reorient",
    "rotation_xyz",
    "run",
]

Prim = tuple  # (W, H, D, X, Y, Z, RX, RY, RZ) floats in 3D, (W, H, X, Y) in 2D

#: Angles this close to +-3.14 are snapped to 0 (cascaded: x first, then y if x is ~0, then z).
_SNAP_PI, _SNAP_TOL = 3.14, 0.01


class ExecutionError(_BaseExecutionError):
    """A program that cannot be executed: an unbound or ill-typed variable, a limit exceeded, or (from
    :func:`execute`) a hard error.

    Attributes:
        reason: the message.
        expr: the text of the offending (sub-)expression, shortened, or None.
        index, file, line: where the caller knows them (None otherwise), as in
            :class:`shapeprog.errors.ExecutionError`.
    """

    def __init__(self, reason: str, expr: str | None = None, index: int | None = None, file: str | None = None,
                 line: int | None = None):
        self.reason, self.expr, self.index, self.file, self.line = reason, expr, index, file, line
        where = "" if expr is None else f"{expr}: "
        if file is not None:
            where = f"{file}:{line}: " + where if line is not None else f"{file}: " + where
        elif index is not None:
            where = f"program {index}: " + where
        ValueError.__init__(self, where + reason)


@dataclass(frozen=True, eq=False)
class Part:
    """One box of an executed shape.

    Attributes:
        dims: (k,) float64, the side lengths along the part's local axes (k = 3, or 2 in 2D).
        center: (k,) float64.
        rot: (k, k) float64; column j is local axis j in world coordinates.
    """

    dims: np.ndarray
    center: np.ndarray
    rot: np.ndarray


@dataclass(frozen=True)
class Execution:
    """The result of :func:`run`.

    Attributes:
        parts: the parts in execution order.
        hard_errors: one message per hard error (the program is invalid).
        soft_errors: one message per soft error.
        lang: the domain.
    """

    parts: tuple = field(repr=False)
    hard_errors: tuple = ()
    soft_errors: tuple = ()
    lang: Lang | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        """No hard error."""
        return not self.hard_errors

    def primitives(self, prec: int = 2, orient: bool = True) -> tuple:
        """:func:`primitives` of the parts."""
        return primitives(self.parts, prec=prec, orient=orient)


# ----------------------------------------------------------------------------- rotations


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def rotation_xyz(angles: Sequence[float]) -> np.ndarray:
    """The (3, 3) rotation ``Rz(c) @ Ry(b) @ Rx(a)`` of Euler angles (a, b, c): about world x, then y,
    then z (what ``Rotate(Rotate(Rotate(S,AX,a),AY,b),AZ,c)`` applies)."""
    a, b, c = (float(v) for v in angles)
    return _axis_rotation(2, c) @ _axis_rotation(1, b) @ _axis_rotation(0, a)


def euler_xyz(rot: np.ndarray) -> tuple:
    """The angles (a, b, c) with ``rotation_xyz((a, b, c)) == rot``, b in [-pi/2, pi/2], a and c in
    (-pi, pi]; at gimbal lock (|b| = pi/2) a is 0."""
    r = np.asarray(rot, dtype=np.float64)
    sb = -r[2, 0]
    b = math.asin(max(-1.0, min(1.0, sb)))
    if math.hypot(r[2, 1], r[2, 2]) < 1e-9:  # gimbal lock: only a - c (or a + c) is defined
        return 0.0, b, math.atan2(-r[0, 1], r[1, 1])
    return math.atan2(r[2, 1], r[2, 2]), b, math.atan2(r[1, 0], r[0, 0])


def reorient(dims: np.ndarray, rot: np.ndarray) -> tuple:
    """Re-assign a part's local axes to the world directions right, up, forward (x, y, z), in that
    order: each takes, among the local axes not yet taken and both their signs, the one closest to it
    (the largest dot product; the first on a tie). The dimensions follow their axes, so the box is the
    same set of points; the result is a proper rotation close to the identity.

    Args:
        dims: (k,) side lengths; rot: (k, k) rotation (or reflection), columns the local axes.

    Returns:
        ``(dims, rot)``, new arrays.
    """
    k = len(dims)
    r = rot.tolist()
    if r[0][0] > abs(r[0][1]) and r[1][1] > 0 and (k == 2 or (r[0][0] > abs(r[0][2]) and r[1][1] > abs(r[1][2])
                                                               and r[2][2] > 0)):
        return np.array(dims, dtype=np.float64), np.array(rot, dtype=np.float64)  # already right/up/forward
    free = list(range(k))
    new_dims = np.empty(k)
    new_rot = np.empty((k, k))
    for w in range(k):
        best, pick, sign = -np.inf, free[0], 1.0
        for j in free:
            for s in (1.0, -1.0):
                v = s * r[w][j]
                if v > best:
                    best, pick, sign = v, j, s
        free.remove(pick)
        new_dims[w] = dims[pick]
        new_rot[:, w] = sign * rot[:, pick]
    return new_dims, new_rot


# ----------------------------------------------------------------------------- primitives


def _clean(v: float, prec: int) -> float:
    return round(float(v), prec) + 0.0  # + 0.0 turns -0.0 into 0.0


def position_key(prim: Sequence[float]) -> float:
    """The ordering key of a primitive: its centre rounded to multiples of 0.05, then
    ``(x + y + z) * 1e4 + x * 1e3 + y * 1e2 + z * 10`` (z = 0 in 2D)."""
    if len(prim) == 9:
        x, y, z = prim[3], prim[4], prim[5]
    else:
        x, y, z = prim[2], prim[3], 0.0
    x, y, z = (round(v * 20) / 20.0 for v in (x, y, z))
    return (x + y + z) * 10000 + x * 1000 + y * 100 + z * 10


def order(prims: Iterable[Sequence[float]]) -> tuple:
    """The primitives sorted by :func:`position_key`, ties by the tuples themselves."""
    return tuple(sorted((tuple(p) for p in prims), key=lambda p: (position_key(p), p)))


def primitives(parts: Sequence[Part], prec: int = 2, orient: bool = True) -> tuple:
    """The primitives of executed parts: with ``orient``, each part's axes are :func:`reorient` ed first;
    3D rotations become :func:`euler_xyz` angles, angles within 0.01 of +-3.14 are snapped to 0 (x; y if
    x is ~0; z if x and y are ~0); everything is rounded to ``prec`` decimals (-0.0 becomes 0.0), and the
    list is :func:`order` ed.

    Returns:
        tuple of P tuples of 9 floats (3D) or 4 floats (2D).
    """
    out = []
    for p in parts:
        dims, rot = (reorient(p.dims, p.rot) if orient else (p.dims, p.rot))
        if len(dims) == 2:
            out.append(tuple(_clean(v, prec) for v in (dims[0], dims[1], p.center[0], p.center[1])))
            continue
        a, b, c = euler_xyz(rot)
        if abs(abs(a) - _SNAP_PI) < _SNAP_TOL:
            a = 0.0
        if abs(a) < _SNAP_TOL and abs(abs(b) - _SNAP_PI) < _SNAP_TOL:
            b = 0.0
        if abs(a) < _SNAP_TOL and abs(b) < _SNAP_TOL and abs(abs(c) - _SNAP_PI) < _SNAP_TOL:
            c = 0.0
        out.append(tuple(_clean(v, prec) for v in (*dims, *p.center, a, b, c)))
    return order(out)


def corners(prims) -> np.ndarray:
    """The 8 corners of each 3D primitive.

    Args:
        prims: (P, 9) primitives (any sequence of 9-tuples).

    Returns:
        (P, 8, 3) float64; corner ``4*i + 2*j + k`` has signs (i, j, k) (0 for -, 1 for +) along the
        local x, y, z axes.
    """
    p = np.asarray(prims, dtype=np.float64).reshape(-1, 9)
    signs = np.array([[i, j, k] for i in (-.5, .5) for j in (-.5, .5) for k in (-.5, .5)])  # (8, 3)
    a, b, c = p[:, 6], p[:, 7], p[:, 8]
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rot = np.stack([
        np.stack([cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa], -1),
        np.stack([sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa], -1),
        np.stack([-sb, cb * sa, cb * ca], -1),
    ], -2)  # (P, 3, 3) = Rz Ry Rx
    local = signs[None] * p[:, None, 0:3]  # (P, 8, 3)
    return p[:, None, 3:6] + np.einsum("pij,pkj->pki", rot, local)


# ----------------------------------------------------------------------------- evaluation


class _Run:
    def __init__(self, lib: Library):
        self.lib, self.lang = lib, lib.lang
        self.k = lib.lang.dim
        self.hard: list = []
        self.soft: list = []

    def value(self, e: Expr, env: Mapping, want: Type):
        t = type(e)
        if t is Num:
            return e.value
        if t is Call:
            return self.call(e, env)
        if t is Var:
            if e.name not in env:
                raise ExecutionError(f"variable {e.name!r} has no value")
            return self._checked(e.name, env[e.name], want)
        if t is AxisConst:
            return e.name
        if t is IntConst:
            return e.value
        raise ExecutionError(f"not an expression node: {type(e).__name__}")

    def _checked(self, name: str, v, want: Type):
        if want is Type.FLOAT:
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                    or not math.isfinite(float(v)):
                raise ExecutionError(f"variable {name!r} needs a finite float, got {v!r}")
            return float(v)
        if want is Type.AXIS:
            if v not in self.lang.axes:
                raise ExecutionError(f"variable {name!r} needs one of {', '.join(self.lang.axes)}, got {v!r}")
            return v
        if want is Type.INT:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= limits.MAX_COUNT:
                raise ExecutionError(f"variable {name!r} needs a count from 1 to {limits.MAX_COUNT}, got {v!r}")
            return int(v)
        raise ExecutionError(f"variable {name!r} cannot be a {want}")

    def call(self, e: Call, env: Mapping):
        sig = self.lib.signature(e.fn)
        if sig is None:
            raise ExecutionError(f"unknown function {e.fn!r}", _short(e))
        if len(e.args) != sig.arity:
            raise ExecutionError(f"{e.fn} takes {sig.arity} argument(s), got {len(e.args)}", _short(e))
        args = [self.value(a, env, t) for a, t in zip(e.args, sig.params)]
        if e.fn in self.lib:
            ab = self.lib[e.fn]
            return self.value(ab.body, {p.name: v for p, v in zip(ab.params, args)}, Type.SHAPE)
        out = getattr(self, "f_" + e.fn)(e, *args)
        if isinstance(out, float) and not math.isfinite(out):
            self.hard.append(f"{_short(e)}: the value is not finite")
            return 0.0
        if isinstance(out, list) and len(out) > limits.MAX_PARTS:
            raise ExecutionError(f"the shape has more than {limits.MAX_PARTS} parts (MAX_PARTS)", _short(e))
        return out

    # shapes
    def _box(self, e: Call, dims) -> list:
        if min(dims) <= 0:
            self.hard.append(f"{_short(e)}: a dimension is <= 0")
        return [Part(np.array(dims, dtype=np.float64), np.zeros(self.k), np.eye(self.k))]

    def f_Cuboid(self, e, w, h, d):
        return self._box(e, (w, h, d))

    def f_Rectangle(self, e, w, h):
        return self._box(e, (w, h))

    def f_Move(self, e, shape, *offset):
        off = np.array(offset, dtype=np.float64)
        return [Part(p.dims, p.center + off, p.rot) for p in shape]

    def f_Rotate(self, e, shape, axis, angle):
        m = _axis_rotation(AXES.index(axis), angle)
        return [Part(p.dims, p.center, m @ p.rot) for p in shape]

    def f_Union(self, e, a, b):
        return a + b

    def f_SymRef(self, e, shape, axis):
        i = AXES.index(axis)
        if any(p.center[i] >= 0 for p in shape):
            self.soft.append(f"{_short(e)}: a part with {axis[1]} >= 0 is reflected")
        copies = []
        for p in shape:
            center, rot = p.center.copy(), p.rot.copy()
            center[i] = -center[i]
            rot[i] = -rot[i]
            dims, rot = reorient(p.dims, rot)
            copies.append(Part(dims, center, rot))
        return shape + copies

    def f_SymTrans(self, e, shape, axis, count, dist):
        i = AXES.index(axis)
        if dist <= 0:
            self.soft.append(f"{_short(e)}: the distance is <= 0")
        if len(shape) * (count + 1) > limits.MAX_PARTS:
            raise ExecutionError(f"the shape has more than {limits.MAX_PARTS} parts (MAX_PARTS)", _short(e))
        copies = []
        for p in shape:
            for k in range(1, count + 1):
                center = p.center.copy()
                center[i] += k / count * dist
                copies.append(Part(p.dims, center, p.rot))
        return shape + copies

    # floats
    def f_Add(self, e, a, b):
        return a + b

    def f_Sub(self, e, a, b):
        return a - b

    def f_Mul(self, e, a, b):
        return a * b

    def f_Div(self, e, a, b):
        if b == 0:
            self.hard.append(f"{_short(e)}: division by 0")
            return 0.0
        return a / b

    def f_Inv(self, e, a):
        return -a


def run(expr: Expr, library: Library | Lang | None = None, env: Mapping | None = None) -> Execution:
    """Execute a Shape expression.

    Args:
        expr: a well-typed Shape expression of ``library`` (see :func:`~shapeprog.coder.lang.check`) or its text.
        library: its functions; :data:`~shapeprog.coder.lang.LANG_3D` by default.
        env: values of the program's variables: floats for Float variables, ``"AX"`` etc. for Axis
            variables, ints for Int variables.

    Raises:
        ProgramError: ``expr`` is not a well-typed Shape expression of ``library``.
        ExecutionError: an unbound or ill-typed variable, more than
            :data:`~shapeprog.coder.limits.MAX_PARTS` parts. Hard errors do not raise here: they are
            listed in :attr:`Execution.hard_errors`.
    """
    lib = _library(library)
    expr = as_expr(expr, lib, "shapeprog.coder.run")
    check(expr, lib, Type.SHAPE)
    r = _Run(lib)
    parts = r.value(expr, env or {}, Type.SHAPE)
    if not isinstance(parts, list):
        raise ExecutionError("the expression is not a Shape", _short(expr))
    return Execution(tuple(parts), tuple(r.hard), tuple(r.soft), lib.lang)


def execute(expr: Expr, library: Library | Lang | None = None, env: Mapping | None = None, *, prec: int = 2,
            orient: bool = True, strict: bool = True) -> tuple:
    """The primitives of a Shape expression (:func:`run`, then :func:`primitives`).

    Raises:
        ExecutionError: as :func:`run`, and on a hard error when ``strict``.
    """
    ex = run(as_expr(expr, library, "shapeprog.coder.execute"), library, env)
    if strict and ex.hard_errors:
        raise ExecutionError(ex.hard_errors[0])
    return ex.primitives(prec=prec, orient=orient)
