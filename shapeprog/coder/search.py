"""The wake's program search with the recognition network, and the per-shape store of covering
expressions that combines what every round found.

:func:`search_shape` (the reference's ``mc_prog_search``): while primitives of the shape are left,

1. the baseline is the naive expression of the first remaining primitive (a ``Cuboid`` in a ``Move``,
   a ``Rotate`` per non-zero angle);
2. batches of :data:`WAKE_BATCH` expressions are sampled from the network conditioned on the remaining
   primitives: :func:`step_batches` of them, a count (``step_budget`` batch-primitives shared by the scene's
   primitives, at most ``batches``), so that the search depends only on its seed; ``seconds`` is a safety
   cap only (no new batch after it), set far above what the count takes on a loaded machine;
3. a sample counts when its primitives match a subset of the remaining ones directly (Hungarian match,
   every pair within the domain's threshold); otherwise, when its first primitive's dimensions are within
   :data:`ALIGN_TOL` of a remaining primitive's, ``Move(sample, dx, dy, dz)`` onto that primitive is tried;
4. the score is structure / covered + 0.001 · parameters / covered (the split cost,
   :func:`shapeprog.coder.dream.split_cost`); the best expression is kept and its primitives removed.

:class:`Store` keeps, per shape, the cheapest expression found for every covered primitive subset, across
rounds. :meth:`Store.replace` swaps a program's pieces for cheaper stored ones that cover the same
primitives (the paper's combine variant iii) and :meth:`Store.rebuild` builds a program greedily from
the stored expressions, cheapest per covered primitive first, without overlaps, the rest naive (variant
iv). The discovery (:func:`shapeprog.coder.wake.wake` with a network) refactors these candidates with
the e-graph and keeps the cheapest.

Example:
    >>> from shapeprog.coder.lang import Library, parse
    >>> prims = ((0.1, 0.5, 0.1, -0.4, 0.0, 0.2, 0.0, 0.0, 0.0), (0.1, 0.5, 0.1, 0.4, 0.0, 0.2, 0.0, 0.0, 0.0))
    >>> covers(parse("SymRef(Move(Cuboid(0.1,0.5,0.1),-0.4,0.0,0.2),AX)"), Library(), prims)[1]
    (0, 1)
    >>> to_text(covers(parse("SymTrans(Move(Cuboid(0.1,0.5,0.1),-0.3,0.0,0.2),AX,INT#1#,0.8)"), Library(), prims)[0])
    'Move(SymTrans(Move(Cuboid(0.1,0.5,0.1),-0.3,0.0,0.2),AX,INT#1#,0.8),-0.1,0.0,0.0)'
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import torch

from .dream import split_cost
from .execute import ExecutionError, run
from .lang import Call, Expr, Library, Num, ProgramError, parse, substitute, to_text
from .objective import match, naive_program, program_cost
from .proposal import pieces
from .recnet import sample

__all__ = ["ALIGN_TOL", "WAKE_BATCH", "WAKE_BATCHES", "WAKE_SECONDS", "WAKE_STEP_BUDGET", "WAKE_BATCH_COST", "Found", "Store",
           "covers", "naive_piece", "search_shape", "step_batches", "union", "wake_score"]

#: Expressions sampled per batch.
WAKE_BATCH = 64
#: Batches per search step at most.
WAKE_BATCHES = 16
#: The budget of one search step, a count: a batch sampled for a scene of n primitives costs
#: ``n + WAKE_BATCH_COST`` units and a step draws ``ceil(WAKE_STEP_BUDGET / (n + WAKE_BATCH_COST))`` batches
#: (at most :data:`WAKE_BATCHES`; :func:`step_batches`). A batch takes about (0.045 + 0.0065 n) s of CPU with the
#: shipped networks, so this count stands for the paper's 1 s per step (``wk_prog_search_timeout``) on an idle
#: CPU: the batches the 1 s drew when measured in CPU time (docs/shapecoder.md, "Budgets").
WAKE_STEP_BUDGET = 180
#: The fixed part of a batch's cost in :data:`WAKE_STEP_BUDGET`'s units (primitives' worth).
WAKE_BATCH_COST = 7
#: A safety cap in seconds per search step, not the budget: no new batch starts after it. Far above what
#: :data:`WAKE_STEP_BUDGET` takes on a loaded machine (16 batches of 64 on a 16-primitive scene: about 3 s of
#: CPU), so that it does not bind and the search depends only on its seed.
WAKE_SECONDS = 120.0
#: Dimension tolerance of the alignment Move.
ALIGN_TOL = 0.1


def wake_score(expr: Expr, n_covered: int, library: Library | None = None) -> float:
    """structure / covered + 0.001 · parameters / covered."""
    s, p = split_cost(expr, library)
    return s / n_covered + 0.001 * p / n_covered


def naive_piece(prim) -> Expr:
    """The naive expression of one primitive, with literals."""
    e, env = naive_program([prim])
    return substitute(e, {k: Num(v) for k, v in env.items()})


def union(exprs: Sequence[Expr]) -> Expr:
    """The right-nested ``Union`` of ``exprs`` (one: itself)."""
    if not exprs:
        raise ValueError("no expressions")
    out = exprs[-1]
    for e in reversed(exprs[:-1]):
        out = Call("Union", (e, out))
    return out


def _prims_of(expr: Expr, library: Library):
    try:
        ex = run(expr, library)
    except (ProgramError, ExecutionError, ValueError, OverflowError, ZeroDivisionError):
        return None
    if ex.hard_errors:
        return None
    return ex.primitives()


def covers(expr: Expr, library: Library, prims: Sequence) -> tuple | None:
    """``(expression, covered indices)`` when ``expr``'s primitives match a subset of ``prims`` directly
    or after an alignment Move (see the module docstring); else None."""
    got = _prims_of(expr, library)
    if not got or len(got) > len(prims) or len(got[0]) != len(prims[0]):
        return None
    thr = library.lang.match_threshold
    m = match(got, prims, threshold=thr)
    if m.valid:
        return expr, m.covered
    k = library.lang.dim
    c0 = 2 if k == 2 else 3
    first = got[0]
    tried = set()
    for p in prims:
        if all(abs(first[j] - p[j]) <= ALIGN_TOL for j in range(c0)):
            off = tuple(round(p[c0 + j] - first[c0 + j], 2) + 0.0 for j in range(k))
            if off in tried or not any(off):
                continue
            tried.add(off)
            moved = Call("Move", (expr,) + tuple(Num(v) for v in off))
            got2 = _prims_of(moved, library)
            if got2 is None:
                continue
            m = match(got2, prims, threshold=thr)
            if m.valid:
                return moved, m.covered
    return None


@dataclass(frozen=True)
class Found:
    """One step of :func:`search_shape`: the expression kept, the shape's primitives it covers (indices),
    its wake score, and whether it came from the network (False: the naive baseline won)."""

    expr: Expr
    covered: tuple
    score: float
    from_network: bool


def step_batches(n_prims: int, batches: int = WAKE_BATCHES, step_budget: int | None = WAKE_STEP_BUDGET) -> int:
    """The batches of one search step on a scene of ``n_prims`` primitives:
    ``ceil(step_budget / (n_prims + WAKE_BATCH_COST))``, at least 1 and at most ``batches``
    (``step_budget=None``: ``batches``).

    >>> [step_batches(n) for n in (1, 4, 5, 7, 10, 12, 16)]
    [16, 16, 15, 13, 11, 10, 8]
    """
    if step_budget is None:
        return max(1, batches)
    return max(1, min(batches, -(-step_budget // (max(1, n_prims) + WAKE_BATCH_COST))))


def search_shape(prims: Sequence, library: Library, model, vocab, *, batch: int = WAKE_BATCH,
                 batches: int = WAKE_BATCHES, step_budget: int | None = WAKE_STEP_BUDGET,
                 seconds: float | None = WAKE_SECONDS, seed: int = 0) -> list:
    """The network search of one shape (see the module docstring).

    Args:
        prims: the shape's primitives (ordered).
        model, vocab: a :class:`~shapeprog.coder.recnet.RecognitionNet` and its vocabulary.
        batches, step_budget: the budget per step, a count (:func:`step_batches`).
        seconds: a safety cap per step, not the budget (no new batch after it; None: no cap); the default
            does not bind on a loaded machine, so the result depends only on ``seed``.
        seed: seeds the sampling (step k uses ``seed * 1000 + k``).

    Returns:
        list of :class:`Found`, whose covered sets partition the primitives.
    """
    prims = tuple(tuple(p) for p in prims)
    remaining = list(range(len(prims)))
    out = []
    step = 0
    limit = model.cfg.max_prims
    while remaining:
        idx = remaining[:limit]
        scene = [prims[i] for i in idx]
        base = naive_piece(scene[0])
        best = (wake_score(base, 1, library), base, (0,), False)
        gen = torch.Generator().manual_seed(seed * 1000 + step)
        seen: set = set()
        t0 = time.perf_counter()
        for b in range(step_batches(len(scene), batches, step_budget)):
            if b and seconds is not None and time.perf_counter() - t0 > seconds:
                break
            for e in sample(model, vocab, scene, batch, gen):
                key = to_text(e)
                if key in seen:
                    continue
                seen.add(key)
                got = covers(e, library, scene)
                if got is None:
                    continue
                s = wake_score(got[0], len(got[1]), library)
                if s < best[0] - 1e-12:
                    best = (s, got[0], got[1], True)
        covered = tuple(sorted(idx[i] for i in best[2]))
        out.append(Found(best[1], covered, best[0], best[3]))
        remaining = [r for r in remaining if r not in covered]
        step += 1
    return out


class Store:
    """Per shape, the cheapest expression found for each covered primitive subset.

    Args:
        prims: the shape's primitives.
        library: the current library (entries that no longer parse with it are dropped).
        entries: ``{"i,j,...": expression text}`` from :meth:`to_dict`.
    """

    def __init__(self, prims: Sequence, library: Library, entries: dict | None = None):
        self.prims = tuple(tuple(p) for p in prims)
        self.library = library
        self.items: dict = {}  # covered tuple -> (cost, expr)
        for key, text in (entries or {}).items():
            try:
                e = parse(text, library)
                cov = tuple(int(x) for x in key.split(","))
            except (ValueError, ProgramError):
                continue
            self.items[cov] = (program_cost(e, library), e)

    def add(self, expr: Expr, covered: Sequence[int]) -> None:
        cov = tuple(sorted(covered))
        c = program_cost(expr, self.library)
        old = self.items.get(cov)
        if old is None or c < old[0] - 1e-9:
            self.items[cov] = (c, expr)

    def add_program(self, program: Expr) -> list | None:
        """Add the top-level pieces of ``program`` (each matched to the shape's primitives); returns
        ``[(piece, covered)]``, or None when a piece covers nothing valid or two pieces overlap."""
        out, used = [], set()
        for p in pieces(program):
            got = covers(p, self.library, self.prims)
            if got is None or got[0] is not p or used & set(got[1]):
                return None
            used |= set(got[1])
            out.append((p, got[1]))
        for p, cov in out:
            self.add(p, cov)
        return out

    def replace(self, parts: list) -> Expr:
        """Variant iii: each ``(piece, covered)`` replaced by the stored expression for the same
        primitives when that is cheaper; the union of the result."""
        out = []
        for p, cov in parts:
            stored = self.items.get(tuple(sorted(cov)))
            cost = program_cost(p, self.library)
            out.append(stored[1] if stored is not None and stored[0] < cost - 1e-9 else p)
        return union(out)

    def rebuild(self) -> Expr:
        """Variant iv: stored expressions by cost per covered primitive (ties: more primitives first),
        without overlaps; uncovered primitives get naive pieces."""
        ranked = sorted(self.items.items(), key=lambda kv: (kv[1][0] / len(kv[0]), -len(kv[0]), kv[0]))
        used: set = set()
        parts = []
        for cov, (_, e) in ranked:
            if used & set(cov):
                continue
            used |= set(cov)
            parts.append((min(cov), e))
        for i, p in enumerate(self.prims):
            if i not in used:
                parts.append((i, naive_piece(p)))
        parts.sort(key=lambda x: x[0])
        return union([e for _, e in parts])

    def to_dict(self) -> dict:
        return {",".join(map(str, k)): to_text(e) for k, (_, e) in sorted(self.items.items())}
