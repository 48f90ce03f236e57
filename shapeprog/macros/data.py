"""ShapeMOD's input data: every corpus program as sub-programs in the modified grammar, with their
valid line orderings O_P and canonical signatures.

Each ``Assembly Program_k`` block of a hierarchical ShapeAssembly program becomes one
:class:`SubProgram` (its ``Program_`` parts are plain cuboids there). Its :class:`Cube` records hold
what the text fixes: dims and aligned flag, the 1-2 attaches or the squeeze that move the cube (the
"direction" of every contact), and its optional reflect/translate. The orderings are the grounded
PBlock orders of the spec: cubes grouped by *grounding level* (the longest path to the bbox), levels in
turn, any permutation inside a level, the first :data:`MAX_ORDERS` in lexicographic order. An
:class:`Ordering` is the permutation of cube indices plus its signature; :meth:`SubProgram.lines` writes
it in the grammar of :mod:`shapeprog.macros.grammar`, where cube ids are canonical (numbered by first
appearance).

:func:`convert_program` converts one program; :func:`convert_corpus` converts categories of the corpus,
optionally through a caller's ``concurrent.futures.Executor``. A block that cannot be written in the
grammar is reported as a :class:`Failure` (category, id, block, reason), never dropped silently.
:func:`order_errors` executes orderings and compares them with the original program.

The decisions (what the text fixes, the cleanup rules, what is dropped): ``docs/shapemod.md`` ("Data").

Example:
    >>> from shapeprog import corpus, parse
    >>> conv = convert_program(parse(corpus.read("chair", 173)), "chair", 173)
    >>> [s.key for s in conv.subprograms], conv.failures
    (['chair/173/Program_0', 'chair/173/Program_1'], [])
    >>> sub = conv.subprograms[1]
    >>> sub.levels, [o.cubes for o in sub.orders], sub.orders[1].signature
    ((1, 1), [(0, 1), (1, 0)], (('squeeze', 0, -1, -2), ('ref', 0), ('squeeze', 1, -1, -2), ('ref', 1)))
    >>> sub.lines(sub.orders[1])[1:3]
    (CuboidLine(l=0.206, h=0.526, w=0.192, aligned=True), SqueezeLine(t1=-1, t2=-1, face='top', u=0.12, v=0.902))
"""
from __future__ import annotations

import math
import time
from collections import Counter
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import torch

from .. import corpus
from ..errors import ParseError
from ..execute import execute_batch
from ..lang import Attach, Block, Cuboid, Program, Reflect, Squeeze, Translate, parse
from .grammar import (
    BBOX, AttachLine, CuboidLine, ReflectLine, Signature, SqueezeLine, TranslateLine, to_shapeassembly,
)
from .subprogram import (
    ConversionError, Cube, MAX_ORDERS, Move, ORDER_TOL, Ordering, SubProgram, _levels, _signature,
    _signature_parts, orderings,
)

__all__ = [
    "CLEANUP_MODES",
    "MIN_SEP_DIST",
    "ConversionError",
    "Conversion",
    "CorpusData",
    "Failure",
    "block_program",
    "convert_block",
    "convert_corpus",
    "convert_program",
    "order_errors",
]

#: Two attach points on the moving cube closer than this (local coordinates) are one contact.
MIN_SEP_DIST = 0.25
#: ``"exact"``: a close second attach is dropped only when that leaves the executed cuboids unchanged;
#: ``"spec"``: always dropped, as the reference's cleanup does (shapes may change).
CLEANUP_MODES = ("exact", "spec")


@dataclass(frozen=True)
class Failure:
    """A block (or a whole program, ``block == ''``) that could not be converted, and why."""

    category: str
    shape_id: int
    block: str
    reason: str

    def __str__(self) -> str:
        where = f"{self.category}/{self.shape_id}" + (f"/{self.block}" if self.block else "")
        return f"{where}: {self.reason}"


@dataclass
class Conversion:
    """The outcome of converting one program: its sub-programs, its failed blocks, and cleanup counts."""

    subprograms: list[SubProgram] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)
    counts: Counter = field(default_factory=Counter)


# ----------------------------------------------------------------------------- block -> cubes


def block_program(program: Program, block: str | Block) -> Program:
    """One block of ``program`` as a flat program whose ``Program_`` parts are plain cuboids.

    A part ``Program_m`` declared as the k-th non-bbox Cuboid line is renamed ``cube<k>`` (the corpus
    names every cube by its slot, so the name is free); the statements keep their order.
    """
    b = program.block(block) if isinstance(block, str) else block
    declared = [s.name for s in b.statements[1:] if isinstance(s, Cuboid)]
    used = set(declared)
    rename = {}
    for k, n in enumerate(declared):
        if n.startswith("Program_"):
            new = f"cube{k}" if f"cube{k}" not in used else f"part_{n[8:]}"
            rename[n] = new
    if not rename:
        return Program((Block("Program_0", b.statements),), flat=True)
    r = lambda n: rename.get(n, n)  # noqa: E731
    stmts = []
    for s in b.statements:
        if isinstance(s, Cuboid):
            s = Cuboid(r(s.name), s.l, s.h, s.w, s.aligned)
        elif isinstance(s, Attach):
            s = Attach(r(s.a), r(s.b), s.x1, s.y1, s.z1, s.x2, s.y2, s.z2)
        elif isinstance(s, Squeeze):
            s = Squeeze(r(s.a), r(s.b), r(s.c), s.face, s.u, s.v)
        elif isinstance(s, Reflect):
            s = Reflect(r(s.a), s.axis)
        else:
            s = Translate(r(s.a), s.axis, s.n, s.d)
        stmts.append(s)
    return Program((Block("Program_0", tuple(stmts)),), flat=True)


def _block_keys(block: Block) -> list[list[tuple[int, int]]]:
    """:meth:`SubProgram.statement_keys` for the block's own statements (text order)."""
    index = {s.name: i for i, s in enumerate(s for s in block.statements[1:] if isinstance(s, Cuboid))}
    keys: list[list[tuple[int, int]]] = []
    for si, s in enumerate(block.statements):
        if isinstance(s, Cuboid):
            keys.append([] if si == 0 else [(index[s.name], 0)])
        elif isinstance(s, Reflect):
            keys.append([(index[s.a], 1)])
        elif isinstance(s, Translate):
            keys.append([(index[s.a], i) for i in range(1, s.n + 1)])
        else:
            keys.append([])
    return keys


_FACE = {"right": (0, 0), "left": (0, 1), "top": (1, 0), "bot": (1, 1), "front": (2, 0), "back": (2, 1)}
_OPP = {"right": "left", "left": "right", "top": "bot", "bot": "top", "front": "back", "back": "front"}


def _as_squeeze(a: AttachLine, b: AttachLine) -> SqueezeLine | None:
    """The squeeze whose execution is exactly the attaches ``a`` then ``b`` (targets t1, t2), if any."""
    src_a, src_b = (a.x1, a.y1, a.z1), (b.x1, b.y1, b.z1)
    tga, tgb = (a.x2, a.y2, a.z2), (b.x2, b.y2, b.z2)
    for face, (k, val) in _FACE.items():
        free = [d for d in range(3) if d != k]
        want_a = [0.5, 0.5, 0.5]
        want_a[k] = 1.0 - val
        want_b = [0.5, 0.5, 0.5]
        want_b[k] = float(val)
        if list(src_a) != want_a or list(src_b) != want_b:
            continue
        u, v = tga[free[0]], tga[free[1]]
        if (tgb[free[0]], tgb[free[1]]) != (u, v):
            continue
        ka = float(1 - val) if a.target == BBOX else float(val)  # the squeeze's target coordinates
        _, val_o = _FACE[_OPP[face]]
        kb = float(1 - val_o) if b.target == BBOX else float(val_o)
        if tga[k] == ka and tgb[k] == kb:
            return SqueezeLine(a.target, b.target, face, u, v)
    return None


def _parse_block(block: Block) -> tuple[CuboidLine, list[Cube], list[int], bool]:
    """Cubes with all their text moves (no cleanup); the cubes' attach-point distances; and whether the
    text's statement order could execute differently from a grounded PBlock order."""
    st = block.statements
    bb = st[0]
    decl = [s for s in st[1:] if isinstance(s, Cuboid)]
    names = [s.name for s in decl]
    index = {n: i for i, n in enumerate(names)}
    if len(index) != len(names):
        raise ConversionError("a cuboid is declared twice")
    moves: list[list[Move]] = [[] for _ in decl]
    syms: list[list] = [[] for _ in decl]
    last_move = {}  # cube -> statement index of its last move
    first_use = {}  # cube -> statement index where another line first targets it or copies it

    def idx(name: str, what: str, si: int) -> int:
        if name == "bbox":
            return BBOX
        if name not in index:
            raise ConversionError(f"{what} uses {name!r}, a reflect/translate copy (statement {si + 1})")
        return index[name]

    for si, s in enumerate(st[1:], 1):
        if isinstance(s, Cuboid):
            if s.name == "bbox":
                raise ConversionError("the bbox is re-declared")
            continue
        a = idx(s.a, type(s).__name__.lower(), si)
        if a == BBOX:
            raise ConversionError(f"statement {si + 1} moves the bbox")
        if isinstance(s, Attach):
            t = idx(s.b, "attach", si)
            moves[a].append(AttachLine(t, s.x1, s.y1, s.z1, s.x2, s.y2, s.z2))
            targets = (t,)
        elif isinstance(s, Squeeze):
            t1, t2 = idx(s.b, "squeeze", si), idx(s.c, "squeeze", si)
            moves[a].append(SqueezeLine(t1, t2, s.face, s.u, s.v))
            targets = (t1, t2)
        else:
            if syms[a]:
                raise ConversionError(f"{s.a} has more than one reflect/translate (the grammar allows one)")
            syms[a].append(ReflectLine(s.axis) if isinstance(s, Reflect) else TranslateLine(s.axis, s.n, s.d))
            first_use.setdefault(a, si)  # its copies read its state now
            continue
        last_move[a] = si
        for t in targets:
            if t != BBOX:
                first_use.setdefault(t, si)
    cubes = []
    for i, (d, m) in enumerate(zip(decl, moves)):
        kinds = tuple(type(x) for x in m)
        if kinds not in ((AttachLine,), (AttachLine, AttachLine), (SqueezeLine,)):
            what = "is never attached" if not m else (
                f"is moved by {len(m)} lines ({', '.join('squeeze' if k is SqueezeLine else 'attach' for k in kinds)})")
            raise ConversionError(f"{d.name} {what}; the grammar needs 1-2 attaches or one squeeze")
        child = d.name if d.name.startswith("Program_") else None
        cubes.append(Cube(d.name, CuboidLine(d.l, d.h, d.w, d.aligned), tuple(m), syms[i][0] if syms[i] else None,
                          child))
    # order sensitivity: some cube is targeted (or copied) before its own last move
    sensitive = any(first_use.get(c, math.inf) < last_move[c] for c in range(len(cubes)))
    bbox = CuboidLine(bb.l, bb.h, bb.w, bb.aligned)
    return bbox, cubes, names, sensitive


def _corners_by_key(shape, keys: list[list[tuple[int, int]]]) -> dict:
    """Leaf corners of an executed flat program keyed by :meth:`SubProgram.statement_keys`."""
    out, seen = {}, Counter()
    for r, line in enumerate(shape.line.tolist()):
        k = keys[line][seen[line]]
        seen[line] += 1
        out[k] = shape.corners[r]
    return out


def _max_error(a: dict, b: dict) -> float:
    if a.keys() != b.keys():
        return math.inf
    return max((float((a[k] - b[k]).abs().max()) for k in a), default=0.0)


def _first_order_error(block: Block, bbox, cubes, names) -> float:
    """Corner difference between the block as written and its first grounded PBlock order."""
    levels = _levels(cubes, names)
    perm = orderings(levels, 1)[0][0]
    sub = SubProgram("", 0, block.name, None, bbox, tuple(cubes), tuple(levels), (Ordering(perm, ()),), 1)
    with torch.no_grad():
        ref, got = execute_batch([block_program(Program((block,)), block), to_shapeassembly(sub.lines(perm))])
    return _max_error(_corners_by_key(ref, _block_keys(block)), _corners_by_key(got, sub.statement_keys(perm)))


def convert_block(program: Program, block: str, category: str = "", shape_id: int = 0, cleanup: str = "exact",
                  max_orders: int = MAX_ORDERS, counts: Counter | None = None, intern: dict | None = None
                  ) -> SubProgram:
    """One block of ``program`` as a :class:`SubProgram` (see ``docs/shapemod.md``, "Data").

    Args:
        program: the parsed program.
        block: the block's name (``'Program_k'``).
        category, shape_id: where the program comes from (kept in the result and its key).
        cleanup: one of :data:`CLEANUP_MODES`.
        max_orders: orderings to enumerate at most.
        counts: a Counter that receives what the cleanup did (optional).
        intern: a dict used to share equal signature tuples between sub-programs (optional).

    Raises:
        ConversionError: the block cannot be written in the grammar (e.g. a cube with a second
            reflect/translate, a cube moved by three lines, an attachment cycle, or a text order
            whose execution differs from every grounded PBlock order).
    """
    if cleanup not in CLEANUP_MODES:
        raise ValueError(f"unknown cleanup {cleanup!r}; expected one of {', '.join(CLEANUP_MODES)}")
    counts = Counter() if counts is None else counts
    intern = {} if intern is None else intern
    b = program.block(block)
    bbox, cubes, names, sensitive = _parse_block(b)
    notes = []
    if sensitive:
        err = _first_order_error(b, bbox, cubes, names)
        if err > ORDER_TOL:
            raise ConversionError(f"its statement order executes differently from the grounded PBlock orders "
                                  f"(a cube is used before its last attach; corners differ by {err:.3g})")
        counts["text order differs, same cuboids"] += 1
    # squeezes written as two attaches
    for i, c in enumerate(cubes):
        if len(c.moves) == 2 and type(c.moves[0]) is AttachLine:
            sq = _as_squeeze(*c.moves)
            if sq is not None:
                cubes[i] = Cube(c.name, c.line, (sq,), c.sym, c.child)
                notes.append(f"{c.name}: two attaches written as one squeeze")
                counts["attach pair -> squeeze"] += 1
    # the cleanup: a second attach point closer than MIN_SEP_DIST to the first is the same contact
    for i, c in enumerate(cubes):
        if len(c.moves) != 2:
            continue
        a, b2 = c.moves
        if math.dist((a.x1, a.y1, a.z1), (b2.x1, b2.y1, b2.z1)) >= MIN_SEP_DIST:
            continue
        trial = list(cubes)
        trial[i] = Cube(c.name, c.line, (a,), c.sym, c.child)
        if cleanup == "exact":
            try:
                err = _dropped_error(b, bbox, cubes, trial, names)
            except ConversionError:
                err = math.inf
            if err > ORDER_TOL:
                notes.append(f"{c.name}: close second attach kept (dropping it changes the cuboids)")
                counts["close second attach kept"] += 1
                continue
        cubes = trial
        notes.append(f"{c.name}: close second attach dropped")
        counts["close second attach dropped"] += 1
    levels = _levels(cubes, names)
    perms, total = orderings(levels, max_orders)
    parts = _signature_parts(cubes)
    orders = tuple(Ordering(p, _signature(parts, p, intern)) for p in perms)
    parent = None
    for pb in program.blocks:
        decl = [s.name for s in pb.statements[1:] if isinstance(s, Cuboid)]
        if block in decl:
            parent = (pb.name, decl.index(block))
    return SubProgram(category, shape_id, block, parent, bbox, tuple(cubes), tuple(levels), orders, total,
                      tuple(notes))


def _dropped_error(block: Block, bbox, cubes, trial, names) -> float:
    """Corner difference between the first orders of two cube lists (the original and a cleaned one)."""
    subs = []
    for cs in (cubes, trial):
        levels = _levels(cs, names)
        perm = orderings(levels, 1)[0][0]
        subs.append(SubProgram("", 0, block.name, None, bbox, tuple(cs), tuple(levels), (Ordering(perm, ()),), 1))
    with torch.no_grad():
        shapes = execute_batch([to_shapeassembly(s.lines()) for s in subs])
    a, b = (_corners_by_key(sh, s.statement_keys()) for sh, s in zip(shapes, subs))
    # compare by cube: the orders may differ, the keys do not
    return _max_error(a, b)


def convert_program(program: Program, category: str = "", shape_id: int = 0, cleanup: str = "exact",
                    max_orders: int = MAX_ORDERS, intern: dict | None = None) -> Conversion:
    """Every block of ``program`` as a :class:`SubProgram`; blocks that fail are in ``failures``.

    Args:
        program: a parsed ShapeAssembly program (corpus or flat format).
        category, shape_id: where it comes from (kept in keys and failures).
        cleanup: one of :data:`CLEANUP_MODES`.
        max_orders: orderings to enumerate at most per sub-program.
        intern: a dict used to share equal signature tuples (optional).
    """
    out = Conversion()
    intern = {} if intern is None else intern
    for b in program.blocks:
        try:
            out.subprograms.append(convert_block(program, b.name, category, shape_id, cleanup, max_orders,
                                                 out.counts, intern))
        except ConversionError as e:
            out.failures.append(Failure(category, shape_id, b.name, str(e)))
    return out


# ----------------------------------------------------------------------------- corpus


@dataclass
class CorpusData:
    """Sub-programs of corpus categories, the failures, and the conversion's figures.

    Attributes:
        subprograms: every converted sub-program, program by program in split order.
        failures: the blocks (and unreadable programs) that were not converted.
        programs: programs read per category.
        counts: cleanup counts (see :class:`Conversion`), summed.
        seconds: wall time of the conversion.
    """

    subprograms: list[SubProgram]
    failures: list[Failure]
    programs: dict[str, int]
    counts: Counter
    seconds: float

    def by_category(self, category: str) -> list[SubProgram]:
        return [s for s in self.subprograms if s.category == category]

    def summary(self) -> str:
        """One line per category: programs, sub-programs, orderings (enumerated, |O_P| before the
        limit, sub-programs at the limit), failures; then the cleanup counts and the time."""
        rows = []
        for cat, n in self.programs.items():
            subs = self.by_category(cat)
            fails = sum(f.category == cat for f in self.failures)
            enum = sum(len(s.orders) for s in subs)
            full = sum(s.n_orders for s in subs)
            capped = sum(s.n_orders > len(s.orders) for s in subs)
            rows.append(f"{cat}: {n} programs, {len(subs)} sub-programs, {enum} orderings "
                        f"({enum / max(len(subs), 1):.2f} per sub-program; |O_P| total {full}, {capped} at the "
                        f"limit), {fails} failures")
        rows.append("cleanup: " + ", ".join(f"{k} {v}" for k, v in sorted(self.counts.items())))
        rows.append(f"seconds: {self.seconds:.1f}")
        return "\n".join(rows)


def _convert_ids(category: str, ids: list[int], cleanup: str, max_orders: int) -> Conversion:
    """Worker: read, parse and convert some corpus programs (module level, so process pools can run it)."""
    out = Conversion()
    intern: dict = {}
    for i in ids:
        try:
            prog = parse(corpus.read(category, i), f"{category}/{i}.txt")
        except (ParseError, KeyError) as e:
            out.failures.append(Failure(category, i, "", f"not read: {e}"))
            continue
        c = convert_program(prog, category, i, cleanup, max_orders, intern)
        out.subprograms += c.subprograms
        out.failures += c.failures
        out.counts.update(c.counts)
    return out


def convert_corpus(categories: Iterable[str] = ("chair", "table", "storage"), split: str = "all",
                   executor: Executor | None = None, cleanup: str = "exact", max_orders: int = MAX_ORDERS,
                   chunk: int = 200, limit: int | None = None) -> CorpusData:
    """Convert corpus programs into sub-programs (all categories by default).

    Args:
        categories: corpus categories.
        split: ``'train'``, ``'val'`` or ``'all'``.
        executor: a ``concurrent.futures.Executor`` (e.g. a ``ProcessPoolExecutor``) that converts
            chunks of programs in parallel; None converts in this process.
        cleanup: one of :data:`CLEANUP_MODES`.
        max_orders: orderings to enumerate at most per sub-program.
        chunk: programs per submitted task.
        limit: convert only the first ``limit`` programs of each category (in split order).

    Returns:
        The :class:`CorpusData`; equal signatures are shared objects across the whole result.
    """
    if cleanup not in CLEANUP_MODES:
        raise ValueError(f"unknown cleanup {cleanup!r}; expected one of {', '.join(CLEANUP_MODES)}")
    if max_orders < 1:
        raise ValueError(f"`max_orders` must be >= 1, got {max_orders}")
    t0 = time.perf_counter()
    tasks, programs = [], {}
    for cat in categories:
        ids = corpus.ids(cat, split)[:limit]
        programs[cat] = len(ids)
        tasks += [(cat, ids[k:k + chunk]) for k in range(0, len(ids), chunk)]
    if executor is None:
        results = [_convert_ids(cat, ids, cleanup, max_orders) for cat, ids in tasks]
    else:
        futures = [executor.submit(_convert_ids, cat, ids, cleanup, max_orders) for cat, ids in tasks]
        results = [f.result() for f in futures]
    subs, fails, counts = [], [], Counter()
    intern: dict = {}
    for r in results:
        for s in r.subprograms:
            orders = tuple(Ordering(o.cubes, _reintern(o.signature, intern)) for o in s.orders)
            subs.append(SubProgram(s.category, s.shape_id, s.block, s.parent, s.bbox, s.cubes, s.levels, orders,
                                   s.n_orders, s.notes))
        fails += r.failures
        counts.update(r.counts)
    return CorpusData(subs, fails, programs, counts, time.perf_counter() - t0)


def _reintern(sig: Signature, intern: dict) -> Signature:
    got = intern.get(sig)
    if got is not None:
        return got
    sig = tuple(intern.setdefault(e, e) for e in sig)
    return intern.setdefault(sig, sig)


# ----------------------------------------------------------------------------- checks


def order_errors(items: Sequence[tuple[SubProgram, Program]], max_orders: int | None = None, dtype=None,
                 batch_size: int = 1000) -> list[float]:
    """Execute orderings of sub-programs and compare them with their original programs.

    Args:
        items: ``(sub-program, the parsed program it comes from)`` pairs.
        max_orders: orderings to execute per sub-program (None: all of its enumerated ones).
        dtype: execution dtype (default float32).
        batch_size: programs per ``execute_batch`` call.

    Returns:
        Per item, the largest corner difference between its original block (executed alone, its
        ``Program_`` parts as leaves) and any executed ordering, matched cuboid by cuboid
        (``inf`` where an ordering creates other cuboids).

    Raises:
        LineError: an ordering that is not an executable sequence (e.g. a cube before its targets).
    """
    dtype = torch.float32 if dtype is None else dtype
    jobs = []  # (item index, program, keys, is_reference)
    for n, (sub, prog) in enumerate(items):
        b = prog.block(sub.block)
        jobs.append((n, block_program(prog, b), _block_keys(b), True))
        for o in sub.orders[:max_orders]:
            jobs.append((n, to_shapeassembly(sub.lines(o)), sub.statement_keys(o), False))
    errors = [0.0] * len(items)
    refs: dict[int, dict] = {}
    with torch.no_grad():
        for k in range(0, len(jobs), batch_size):
            part = jobs[k:k + batch_size]
            shapes = execute_batch([j[1] for j in part], dtype=dtype)
            for (n, _, keys, is_ref), shape in zip(part, shapes):
                got = _corners_by_key(shape, keys)
                if is_ref:
                    refs[n] = got
                else:
                    errors[n] = max(errors[n], _max_error(refs[n], got))
    return errors
