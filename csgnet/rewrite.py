"""Short programs: pruning the parts of a program that do not pay for their length, and choosing among
candidates by IoU minus a price per primitive.

A decoded or refined program may carry primitives that change little of its shape (a small circle
subtracted where there is nothing, a union with a sliver). :func:`prune` removes them: at every
operator it tries keeping only the left or only the right operand, and takes the change that raises
``IoU - penalty * primitives`` most, until no change raises it. :func:`graft` goes the other way: it
adds a primitive of another candidate (e.g. another beam) by union, intersection or difference where
that raises the same objective, and :func:`extend` searches the whole vocabulary for such a primitive.
:func:`choose` picks, among candidate programs, the one with the
highest ``IoU - penalty * primitives`` (ties: the earlier).

The price ``LENGTH_PENALTY`` (IoU per primitive, by dimension) is chosen on the synthetic validation
split by ``python bench/length_penalty.py`` (docs/csgnet.md): the largest price whose chosen
programs lose at most ``MAX_VAL_IOU_COST`` of mean IoU against choosing by IoU alone.

Example:
    >>> import csgnet
    >>> from csgnet.rewrite import prune
    >>> target = csgnet.render("c(32,32,20)")[0]
    >>> prune("c(32,32,20)c(8,8,8)-", target).text()    # the subtracted circle misses the shape
    'c(32,32,20)'
"""
from __future__ import annotations

from functools import lru_cache
from typing import Sequence

import numpy as np
import torch

from . import render
from .lang import OPERATORS, Draw, Op, Program, is_valid, parse
from .renderer import draw_packed, pack
from .score import _check_target, program_scores
from .vocab import vocabulary

__all__ = ["LENGTH_PENALTY", "MAX_PRUNE_ROUNDS", "MAX_GRAFT_ROUNDS", "MAX_EXTEND_ROUNDS", "MAX_GRAFT_DRAWS",
           "MAX_VAL_IOU_COST", "objective", "removals", "prune", "graft", "extend", "choose"]

LENGTH_PENALTY = {2: 0.02, 3: 0.01}
"""IoU given up per primitive saved (by dimension), chosen on the validation split (module docstring)."""
MAX_VAL_IOU_COST = 0.005
"""The mean IoU the chosen price may cost on the validation split, against choosing by IoU alone."""
MAX_PRUNE_ROUNDS = 16
"""Removals :func:`prune` makes at most (each removes at least one primitive, so 16 covers the
longest decoded programs, 7 primitives in 2D and 4 in 3D, with room to spare)."""


MAX_EXTEND_ROUNDS = 4
"""Primitives :func:`extend` adds at most."""
MAX_GRAFT_ROUNDS = 3
"""Primitives :func:`graft` adds at most."""
MAX_GRAFT_DRAWS = 8
"""The most primitives a grafted program may reach (twice the longest 3D training program's)."""


def _program(program: Program | str, dim: int) -> Program:
    if isinstance(program, str):
        return parse(program, dim)
    if not isinstance(program, Program):
        raise TypeError(f"expected a Program or program text, got {type(program).__name__}")
    if program.dim != dim:
        raise ValueError(f"a {program.dim}D program for a {dim}D target")
    return program


def objective(iou: float, program: Program, penalty: float) -> float:
    """``iou - penalty * (number of primitives)``: what :func:`prune` and :func:`choose` maximise."""
    return float(iou) - float(penalty) * len(program.draws)


def removals(program: Program) -> list[Program]:
    """Every program obtained by replacing one operator's subtree with one of its two operands, in
    program order (left operand first). An invalid program has none."""
    tokens = program.tokens
    if not is_valid(program):
        return []
    starts: list[int] = []  # starts[i]: the first token of the subtree that ends at token i
    for i, t in enumerate(tokens):
        # an operator's right operand ends just before it, and its left operand just before that
        starts.append(i if isinstance(t, Draw) else starts[starts[i - 1] - 1])
    out = []
    for i, t in enumerate(tokens):
        if isinstance(t, Draw):
            continue
        right = (starts[i - 1], i - 1)
        left = (starts[i], right[0] - 1)
        for a, b in (left, right):
            out.append(Program(tokens[:starts[i]] + tokens[a:b + 1] + tokens[i + 1:], program.dim))
    return out


def _scores(programs: Sequence[Program], target) -> list[float]:
    return [iou for iou, _ in program_scores(programs, target)]


def _improve(best: Program, changes, target, penalty: float, max_rounds: int) -> Program:
    """Hill climbing on :func:`objective`: each round takes the best of ``changes(best)`` (the earliest on
    ties) if it scores higher, for at most ``max_rounds`` rounds."""
    best_score = objective(_scores([best], target)[0], best, penalty)
    for _ in range(int(max_rounds)):
        cands = changes(best)
        if not cands:
            break
        scored = [objective(s, c, penalty) for s, c in zip(_scores(cands, target), cands)]
        i = max(range(len(cands)), key=lambda j: (scored[j], -j))
        if scored[i] <= best_score:
            break
        best, best_score = cands[i], scored[i]
    return best


def prune(program: Program | str, target, penalty: float | None = None,
          max_rounds: int = MAX_PRUNE_ROUNDS) -> Program:
    """Remove operands while that raises :func:`objective` (best removal first); returns the program
    itself when nothing does, or when it is invalid.

    Args:
        program: a program or its text, of the target's dimension.
        target: ``(64, 64)`` image or ``(64, 64, 64)`` volume (non-zero = on).
        penalty: IoU per primitive (default ``LENGTH_PENALTY`` of the dimension).
        max_rounds: removals made at most.
    """
    t = _check_target(target)
    penalty = LENGTH_PENALTY[t.ndim] if penalty is None else float(penalty)
    best = _program(program, t.ndim)
    if not is_valid(best):
        return best
    return _improve(best, removals, t, penalty, max_rounds)


def choose(programs: Sequence[Program | str], target, penalty: float | None = None) -> tuple[int, list[float]]:
    """The index of the program with the highest :func:`objective` (the earliest on ties), and every
    program's IoU. Invalid programs render empty."""
    t = _check_target(target)
    penalty = LENGTH_PENALTY[t.ndim] if penalty is None else float(penalty)
    progs = [_program(p, t.ndim) for p in programs]
    if not progs:
        raise ValueError("choose needs at least one program")
    ious = _scores(progs, t)
    scored = [objective(s, p, penalty) for s, p in zip(ious, progs)]
    return max(range(len(progs)), key=lambda j: (scored[j], -j)), ious


def graft(program: Program | str, donors: Sequence[Program | str], target, penalty: float | None = None,
          max_rounds: int = MAX_GRAFT_ROUNDS, max_draws: int = MAX_GRAFT_DRAWS) -> Program:
    """Combine ``program`` with primitives of other programs (e.g. the other beams) while that raises
    :func:`objective`: each round tries the program with each donor primitive added by union, intersection
    and difference at its end (``P q +``, ``P q *``, ``P q -``) and keeps the best change, until no change
    raises the objective, ``max_rounds`` changes were made, or the program has ``max_draws`` primitives.
    Returns ``program`` itself when it is invalid or nothing helps."""
    t = _check_target(target)
    penalty = LENGTH_PENALTY[t.ndim] if penalty is None else float(penalty)
    best = _program(program, t.ndim)
    if not is_valid(best):
        return best
    pool: list[Draw] = []
    for d in donors:
        for tok in _program(d, t.ndim).draws:
            if tok not in pool:
                pool.append(tok)
    def additions(p: Program) -> list[Program]:
        if len(p.draws) >= max_draws:
            return []
        return [Program(p.tokens + (q, Op(op)), t.ndim) for q in pool for op in OPERATORS]

    return _improve(best, additions, t, penalty, max_rounds)


@lru_cache(maxsize=2)
def _vocabulary_canvases(dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Every vocabulary primitive's token index and packed canvas ``(P, words) uint64`` (drawn once per
    process: 3D, 6,631 primitives of 32 KiB)."""
    vocab = vocabulary(dim)
    kinds, params = vocab.table()
    ids = np.array([i for i, d in enumerate(vocab._draws) if isinstance(d, Draw)], dtype=np.int64)
    words = draw_packed(torch.from_numpy(kinds[ids]), torch.from_numpy(params[ids]), dim)
    return ids, words.reshape(len(ids), -1).numpy().view(np.uint64)


def extend(program: Program | str, target, penalty: float | None = None, max_rounds: int = MAX_EXTEND_ROUNDS,
           chunk: int = 512) -> Program:
    """Add primitives of the whole vocabulary while that raises :func:`objective`: each round scores the
    program followed by every primitive of the vocabulary and each operator (``P q +``, ``P q *``,
    ``P q -``; 3 x 6,631 programs in 3D, 3 x 396 in 2D, scored with bit operations on packed canvases,
    not rendered one by one) and keeps the best change; it stops when no change raises the objective,
    after ``max_rounds`` changes, or at ``MAX_GRAFT_DRAWS`` primitives. Returns ``program`` itself when
    it is invalid or nothing helps."""
    t = _check_target(target)
    dim = t.ndim
    penalty = LENGTH_PENALTY[dim] if penalty is None else float(penalty)
    best = _program(program, dim)
    if not is_valid(best):
        return best
    vocab = vocabulary(dim)
    ids, prims = _vocabulary_canvases(dim)
    tgt = pack(torch.from_numpy(t)).numpy().view(np.uint64).reshape(-1)
    plus = 1.0 if dim == 3 else 0.0  # the 3D IoU is |A∧B| / (|A∨B| + 1)
    best_score = objective(_scores([best], t)[0], best, penalty)
    for _ in range(int(max_rounds)):
        if len(best.draws) >= MAX_GRAFT_DRAWS:
            break
        cur = pack(torch.from_numpy(render(best, dim)[0])).numpy().view(np.uint64).reshape(-1)
        top = (best_score, None, None)
        for lo in range(0, len(ids), chunk):
            q = prims[lo: lo + chunk]
            for op, res in (("+", cur | q), ("*", cur & q), ("-", cur & ~q)):
                inter = np.bitwise_count(res & tgt).sum(1, dtype=np.int64)
                union = np.bitwise_count(res | tgt).sum(1, dtype=np.int64)
                iou = np.where(union + plus > 0, inter / np.maximum(union + plus, 1e-12), 0.0)
                j = int(np.argmax(iou))
                score = float(iou[j]) - penalty * (len(best.draws) + 1)
                if score > top[0]:
                    top = (score, int(ids[lo + j]), op)
        if top[1] is None:
            break
        best = Program(best.tokens + (vocab._draws[top[1]], Op(top[2])), dim)
        best_score = objective(_scores([best], t)[0], best, penalty)
    return best
