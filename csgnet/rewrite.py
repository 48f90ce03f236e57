"""Short programs: pruning the parts of a program that do not pay for their length, and choosing among
candidates by IoU minus a price per primitive.

A decoded or refined program may carry primitives that change little of its shape (a small circle
subtracted where there is nothing, a union with a sliver). :func:`prune` removes them: at every
operator it tries keeping only the left or only the right operand, and takes the change that raises
``IoU - penalty * primitives`` most, until no change raises it. :func:`graft` goes the other way: it
adds a primitive of another candidate (e.g. another beam) by union, intersection or difference where
that raises the same objective, and :func:`extend` searches the whole vocabulary for such a primitive.
:func:`fit` is not bound to the vocabulary: it fits primitives to the parts of the shape a program misses
(added by union) or covers wrongly (taken away by difference), sized from each part's bounding box, so
that parts thinner or larger than the grammar's primitives (a table's 5-voxel legs, its 56-voxel top)
can be drawn; an axis-aligned box of any size is the intersection of two squares or cubes.
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
from math import trunc
from typing import Sequence

import numpy as np
import torch
from scipy import ndimage

from . import render
from .lang import OPERATORS, Draw, Op, Program, is_valid, parse
from .renderer import draw_packed, pack
from .score import _check_target, program_scores
from .vocab import vocabulary

__all__ = ["LENGTH_PENALTY", "MAX_PRUNE_ROUNDS", "MAX_GRAFT_ROUNDS", "MAX_EXTEND_ROUNDS", "MAX_GRAFT_DRAWS",
           "MAX_FIT_ROUNDS", "MAX_FIT_DRAWS", "MAX_FIT_PARTS", "GROW_FILL", "MAX_VAL_IOU_COST", "objective", "removals",
           "prune", "graft", "extend", "part_candidates", "fit", "choose"]

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
MAX_FIT_ROUNDS = 8
"""Changes :func:`fit` makes at most (each adds one part: one primitive, or two for a box)."""
MAX_FIT_DRAWS = 16
"""The most primitives a fitted program may reach."""
MAX_FIT_PARTS = 8
"""The largest parts (connected components of what is missing and of what is wrong) :func:`fit` tries
per round."""
GROW_FILL = 0.9
"""The share of a new layer that must lie in the part for :func:`fit`'s grown box to take it."""


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


def _improve(best: Program | None, changes, target, penalty: float, max_rounds: int) -> Program | None:
    """Hill climbing on :func:`objective`: each round takes the best of ``changes(best)`` (the earliest on
    ties) if it scores higher, for at most ``max_rounds`` rounds. ``best=None`` starts from nothing
    (objective 0)."""
    best_score = 0.0 if best is None else objective(_scores([best], target)[0], best, penalty)
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


def _box(lo: np.ndarray, hi: np.ndarray, dim: int) -> list[Draw]:
    """Two squares (2D) or cubes (3D) whose intersection is the box ``[lo, hi]`` (inclusive cell
    indices, by axis: row, column[, depth]): the first square or cube shares the box's low corner, the
    second its high corner, and both reach past the other end; one when the two are the same."""
    ext = int((hi - lo).max()) + 1
    if dim == 3:
        q = ext // 2  # cu(x, y, z, r) covers x - q .. x + q with q = (r - 1) // 2; edge 2q + 1 >= ext
        a, b = (Draw("u", tuple(int(v) for v in c) + (2 * q + 1,)) for c in (lo + q, hi - q))
        return [a] if a == b else [a, b]  # a cube of odd edge is one cube
    # s(x, y, r) covers rows trunc(y -+ r * 1.412 / 2) (x: columns): the smallest r whose integer centres
    # put one square's low edges and the other's high edges on the box's
    for r in range(int(np.ceil(ext / 1.412)), int(np.ceil(ext / 1.412)) + 8):
        half = r * 1.412 / 2
        if trunc(half) * 2 + 1 < ext:
            continue
        a = [next((c for c in range(int(v + half) - 2, int(v + half) + 3) if trunc(c - half) == v), None)
             for v in (lo[1], lo[0])]
        b = [next((c for c in range(int(v - half) - 2, int(v - half) + 3) if trunc(c + half) == v), None)
             for v in (hi[1], hi[0])]
        if None not in a + b and all(trunc(c + half) >= h for c, h in zip(a, (hi[1], hi[0]))) \
                and all(trunc(c - half) <= v for c, v in zip(b, (lo[1], lo[0]))):
            first, second = Draw("s", (a[0], a[1], r)), Draw("s", (b[0], b[1], r))
            return [first] if first == second else [first, second]
    raise AssertionError(f"no square pair draws the box {lo}..{hi}")  # pragma: no cover - every box has one


def _grown_box(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box inside a part: grown from the cell deepest inside it (the largest distance to its outside),
    one face at a time, the face whose new layer is fullest first, while that layer is at least
    ``GROW_FILL`` full. Returns inclusive ``(lo, hi)`` cell indices."""
    dist = ndimage.distance_transform_edt(np.pad(mask, 1))[(slice(1, -1),) * mask.ndim]
    lo = np.array(np.unravel_index(int(np.argmax(dist)), mask.shape))
    hi = lo.copy()
    while True:
        best = (GROW_FILL, None)
        for axis in range(mask.ndim):
            for side, edge in ((0, lo[axis] - 1), (1, hi[axis] + 1)):
                if not 0 <= edge < mask.shape[axis]:
                    continue
                box = tuple(slice(edge, edge + 1) if a == axis else slice(lo[a], hi[a] + 1)
                            for a in range(mask.ndim))
                fill = float(mask[box].mean())
                if fill >= best[0]:
                    best = (fill, (axis, side, edge))
        if best[1] is None:
            return lo, hi
        axis, side, edge = best[1]
        (hi if side else lo)[axis] = edge


def part_candidates(mask: np.ndarray) -> list[list[Draw]]:
    """Primitives sized to one part (a bool image or volume holding one connected component): its
    bounding box and a box grown inside it (:func:`_grown_box`; each two squares or cubes, :func:`_box`),
    a circle or, in 3D, a cylinder (along the last axis) and a sphere, centred on the bounding box and
    sized to it. Each candidate is a list of draws whose intersection draws the part."""
    dim = mask.ndim
    idx = np.argwhere(mask)
    lo, hi = idx.min(0), idx.max(0)
    ext = hi - lo + 1
    mid = np.rint((lo + hi) / 2).astype(int)
    out = [_box(lo, hi, dim)]
    crop = tuple(slice(a, b + 1) for a, b in zip(lo, hi))
    glo, ghi = _grown_box(mask[crop])
    if not (np.array_equal(glo, 0 * glo) and np.array_equal(ghi, ext - 1)):  # not the bounding box again
        out.append(_box(glo + lo, ghi + lo, dim))
    if dim == 2:  # c(x, y, r): cells with distance < r; x along columns
        out.append([Draw("c", (int(mid[1]), int(mid[0]), max(1, int(np.ceil(ext.max() / 2)))))])
    else:  # cy(x, y, z, r, h): distance^2 <= (r - 1)^2 across, |dz| <= (h - 1) // 2; sp: distance <= r - 1
        r_across = int(np.ceil(ext[:2].max() / 2)) + 1
        out.append([Draw("y", (int(mid[0]), int(mid[1]), int(mid[2]), r_across, int(ext[2]) | 1))])
        out.append([Draw("p", tuple(int(v) for v in mid) + (int(np.ceil(ext.max() / 2)) + 1,))])
    return out


def _parts(residual: np.ndarray, limit: int, smallest: int) -> list[np.ndarray]:
    """The ``limit`` largest connected components of ``residual`` with at least ``smallest`` cells."""
    labels, n = ndimage.label(residual)
    if n == 0:
        return []
    sizes = np.bincount(labels.ravel())[1:]
    order = [i + 1 for i in np.argsort(-sizes, kind="stable")[:limit] if sizes[i] >= smallest]
    return [labels == k for k in order]


def _with_part(program: Program | None, part: list[Draw], op: str, dim: int) -> Program:
    tokens: tuple = tuple(part[:1]) + tuple(t for d in part[1:] for t in (d, Op("*")))
    if program is None:
        return Program(tokens, dim)
    return Program(program.tokens + tokens + (Op(op),), dim)


def fit(program: Program | str | None, target, penalty: float | None = None, max_rounds: int = MAX_FIT_ROUNDS,
        max_draws: int = MAX_FIT_DRAWS, max_parts: int = MAX_FIT_PARTS) -> Program | None:
    """Add parts fitted to what ``program`` gets wrong while that raises :func:`objective`.

    Each round finds the connected components of the target cells the program misses and of the cells it
    draws outside the target (the ``max_parts`` largest of each that could pay for a primitive), tries
    every :func:`part_candidates` of each, by union for a missed part and by difference for a wrong one,
    and keeps the best change; it stops when no change raises the objective, after ``max_rounds`` changes,
    or at ``max_draws`` primitives. The parts' parameters come from their bounding boxes and may lie
    outside the grammar's ranges (refinement polishes them).

    Args:
        program: a program or its text, or ``None`` to fit from nothing (the first part is the program).
        target: ``(64, 64)`` image or ``(64, 64, 64)`` volume (non-zero = on).
        penalty: IoU per primitive (default ``LENGTH_PENALTY`` of the dimension).

    Returns:
        The fitted program; ``program`` itself when it is invalid or nothing helps (``None`` when fitting
        from nothing finds no part).
    """
    t = _check_target(target).astype(bool)
    dim = t.ndim
    penalty = LENGTH_PENALTY[dim] if penalty is None else float(penalty)
    start = None if program is None else _program(program, dim)
    if start is not None and not is_valid(start):
        return start

    def changes(best: Program | None) -> list[Program]:
        drawn = np.zeros_like(t) if best is None else render(best, dim)[0].astype(bool)
        smallest = max(1, int(penalty * (drawn | t).sum()))  # a part below this cannot pay for its primitive
        cands: list[Program] = []
        for residual, op in ((t & ~drawn, "+"), (drawn & ~t, "-")):
            for part in _parts(residual, max_parts, smallest) if best is not None or op == "+" else []:
                for draws in part_candidates(part):
                    if len(draws) + (0 if best is None else len(best.draws)) <= max_draws:
                        cands.append(_with_part(best, draws, op, dim))
        return cands

    return _improve(start, changes, t, penalty, max_rounds)
