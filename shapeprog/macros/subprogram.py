"""A ShapeMOD sub-program: its cubes (:class:`Cube`), its valid line orderings (:func:`orderings`,
:class:`Ordering`) and their canonical signatures, written in the grammar of
:mod:`shapeprog.macros.grammar` (:meth:`SubProgram.lines`).

The orderings are the grounded PBlock orders: cubes grouped by grounding level (the longest path to the
bbox), levels in turn, any permutation inside a level, the first :data:`MAX_ORDERS` in lexicographic
order. :mod:`shapeprog.macros.data` converts corpus programs into sub-programs.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Sequence, Union

from .grammar import (
    BBOX, AttachLine, CuboidLine, Line, ReflectLine, Signature, SqueezeLine, TranslateLine, bbox_side,
    squeeze_sides,
)

__all__ = [
    "MAX_ORDERS",
    "ORDER_TOL",
    "ConversionError",
    "Cube",
    "Ordering",
    "SubProgram",
    "orderings",
]


#: At most this many orderings are enumerated per sub-program (the reference's MAX_ORDERS).
MAX_ORDERS = 10000


#: Largest corner difference for two executions to count as the same cuboids.
ORDER_TOL = 1e-4


Move = Union[AttachLine, SqueezeLine]
Sym = Union[ReflectLine, TranslateLine]


class ConversionError(ValueError):
    """A block that cannot be written in the modified grammar; the message says why."""


@dataclass(frozen=True)
class Cube:
    """One non-bbox cuboid of a sub-program, as the text declares and moves it.

    Attributes:
        name: its name in the block (``'cube3'`` or ``'Program_2'``).
        line: its dims and aligned flag.
        moves: the lines that move it, in text order: one or two :class:`AttachLine`, or one
            :class:`SqueezeLine`. Their targets are *original* cube indices (positions in
            :attr:`SubProgram.cubes`) or :data:`~shapeprog.macros.grammar.BBOX`.
        sym: its reflect or translate line, or None.
        child: the block of a ``Program_`` part (its sub-program), None for a leaf.
    """

    name: str
    line: CuboidLine
    moves: tuple[Move, ...]
    sym: Sym | None = None
    child: str | None = None

    def targets(self) -> set[int]:
        """Original indices of the cubes it attaches to (the bbox excluded)."""
        out = set()
        for m in self.moves:
            out.update((m.target,) if type(m) is AttachLine else (m.t1, m.t2))
        out.discard(BBOX)
        return out


@dataclass(frozen=True, slots=True)
class Ordering:
    """One valid line ordering o in O_P.

    Attributes:
        cubes: original cube indices in declaration order; the canonical id of ``cubes[i]`` is ``i``.
        signature: the canonical order signature (:func:`shapeprog.macros.grammar.signature` of
            :meth:`SubProgram.lines`); equal signatures are structural matches.
    """

    cubes: tuple[int, ...]
    signature: Signature


@dataclass(frozen=True)
class SubProgram:
    """One non-hierarchical sub-program (one block of a corpus program) and its orderings.

    Attributes:
        category: corpus category (``'chair'``, ...; may be empty for programs from elsewhere).
        shape_id: the program's id in its category.
        block: the block's name (``'Program_k'``).
        parent: ``(parent block, cube index there)`` of a non-root block, None for the root.
        bbox: the bbox line.
        cubes: the cuboids in declaration order (see :class:`Cube`).
        levels: grounding level of each cube (1: attached to the bbox only; the longest path to it).
        orders: the enumerated orderings, at most the ``max_orders`` given to the conversion.
        n_orders: |O_P|, the number of valid orderings before that limit.
        notes: what the cleanup did to this block (e.g. ``'cube2: close second attach dropped'``).
    """

    category: str
    shape_id: int
    block: str
    parent: tuple[str, int] | None
    bbox: CuboidLine
    cubes: tuple[Cube, ...]
    levels: tuple[int, ...]
    orders: tuple[Ordering, ...]
    n_orders: int
    notes: tuple[str, ...] = ()

    @property
    def key(self) -> str:
        """``'category/id/Program_k'``, unique over the corpus."""
        return f"{self.category}/{self.shape_id}/{self.block}"

    def lines(self, order: Ordering | Sequence[int] | None = None) -> tuple[Line, ...]:
        """The sub-program in the modified grammar, in ``order`` (default: the first ordering).

        The bbox line comes first; targets are canonical ids (positions in ``order``).
        """
        perm = self._perm(order)
        pos = {c: i for i, c in enumerate(perm)}
        pos[BBOX] = BBOX
        out: list[Line] = [self.bbox]
        for c in perm:
            cube = self.cubes[c]
            out.append(cube.line)
            for m in cube.moves:
                if type(m) is AttachLine:
                    out.append(AttachLine(pos[m.target], m.x1, m.y1, m.z1, m.x2, m.y2, m.z2))
                else:
                    out.append(SqueezeLine(pos[m.t1], pos[m.t2], m.face, m.u, m.v))
            if cube.sym is not None:
                out.append(cube.sym)
        return tuple(out)

    def _perm(self, order) -> tuple[int, ...]:
        if order is None:
            order = self.orders[0]
        perm = tuple(order.cubes if isinstance(order, Ordering) else order)
        if sorted(perm) != list(range(len(self.cubes))):
            raise ValueError(f"{self.key}: {perm} is not a permutation of its {len(self.cubes)} cubes")
        return perm

    def statement_keys(self, order: Ordering | Sequence[int] | None = None) -> list[list[tuple[int, int]]]:
        """Per line of :meth:`lines`, the cuboids it creates as ``(original cube index, copy)``: copy 0
        is the declared cuboid, 1..n its reflect/translate copies (the bbox line creates none)."""
        keys: list[list[tuple[int, int]]] = [[]]
        for c in self._perm(order):
            cube = self.cubes[c]
            keys.append([(c, 0)])
            keys.extend([] for _ in cube.moves)
            if cube.sym is not None:
                n = 1 if type(cube.sym) is ReflectLine else cube.sym.n
                keys.append([(c, i) for i in range(1, n + 1)])
        return keys


def _levels(cubes: Sequence[Cube], names: Sequence[str]) -> list[int]:
    """Grounding level of every cube: 1 + the largest level of its targets (bbox 0)."""
    level: dict[int, int] = {}
    state: dict[int, int] = {}

    def visit(i: int) -> int:
        if i in level:
            return level[i]
        if state.get(i) == 1:
            raise ConversionError(f"{names[i]} is part of an attachment cycle")
        state[i] = 1
        level[i] = 1 + max([visit(t) for t in cubes[i].targets()], default=0)
        return level[i]

    return [visit(i) for i in range(len(cubes))]


def orderings(levels: Sequence[int], limit: int = MAX_ORDERS) -> tuple[list[tuple[int, ...]], int]:
    """The grounded orders of cubes with the given levels: levels in turn, every permutation of the
    cubes inside a level.

    Returns:
        The first ``limit`` orders in lexicographic order (each a tuple of cube indices) and the
        number of valid orders, ``prod(n_l!)``.

    Example:
        >>> orderings([1, 2, 1])
        ([(0, 2, 1), (2, 0, 1)], 2)
    """
    if limit < 1:
        raise ValueError(f"`limit` must be >= 1, got {limit}")
    groups = [[i for i, lv in enumerate(levels) if lv == g] for g in sorted(set(levels))]
    total = math.prod(math.factorial(len(g)) for g in groups)
    perms = (itertools.permutations(g) for g in groups)
    out = [tuple(itertools.chain.from_iterable(p)) for p in itertools.islice(itertools.product(*perms), limit)]
    return out, total


def _signature_parts(cubes: Sequence[Cube]) -> list[list[tuple]]:
    """Per cube, its signature entries with original target indices (bbox targets already sided)."""
    parts = []
    for cube in cubes:
        ent: list[tuple] = []
        for m in cube.moves:
            if type(m) is AttachLine:
                ent.append(("att", bbox_side(m.y2) if m.target == BBOX else (m.target,)))
            else:
                s1, s2 = squeeze_sides(m)
                ent.append(("squeeze", s1 if m.t1 == BBOX else (m.t1,), s2 if m.t2 == BBOX else (m.t2,)))
        if cube.sym is not None:
            ent.append(("ref",) if type(cube.sym) is ReflectLine else ("trans",))
        parts.append(ent)
    return parts


def _signature(parts, perm, intern: dict) -> Signature:
    pos = {c: i for i, c in enumerate(perm)}
    out = []
    for i, c in enumerate(perm):
        for e in parts[c]:
            if len(e) == 1:
                t = (e[0], i)
            else:
                t = (e[0], i) + tuple(x if isinstance(x, int) else pos[x[0]] for x in e[1:])
            out.append(intern.setdefault(t, t))
    sig = tuple(out)
    return intern.setdefault(sig, sig)
