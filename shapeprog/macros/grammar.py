"""ShapeMOD's modified ShapeAssembly grammar: lines whose subject is the last declared cuboid.

A sub-program in this grammar (the paper's Appendix A) is a bbox line followed by *PBlocks*: a
:class:`CuboidLine`; then 1-2 :class:`AttachLine` or one :class:`SqueezeLine`; then optionally one
:class:`ReflectLine` or :class:`TranslateLine`. Every non-Cuboid line acts on the last declared cuboid,
so it names only its targets. Standard library only.

**Cuboid ids.** A target is an ``int``: :data:`BBOX` (``-1``) for the bbox, ``k >= 0`` for the k-th
non-bbox Cuboid line of the sequence (``cube<k>`` of the reference's ``ret_list``). Because the ids
count Cuboid lines in sequence order, cube ids *are* the canonical numbering "by first appearance".

**Signatures.** :func:`signature` gives the canonical order signature of a line sequence: one entry per
non-Cuboid line, ``('att', c, t)``, ``('squeeze', c, t1, t2)``, ``('ref', c)`` or ``('trans', c)``,
where ``c`` is the subject's id and a bbox target is :data:`BBOX_TOP` (``-1``) or :data:`BBOX_BOT`
(``-2``) by the half of the bbox the target point lies in (:func:`bbox_side`). Two sequences with equal
signatures differ only in continuous and categorical values (a *structural match*).

**Units.** Every number is the ShapeAssembly value (translate's ``n`` is the copy count).
:func:`attributes` gives the reference's line-attribute tuples (``n / TRANS_NORM``, bbox ``y``
flipped on request, rounded to :data:`PREC`).

Example:
    >>> lines = (CuboidLine(1.0, 1.0, 1.0, True), CuboidLine(0.1, 1.0, 0.1, False),
    ...          SqueezeLine(BBOX, BBOX, "top", 0.1, 0.1), ReflectLine("X"))
    >>> signature(lines)
    (('squeeze', 0, -1, -2), ('ref', 0))
    >>> from shapeprog.lang import to_text
    >>> print(to_text(to_shapeassembly(lines)), end="")
    bbox = Cuboid(1.0, 1.0, 1.0, True)
    cube0 = Cuboid(0.1, 1.0, 0.1, False)
    squeeze(cube0, bbox, bbox, top, 0.1, 0.1)
    reflect(cube0, X)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence, Union

from .. import limits
from ..lang import AXES, FACES, Attach, Block, Cuboid, Program, Reflect, Squeeze, Statement, Translate

__all__ = [
    "BBOX",
    "BBOX_BOT",
    "BBOX_TOP",
    "COMMANDS",
    "PREC",
    "TRANS_NORM",
    "AttachLine",
    "CuboidLine",
    "Line",
    "LineError",
    "ReflectLine",
    "Signature",
    "SqueezeLine",
    "TranslateLine",
    "attributes",
    "bbox_side",
    "check_lines",
    "command",
    "cuboid_names",
    "float_params",
    "signature",
    "squeeze_sides",
    "to_shapeassembly",
]

#: Cuboid id of the bbox in line targets.
BBOX = -1
#: Signature id of a bbox target in the top half of the bbox (the reference's -1).
BBOX_TOP = -1
#: Signature id of a bbox target in the bottom half of the bbox (the reference's -2).
BBOX_BOT = -2
#: The reference divides translate's copy count by this in its line attributes.
TRANS_NORM = 10
#: Decimals of the reference's line-attribute floats.
PREC = 4
#: The base commands, in the order of the paper's grammar.
COMMANDS = ("Cuboid", "attach", "squeeze", "reflect", "translate")


@dataclass(frozen=True, slots=True)
class CuboidLine:
    """``Cuboid(l, h, w, aligned)``: declares the next cuboid (the first line of a sequence is the bbox)."""

    l: float
    h: float
    w: float
    aligned: bool


@dataclass(frozen=True, slots=True)
class AttachLine:
    """``attach(target, x1, y1, z1, x2, y2, z2)``: point (x1, y1, z1) of the last cuboid goes to point
    (x2, y2, z2) of ``target``."""

    target: int
    x1: float
    y1: float
    z1: float
    x2: float
    y2: float
    z2: float


@dataclass(frozen=True, slots=True)
class SqueezeLine:
    """``squeeze(t1, t2, face, u, v)``: the last cuboid between ``t1`` (on side ``face``) and ``t2``."""

    t1: int
    t2: int
    face: str
    u: float
    v: float


@dataclass(frozen=True, slots=True)
class ReflectLine:
    """``reflect(axis)``: a mirrored copy of the last cuboid."""

    axis: str


@dataclass(frozen=True, slots=True)
class TranslateLine:
    """``translate(axis, n, d)``: ``n`` copies of the last cuboid, the last ``d`` (fraction of the bbox
    extent) away."""

    axis: str
    n: int
    d: float


Line = Union[CuboidLine, AttachLine, SqueezeLine, ReflectLine, TranslateLine]
#: A canonical order signature: a tuple of ``('att', c, t)``, ``('squeeze', c, t1, t2)``, ``('ref', c)``,
#: ``('trans', c)`` entries (see the module docstring).
Signature = tuple

class LineError(ValueError):
    """A line sequence that cannot be executed; ``index`` is the 0-based index of the offending line."""

    def __init__(self, reason: str, index: int):
        self.reason, self.index = reason, index
        super().__init__(f"line {index}: {reason}")


_COMMAND = {CuboidLine: "Cuboid", AttachLine: "attach", SqueezeLine: "squeeze", ReflectLine: "reflect",
            TranslateLine: "translate"}
_FACE_AXIS = {"right": 0, "left": 0, "top": 1, "bot": 1, "front": 2, "back": 2}


def command(line: Line) -> str:
    """The base command of ``line`` (``'Cuboid'``, ``'attach'``, ``'squeeze'``, ``'reflect'``, ``'translate'``)."""
    return _COMMAND[type(line)]


def bbox_side(y: float) -> int:
    """:data:`BBOX_TOP` if a bbox point at local height ``y`` is in the top half (``y >= 0.5``), else
    :data:`BBOX_BOT`."""
    return BBOX_TOP if y >= 0.5 else BBOX_BOT


def squeeze_sides(s: SqueezeLine) -> tuple[int, int]:
    """The bbox sides (:data:`BBOX_TOP` / :data:`BBOX_BOT`) that the squeeze's two attachments would
    land on if ``t1`` / ``t2`` were the bbox: the face itself and its opposite for top/bot, else the
    half holding the free y coordinate (``u`` for left/right, ``v`` for front/back)."""
    k = _FACE_AXIS[s.face]
    if k == 1:  # top/bot: t1 gets the bbox's face `face`, t2 the opposite one
        return (BBOX_TOP, BBOX_BOT) if s.face == "top" else (BBOX_BOT, BBOX_TOP)
    y = s.u if k == 0 else s.v  # (y, z) for left/right, (x, y) for front/back
    return bbox_side(y), bbox_side(y)


def signature(lines: Sequence[Line]) -> Signature:
    """The canonical order signature of a line sequence (bbox line first).

    Cube ids in ``lines`` are already canonical (they count Cuboid lines), so the signature only
    replaces bbox targets by their side and names each line's subject.
    """
    out = []
    c = BBOX
    for ln in lines[1:]:
        t = type(ln)
        if t is CuboidLine:
            c += 1
        elif t is AttachLine:
            out.append(("att", c, bbox_side(ln.y2) if ln.target == BBOX else ln.target))
        elif t is SqueezeLine:
            s1, s2 = squeeze_sides(ln)
            out.append(("squeeze", c, s1 if ln.t1 == BBOX else ln.t1, s2 if ln.t2 == BBOX else ln.t2))
        elif t is ReflectLine:
            out.append(("ref", c))
        else:
            out.append(("trans", c))
    return tuple(out)


def _r(x: float) -> float:
    return round(float(x), PREC)


def attributes(lines: Sequence[Line], flip_bbox_y: bool = False) -> list[tuple]:
    """The reference's line-attribute tuples (``param_list``) of a line sequence.

    ``('Cuboid', l, h, w, aligned)``, ``('attach', target, x1, y1, z1, x2, y2, z2)``,
    ``('squeeze', t1, t2, face, u, v)``, ``('reflect', axis)``, ``('translate', axis, n / TRANS_NORM, d)``;
    targets are ``'bbox'`` or ``'cube<k>'`` and floats are rounded to :data:`PREC` decimals. With
    ``flip_bbox_y`` an attach to the bbox stores ``1 - y2``, as the reference does.
    """
    name = lambda t: "bbox" if t == BBOX else f"cube{t}"  # noqa: E731
    out: list[tuple] = []
    for ln in lines:
        t = type(ln)
        if t is CuboidLine:
            out.append(("Cuboid", _r(ln.l), _r(ln.h), _r(ln.w), ln.aligned))
        elif t is AttachLine:
            y2 = 1.0 - ln.y2 if flip_bbox_y and ln.target == BBOX else ln.y2
            out.append(("attach", name(ln.target), _r(ln.x1), _r(ln.y1), _r(ln.z1), _r(ln.x2), _r(y2), _r(ln.z2)))
        elif t is SqueezeLine:
            out.append(("squeeze", name(ln.t1), name(ln.t2), ln.face, _r(ln.u), _r(ln.v)))
        elif t is ReflectLine:
            out.append(("reflect", ln.axis))
        else:
            out.append(("translate", ln.axis, _r(ln.n / TRANS_NORM), _r(ln.d)))
    return out


def float_params(lines: Sequence[Line]) -> list[float]:
    """All floats of the line attributes flattened in line order (cuboid dims, the 6 attach
    coordinates, squeeze u, v, translate n / TRANS_NORM and d; the reference's ``float_params``)."""
    return [v for a in attributes(lines) for v in a[1:] if isinstance(v, float)]


def check_lines(lines: Sequence[Line]) -> None:
    """Raise :class:`LineError` at the first line where ``lines`` is not an executable sequence.

    Checked: a bbox :class:`CuboidLine` first; every other line a line type with a subject (a non-bbox
    cuboid declared before it); targets declared before it and not the subject; faces and axes known;
    translate counts from 1 to :data:`shapeprog.limits.MAX_TRANSLATE_COPIES`; finite numbers.
    """
    if not lines or type(lines[0]) is not CuboidLine:
        raise LineError("a sequence must start with the bbox Cuboid line", 0)
    n = 0  # non-bbox cuboids declared
    for i, ln in enumerate(lines):
        t = type(ln)
        if t not in _COMMAND:
            raise LineError(f"not a line of the grammar: {type(ln).__name__}", i)
        nums = [getattr(ln, f) for f in ln.__slots__ if f not in ("target", "t1", "t2", "face", "axis", "aligned")]
        if not all(isinstance(x, (int, float)) and math.isfinite(x) for x in nums):
            raise LineError(f"{command(ln)} has a non-finite number", i)
        if t is CuboidLine:
            if i > 0:
                n += 1
            continue
        if n == 0:
            raise LineError(f"{command(ln)} has no subject (no cuboid declared after the bbox)", i)
        targets = (ln.target,) if t is AttachLine else (ln.t1, ln.t2) if t is SqueezeLine else ()
        for tg in targets:
            if not isinstance(tg, int) or tg < BBOX or tg >= n:
                raise LineError(f"{command(ln)} targets cuboid {tg!r}, which is not declared before it", i)
            if tg == n - 1:
                raise LineError(f"{command(ln)} targets its own subject cube{tg}", i)
        if t is SqueezeLine and ln.face not in FACES:
            raise LineError(f"unknown face {ln.face!r}", i)
        if t in (ReflectLine, TranslateLine) and ln.axis not in AXES:
            raise LineError(f"unknown axis {ln.axis!r}", i)
        if t is TranslateLine and not (isinstance(ln.n, int) and 1 <= ln.n <= limits.MAX_TRANSLATE_COPIES):
            raise LineError(f"translate count {ln.n!r} is not an integer from 1 to {limits.MAX_TRANSLATE_COPIES}", i)


def cuboid_names(lines: Sequence[Line]) -> list[str]:
    """The ShapeAssembly name of each non-bbox Cuboid line in :func:`to_shapeassembly`: ``cube<N>`` with
    N the number of cuboids before it (bbox and reflect/translate copies included), the executor's
    naming of macro copies, so that a declared name never collides with a copy's."""
    names, count = [], 1
    for ln in lines[1:]:
        t = type(ln)
        if t is CuboidLine:
            names.append(f"cube{count - 1}")
            count += 1
        elif t is ReflectLine:
            count += 1
        elif t is TranslateLine:
            count += ln.n
    return names


def to_shapeassembly(lines: Sequence[Line], check: bool = True) -> Program:
    """A line sequence as a flat ShapeAssembly :class:`~shapeprog.lang.Program` (explicit subjects).

    Cuboids are named by :func:`cuboid_names`. Statement ``i`` of the result is ``lines[i]``, so the
    executor's ``ExecutedShape.line`` indexes ``lines``. ``check`` runs :func:`check_lines` first.
    """
    if check:
        check_lines(lines)
    names = cuboid_names(lines)
    name = lambda t: "bbox" if t == BBOX else names[t]  # noqa: E731
    stmts: list[Statement] = []
    k = -1
    for ln in lines:
        t = type(ln)
        if t is CuboidLine:
            stmts.append(Cuboid("bbox" if k < 0 else names[k], ln.l, ln.h, ln.w, ln.aligned))
            k += 1
            continue
        a = names[k - 1]
        if t is AttachLine:
            stmts.append(Attach(a, name(ln.target), ln.x1, ln.y1, ln.z1, ln.x2, ln.y2, ln.z2))
        elif t is SqueezeLine:
            stmts.append(Squeeze(a, name(ln.t1), name(ln.t2), ln.face, ln.u, ln.v))
        elif t is ReflectLine:
            stmts.append(Reflect(a, ln.axis))
        else:
            stmts.append(Translate(a, ln.axis, ln.n, ln.d))
    return Program((Block("Program_0", tuple(stmts)),), flat=True)
