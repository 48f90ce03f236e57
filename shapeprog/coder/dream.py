"""ShapeCoder's dream phase: random programs of the library's functions, and composite scenes that pair
primitives with the expression to recognise (the recognition network's training data). NumPy and the
standard library.

For every Shape-returning function except ``Cuboid``/``Move``/``Rotate``/``Union`` (round 0: ``SymRef`` and
``SymTrans``; later also each abstraction), :func:`function_dreams` samples expressions until it has
``n`` valid ones (:data:`N_DREAMS` in the paper), :data:`DREAM_TIMEOUT` seconds have passed, or more than
:data:`MAX_FAILURES` attempts failed with fewer than :data:`MIN_SUCCESSES` successes (the function is then
abandoned).

* **Base functions.** ``SymRef(part, A)`` and ``SymTrans(part, A, INT#k#, D)``, the part
  ``Move(Cuboid(w,h,d),x,y,z)``, wrapped in a ``Rotate`` about a random axis with probability
  :data:`ROTATE_PROB` (2D: ``Move(Rectangle(w,h),x,y)``); A uniform, k uniform in :data:`COUNTS`.
* **Abstractions.** Each Float parameter is drawn from the law of the first slot it feeds
  (:func:`slot_kinds`: a ``Cuboid`` dimension, a ``Move`` coordinate, a ``Rotate`` angle, a ``SymTrans``
  distance; through nested abstractions too); Axis and Int parameters uniformly.
* **Laws** (:data:`LAWS`; Gaussian mixtures, weights normalised, then clipped, then rounded to 2 decimals):
  w, d: 0.8·N(.05,.05) + 0.2·N(.6,.3), clipped to [0, 1.4] / [0, 1.5]; h: .5·N(.1,.05) + .4·N(.6,.15) +
  .1·N(.25,.4), clipped to [0, 1.25]; x, z: .5·N(−.35,.15) + .5·N(.35,.15) + .2·N(0,.01); y: .4·N(−.25,.15)
  + .5·N(0,.01) + .1·N(.25,.15); a rotation takes one axis law at random (x: .3·N(.25,.1) + .2·N(−.15,.1)
  + .5·N(0,.4); y: U(−1,1); z: .9·N(0,.2) + .05·N(.65,.1) + .05·N(−.65,.1)); a SymTrans distance U(0.1, 1.5).
* **Rejection** (:func:`reject_reason`, in this order): 1 execution exception or hard error; 2 a soft
  error (base functions only); 3 ``Move(Move(`` or ``Union(Union(`` in the text; 4 more primitives than
  the domain's scene limit (16 / 12); 5 a dimension <= 0 after rounding; 6 a corner outside ±:data:`BOUND`;
  7 a total volume (area in 2D) below :data:`MIN_VOLUME`; 8 two primitives whose axis-aligned boxes overlap
  by more than :data:`MAX_OVERLAP` of the smaller box; 9 a literal that is not a primitive value (within
  :data:`LITERAL_TOL`), except a ``SymTrans`` distance (:func:`distance_literals`), which may be the
  difference of two values (the network writes it ``Sub(a,b)``); 10 not cheaper than the naive program of its primitives (structure cost, then
  parameter cost, :func:`split_cost`).

:func:`compose` builds scenes from the pools: k ~ U{1..:data:`MAX_SUB`} functions among those with fewer
than ``n`` targets; each sub-dream gets, with probability 1/2, an extra ``Move`` by U[0, 0.5)³ that is not
in its target; with probability 1/2 a scene gets 1 to :data:`MAX_DISTRACTORS` parts of a random real shape
(:data:`DISTRACTOR_TRIES` tries each to keep the scene valid: count, bounds, overlap). Each sub-dream is
one :class:`DreamPair` (the scene's ordered primitives, the target expression). :func:`dream` does both,
the pools one task per function through ``executor.map``; every function has its own seed, so the result
does not depend on the executor.

Example:
    >>> from shapeprog.coder.lang import Library
    >>> d = dream(Library(), n=20, seed=0)
    >>> sorted(d.functions), len(d.pairs) >= 40
    (['SymRef', 'SymTrans'], True)
    >>> reject_reason(parse("SymRef(Move(Cuboid(0.1,0.5,0.1),0.4,0.0,0.0),AX)"), Library())
    'soft error'
"""
from __future__ import annotations

import concurrent.futures as cf
import random
import time
import zlib
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .execute import ExecutionError, corners, order, run
from .lang import (FLOAT_CONSTANTS, FLOAT_FN, AxisConst, Call, Expr, IntConst, Library, Num, ProgramError, Type, Var,
                   parse, to_text, walk)  # parse: for the examples
from .objective import naive_cost

__all__ = ["BASE_EXCLUDED", "BOUND", "COUNTS", "DISTRACTOR_TRIES", "DREAM_TIMEOUT", "Dream", "DreamPair", "Dreams",
           "FunctionDreams", "LAWS", "LITERAL_TOL", "MAX_DISTRACTORS", "MAX_FAILURES", "MAX_OVERLAP", "MAX_SUB",
           "MIN_SUCCESSES", "MIN_VOLUME", "N_DREAMS", "REJECTIONS", "ROTATE_PROB", "compose", "distance_literals",
           "dream", "dreamed_functions", "function_dreams", "reject_reason", "sample_dream", "slot_kinds", "split_cost"]

#: Valid dreams per function (``num_dreams``).
N_DREAMS = 10_000
#: Seconds per function before its dreaming stops.
DREAM_TIMEOUT = 1800.0
#: A function is abandoned after more than this many failures ...
MAX_FAILURES = 20_000
#: ... with fewer than this many successes.
MIN_SUCCESSES = 10
#: Shape functions that are never dreamed.
BASE_EXCLUDED = ("Cuboid", "Rectangle", "Move", "Rotate", "Union")
#: Probability that a base dream's part is rotated.
ROTATE_PROB = 0.25
#: The ``SymTrans`` counts sampled (``INT#k#``).
COUNTS = (1, 2, 3, 4, 5, 6)
#: Corners must stay within ±BOUND on every axis ([-1, 1] plus 10%).
BOUND = 1.1
#: Smallest total volume (3D) / area (2D) of a dream (the reference code's ``min_area``).
MIN_VOLUME = {"3d": 0.005, "2d": 0.00025}
#: Largest overlap of two primitives' axis-aligned boxes, as a share of the smaller box.
MAX_OVERLAP = 0.5
#: A dream's literals must be within this of one of its primitives' values.
LITERAL_TOL = 0.01
#: Functions per composite scene (3D; 2D: 3).
MAX_SUB = {"3d": 4, "2d": 3}
#: Distractor primitives per scene at most (3D; 2D: 3).
MAX_DISTRACTORS = {"3d": 4, "2d": 3}
#: Tries to add one distractor primitive.
DISTRACTOR_TRIES = 10
#: The rejection reasons of :func:`reject_reason`, in the order they are checked.
REJECTIONS = ("exception", "hard error", "soft error", "nested", "too many prims", "dim <= 0", "out of bounds",
              "volume", "overlap", "literal", "not cheaper")

#: Gaussian mixtures ``((weight, mean, std), ...)`` and clip ranges of each parameter kind; ``U`` is uniform.
LAWS = {
    "w": (((0.8, 0.05, 0.05), (0.2, 0.6, 0.3)), (0.0, 1.4)),
    "d": (((0.8, 0.05, 0.05), (0.2, 0.6, 0.3)), (0.0, 1.5)),
    "h": (((0.5, 0.1, 0.05), (0.4, 0.6, 0.15), (0.1, 0.25, 0.4)), (0.0, 1.25)),
    "x": (((0.5, -0.35, 0.15), (0.5, 0.35, 0.15), (0.2, 0.0, 0.01)), None),
    "z": (((0.5, -0.35, 0.15), (0.5, 0.35, 0.15), (0.2, 0.0, 0.01)), None),
    "y": (((0.4, -0.25, 0.15), (0.5, 0.0, 0.01), (0.1, 0.25, 0.15)), None),
    "rx": (((0.3, 0.25, 0.1), (0.2, -0.15, 0.1), (0.5, 0.0, 0.4)), None),
    "ry": ("U", (-1.0, 1.0)),
    "rz": (((0.9, 0.0, 0.2), (0.05, 0.65, 0.1), (0.05, -0.65, 0.1)), None),
    "dist": ("U", (0.1, 1.5)),
}
_ROT = {"AX": "rx", "AY": "ry", "AZ": "rz"}


def _sample(kind: str, rng: random.Random) -> float:
    if kind == "rot":
        kind = rng.choice(("rx", "ry", "rz"))
    mix, clip = LAWS[kind]
    if mix == "U":
        v = rng.uniform(*clip)
    else:
        total = sum(w for w, _, _ in mix)
        r, acc = rng.random() * total, 0.0
        for w, mu, sd in mix:
            acc += w
            if r <= acc:
                break
        v = rng.gauss(mu, sd)
        if clip is not None:
            v = min(max(v, clip[0]), clip[1])
    return round(v, 2) + 0.0


# ----------------------------------------------------------------------------- costs and checks


def split_cost(expr: Expr, library: Library | None = None) -> tuple:
    """The wake's split cost ``(structure, parameters)``: structure counts the shape functions (1.0 each)
    and float operators (0.1); parameters count the *distinct* free float values or Float variables (2.0
    each), the constants 0/1/2 (0.5 per occurrence) and the categoricals (0.5 per occurrence)."""
    lib = library if library is not None else Library()
    struct, floats, param = 0.0, set(), 0.0
    for n in walk(expr):
        if isinstance(n, Call):
            sig = lib.signature(n.fn)
            struct += 0.1 if sig is not None and sig.kind == FLOAT_FN else 1.0
        elif isinstance(n, Num):
            if n.value in FLOAT_CONSTANTS:
                param += 0.5
            else:
                floats.add(round(n.value, 2))
        elif isinstance(n, Var):
            if n.type.categorical:
                param += 0.5
            else:
                floats.add(n.name)
        elif isinstance(n, (AxisConst, IntConst)):
            param += 0.5
    return struct, param + 2.0 * len(floats)


def _boxes(prims: np.ndarray) -> tuple:
    """Axis-aligned boxes (lo, hi) of primitives: (P, k) each."""
    if prims.shape[1] == 4:
        half = prims[:, 0:2] / 2
        return prims[:, 2:4] - half, prims[:, 2:4] + half
    c = corners(prims)
    return c.min(1), c.max(1)


def _scene_ok(prims: Sequence, lang) -> str | None:
    """Rules 4, 6 and 8 (count, bounds, overlap) on a primitive set."""
    if len(prims) > lang.max_prims:
        return "too many prims"
    p = np.asarray(prims, dtype=np.float64)
    lo, hi = _boxes(p)
    if (lo < -BOUND - 1e-9).any() or (hi > BOUND + 1e-9).any():
        return "out of bounds"
    if _overlapping(lo, hi):
        return "overlap"
    return None


def _overlapping(lo: np.ndarray, hi: np.ndarray) -> bool:
    if len(lo) < 2:
        return False
    inter = np.clip(np.minimum(hi[:, None], hi[None]) - np.maximum(lo[:, None], lo[None]), 0, None).prod(-1)
    vol = (hi - lo).prod(-1)
    small = np.minimum(vol[:, None], vol[None])
    np.fill_diagonal(inter, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(small > 0, inter / np.where(small > 0, small, 1), 0.0)
    return bool((share > MAX_OVERLAP).any())


def distance_literals(expr: Expr, library: Library | None = None) -> set:
    """``id()`` of the float literals of ``expr`` that fill a ``SymTrans`` distance, directly or as an
    abstraction argument whose parameter feeds one (:func:`slot_kinds`)."""
    lib = library if library is not None else Library()
    out: set = set()
    for n in walk(expr):
        if not isinstance(n, Call):
            continue
        if n.fn == "SymTrans" and isinstance(n.args[3], Num):
            out.add(id(n.args[3]))
        elif n.fn in lib:
            kinds = slot_kinds(n.fn, lib)
            for p, a in zip(lib[n.fn].params, n.args):
                if isinstance(a, Num) and kinds.get(p.name) == "dist":
                    out.add(id(a))
    return out


def reject_reason(expr: Expr, library: Library | None = None, base: bool | None = None) -> str | None:
    """Why a dream is rejected (one of :data:`REJECTIONS`, checked in that order), or None when it is
    valid. ``base``: the dreamed function is a base function (soft errors reject it); by default, when
    the expression's root is one."""
    lib = library if library is not None else Library()
    lang = lib.lang
    if base is None:
        base = isinstance(expr, Call) and lang.signature(expr.fn) is not None
    try:
        ex = run(expr, lib)
    except (ProgramError, ExecutionError, ValueError, ZeroDivisionError, OverflowError):
        return "exception"
    if ex.hard_errors:
        return "hard error"
    if base and ex.soft_errors:
        return "soft error"
    text = to_text(expr)
    if "Move(Move(" in text or "Union(Union(" in text:
        return "nested"
    prims = ex.primitives()
    if not prims:
        return "exception"
    if len(prims) > lang.max_prims:
        return "too many prims"
    k = lang.dim
    p = np.asarray(prims, dtype=np.float64)
    if (p[:, 0:k] <= 0).any():
        return "dim <= 0"
    lo, hi = _boxes(p)
    if (lo < -BOUND - 1e-9).any() or (hi > BOUND + 1e-9).any():
        return "out of bounds"
    if p[:, 0:k].prod(-1).sum() < MIN_VOLUME[lang.name]:
        return "volume"
    if _overlapping(lo, hi):
        return "overlap"
    values = np.unique(p.ravel())
    diffs, dist = None, distance_literals(expr, lib)
    for n in walk(expr):
        if isinstance(n, Num) and np.abs(values - n.value).min() > LITERAL_TOL + 1e-9:
            if id(n) not in dist:
                return "literal"
            if diffs is None:
                diffs = (values[:, None] - values[None]).ravel()
            if np.abs(diffs - n.value).min() > LITERAL_TOL + 1e-9:
                return "literal"
    nc = naive_cost(prims)
    struct, param = split_cost(expr, lib)
    if (struct, param) >= (nc.struct(), nc.param()):
        return "not cheaper"
    return None


# ----------------------------------------------------------------------------- sampling one dream


def dreamed_functions(library: Library) -> tuple:
    """The functions dreamed for ``library``: its Shape-returning base functions other than
    :data:`BASE_EXCLUDED`, then its abstractions."""
    base = tuple(n for n in library.lang.shape_functions if n not in BASE_EXCLUDED)
    return base + tuple(ab.name for ab in library.abstractions)


def slot_kinds(name: str, library: Library) -> dict:
    """``{parameter: law}`` of an abstraction's Float parameters: the law (a key of :data:`LAWS`, or
    ``"rot"`` for a rotation about a variable axis) of the first slot each feeds, in text order."""
    lib = library
    ab = lib[name]
    out: dict = {}
    slot = {("Cuboid", 0): "w", ("Cuboid", 1): "h", ("Cuboid", 2): "d", ("Rectangle", 0): "w",
            ("Rectangle", 1): "h", ("Move", 1): "x", ("Move", 2): "y", ("Move", 3): "z", ("SymTrans", 3): "dist"}

    def visit(e, kind):
        if isinstance(e, Var) and e.type is Type.FLOAT:
            out.setdefault(e.name, kind)
        elif isinstance(e, Call):
            for a in e.args:
                visit(a, kind)

    def go(e):
        if not isinstance(e, Call):
            return
        sig = lib.signature(e.fn)
        if sig.kind == FLOAT_FN:
            return
        inner = slot_kinds(e.fn, lib) if e.fn in lib else None
        for i, (a, t) in enumerate(zip(e.args, sig.params)):
            if t is Type.SHAPE:
                go(a)
            elif t is Type.FLOAT:
                if inner is not None:
                    kind = inner.get(lib[e.fn].params[i].name, "x")
                elif e.fn == "Rotate":
                    ax = e.args[1]
                    kind = _ROT[ax.name] if isinstance(ax, AxisConst) else "rot"
                else:
                    kind = slot.get((e.fn, i), "x")
                visit(a, kind)

    go(ab.body)
    return out


def _part(lang, rng: random.Random) -> Expr:
    if lang.dim == 2:
        return Call("Move", (Call("Rectangle", (Num(_sample("w", rng)), Num(_sample("h", rng)))),
                             Num(_sample("x", rng)), Num(_sample("y", rng))))
    e = Call("Move", (Call("Cuboid", tuple(Num(_sample(k, rng)) for k in "whd")),) +
             tuple(Num(_sample(k, rng)) for k in "xyz"))
    if rng.random() < ROTATE_PROB:
        axis = rng.choice(("AX", "AY", "AZ"))
        e = Call("Rotate", (e, AxisConst(axis), Num(_sample(_ROT[axis], rng))))
    return e


def sample_dream(name: str, library: Library, rng: random.Random) -> Expr:
    """One random expression of function ``name`` (not checked; see :func:`reject_reason`)."""
    lang = library.lang
    if name == "SymRef":
        return Call("SymRef", (_part(lang, rng), AxisConst(rng.choice(lang.axes))))
    if name == "SymTrans":
        return Call("SymTrans", (_part(lang, rng), AxisConst(rng.choice(lang.axes)), IntConst(rng.choice(COUNTS)),
                                 Num(_sample("dist", rng))))
    if name not in library:
        raise ProgramError(f"cannot dream {name!r}: not a dreamed base function nor an abstraction of the library")
    kinds = slot_kinds(name, library)
    args = []
    for p in library[name].params:
        if p.type is Type.FLOAT:
            args.append(Num(_sample(kinds.get(p.name, "x"), rng)))
        elif p.type is Type.AXIS:
            args.append(AxisConst(rng.choice(lang.axes)))
        else:
            args.append(IntConst(rng.choice(COUNTS)))
    return Call(name, tuple(args))


@dataclass(frozen=True)
class Dream:
    """One valid dream: the function dreamed, its expression (literals) and its ordered primitives."""

    fn: str
    expr: Expr
    prims: tuple


@dataclass(frozen=True)
class FunctionDreams:
    """The dreams of one function.

    Attributes:
        fn: the function.
        dreams: the valid dreams, in sampling order.
        failures: ``{reason: count}`` of the rejected samples.
        abandoned: stopped after :data:`MAX_FAILURES` failures with fewer than :data:`MIN_SUCCESSES` dreams.
        timed_out: stopped by the timeout.
        seconds: wall time.
    """

    fn: str
    dreams: tuple
    failures: dict
    abandoned: bool = False
    timed_out: bool = False
    seconds: float = 0.0


def _seed(seed: int, name: str) -> int:
    return (int(seed) * 1_000_003 + zlib.crc32(name.encode())) % (2 ** 63)


def function_dreams(name: str, library: Library, n: int = N_DREAMS, seed: int = 42,
                    timeout: float | None = DREAM_TIMEOUT) -> FunctionDreams:
    """Up to ``n`` valid dreams of ``name`` (see the module docstring); deterministic for a seed unless
    the timeout stops it."""
    rng = random.Random(_seed(seed, name))
    base = library.lang.signature(name) is not None
    t0 = time.perf_counter()
    dreams, failures, fails = [], {}, 0
    abandoned = timed_out = False
    while len(dreams) < n:
        e = sample_dream(name, library, rng)
        why = reject_reason(e, library, base)
        if why is None:
            dreams.append(Dream(name, e, run(e, library).primitives()))
        else:
            failures[why] = failures.get(why, 0) + 1
            fails += 1
            if fails > MAX_FAILURES and len(dreams) < MIN_SUCCESSES:
                abandoned = True
                break
        if timeout is not None and time.perf_counter() - t0 > timeout:
            timed_out = True
            break
    return FunctionDreams(name, tuple(dreams), failures, abandoned, timed_out, time.perf_counter() - t0)


def _task(args) -> FunctionDreams:
    name, library, n, seed, timeout = args
    return function_dreams(name, library, n, seed, timeout)


# ----------------------------------------------------------------------------- composite scenes


@dataclass(frozen=True)
class DreamPair:
    """One training pair: a scene's primitives (ordered) and the expression of one of its sub-dreams
    (without the sub-dream's extra Move, if it got one).

    Attributes:
        scene: P tuples of 9 (3D) or 4 (2D) floats.
        target: the expression to recognise.
        fn: the dreamed function.
        moved: the sub-dream's primitives were moved by an extra Move not in ``target``.
    """

    scene: tuple
    target: Expr
    fn: str
    moved: bool = False


def _moved(prims: tuple, off: tuple) -> tuple:
    k = len(off)
    i0 = 2 if len(prims[0]) == 4 else 3
    return tuple(tuple(p[:i0]) + tuple(round(p[i0 + j] + off[j], 2) + 0.0 for j in range(k)) + tuple(p[i0 + k:])
                 for p in prims)


def compose(pools: dict, n: int, rng: random.Random, lang, shapes: Sequence = ()) -> list:
    """Composite scenes from ``pools`` (``{fn: [Dream, ...]}``) until every function with dreams has
    ``n`` targets (see the module docstring); ``shapes`` are real primitive sets for distractors.

    Returns:
        list of :class:`DreamPair`, in generation order.
    """
    names = [f for f in sorted(pools) if pools[f]]
    counts = {f: 0 for f in names}
    nxt = {f: 0 for f in names}
    real = [tuple(getattr(s, "prims", s)) for s in shapes]
    real = [r for r in real if r]
    pairs: list = []
    tries = 0
    max_tries = 50 * n * max(1, len(names)) + 100
    k_max = MAX_SUB[lang.name]
    while names and tries < max_tries:
        needing = [f for f in names if counts[f] < n]
        if not needing:
            break
        tries += 1
        k = rng.randint(1, k_max)
        scene: list = []
        subs: list = []
        for _ in range(k):
            f = rng.choice(needing)
            d = pools[f][nxt[f] % len(pools[f])]
            nxt[f] += 1
            prims, moved = d.prims, False
            if rng.random() < 0.5:
                prims, moved = _moved(prims, tuple(rng.uniform(0.0, 0.5) for _ in range(lang.dim))), True
            if _scene_ok(scene + list(prims), lang) is not None:
                continue
            scene += list(prims)
            subs.append((d, moved))
        if not subs:
            continue
        if real and rng.random() < 0.5:
            for _ in range(rng.randint(1, MAX_DISTRACTORS[lang.name])):
                for _t in range(DISTRACTOR_TRIES):
                    shape = rng.choice(real)
                    p = shape[rng.randrange(len(shape))]
                    if _scene_ok(scene + [p], lang) is None:
                        scene.append(p)
                        break
        ordered = order(scene)
        for d, moved in subs:
            if counts[d.fn] < n:
                pairs.append(DreamPair(ordered, d.expr, d.fn, moved))
                counts[d.fn] += 1
    return pairs


@dataclass
class Dreams:
    """The result of :func:`dream`: the training pairs and the dreams of each function."""

    pairs: list
    functions: dict = field(default_factory=dict)

    def summary(self) -> str:
        """One line per function: valid dreams, failures by reason, abandoned / timed out."""
        lines = []
        for f, fd in self.functions.items():
            fails = ", ".join(f"{k} {v}" for k, v in sorted(fd.failures.items(), key=lambda kv: -kv[1]))
            flag = " (abandoned)" if fd.abandoned else " (timed out)" if fd.timed_out else ""
            lines.append(f"{f}: {len(fd.dreams)} dreams, {sum(fd.failures.values())} rejected [{fails}]"
                         f" {fd.seconds:.1f} s{flag}")
        return "\n".join(lines)


def dream(library: Library, n: int = N_DREAMS, seed: int = 42, shapes: Sequence = (),
          executor: cf.Executor | None = None, cache: dict | None = None,
          timeout: float | None = DREAM_TIMEOUT) -> Dreams:
    """The dream phase for ``library``: ``n`` valid dreams per function of :func:`dreamed_functions`
    (one ``executor.map`` task per function; None: in this process), then :func:`compose` until every
    function has ``n`` targets (seeded with ``seed``; ``shapes`` give the distractors).

    Args:
        cache: ``{abstraction text: FunctionDreams}``; abstractions found there are not dreamed again,
            and new ones are added (the paper caches abstraction dreams across rounds, and dreams the
            base functions every round).
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be an int >= 1, got {n!r}")
    names = dreamed_functions(library)
    keys = {f: (library[f].to_text() if f in library else None) for f in names}
    todo = [f for f in names if keys[f] is None or cache is None or keys[f] not in cache]
    tasks = [(f, library, n, seed, timeout) for f in todo]
    got = list(executor.map(_task, tasks)) if executor is not None else [_task(t) for t in tasks]
    results = dict(zip(todo, got))
    for f in names:
        if f not in results:
            fd = cache[keys[f]]
            results[f] = FunctionDreams(f, tuple(Dream(f, Call(f, d.expr.args), d.prims) for d in fd.dreams),
                                        fd.failures, fd.abandoned, fd.timed_out, 0.0)
        elif cache is not None and keys[f] is not None:
            cache[keys[f]] = results[f]
    pools = {f: list(results[f].dreams) for f in names}
    pairs = compose(pools, n, random.Random(_seed(seed, "<compose>")), library.lang, shapes)
    return Dreams(pairs, results)

