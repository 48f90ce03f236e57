"""Short programs: pruning the parts of a program that do not pay for their length, and choosing among
candidates by IoU minus a price per primitive.

A decoded or refined program may carry primitives that change little of its shape (a small circle
subtracted where there is nothing, a union with a sliver). :func:`prune` removes them: at every
operator it tries keeping only the left or only the right operand, and takes the change that raises
``IoU - penalty * primitives`` most, until no change raises it. :func:`choose` picks, among
candidate programs, the one with the highest ``IoU - penalty * primitives`` (ties: the earlier).

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

from typing import Sequence

from .lang import Draw, Program, is_valid, parse

__all__ = ["LENGTH_PENALTY", "MAX_PRUNE_ROUNDS", "MAX_VAL_IOU_COST", "objective", "removals", "prune", "choose"]

LENGTH_PENALTY = {2: 0.025, 3: 0.005}
"""IoU given up per primitive saved (by dimension), chosen on the validation split (module docstring)."""
MAX_VAL_IOU_COST = 0.005
"""The mean IoU the chosen price may cost on the validation split, against choosing by IoU alone."""
MAX_PRUNE_ROUNDS = 16
"""Removals :func:`prune` makes at most (each removes at least one primitive, so 16 covers the
longest decoded programs, 7 primitives in 2D and 4 in 3D, with room to spare)."""


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
    from .refinement import program_scores

    return [iou for iou, _ in program_scores(programs, target)]


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
    from .refinement import _check_target

    t = _check_target(target)
    penalty = LENGTH_PENALTY[t.ndim] if penalty is None else float(penalty)
    best = _program(program, t.ndim)
    if not is_valid(best):
        return best
    best_score = objective(_scores([best], t)[0], best, penalty)
    for _ in range(int(max_rounds)):
        cands = removals(best)
        if not cands:
            break
        scored = [objective(s, c, penalty) for s, c in zip(_scores(cands, t), cands)]
        i = max(range(len(cands)), key=lambda j: (scored[j], -j))
        if scored[i] <= best_score:
            break
        best, best_score = cands[i], scored[i]
    return best


def choose(programs: Sequence[Program | str], target, penalty: float | None = None) -> tuple[int, list[float]]:
    """The index of the program with the highest :func:`objective` (the earliest on ties), and every
    program's IoU. Invalid programs render empty."""
    from .refinement import _check_target

    t = _check_target(target)
    penalty = LENGTH_PENALTY[t.ndim] if penalty is None else float(penalty)
    progs = [_program(p, t.ndim) for p in programs]
    if not progs:
        raise ValueError("choose needs at least one program")
    ious = _scores(progs, t)
    scored = [objective(s, p, penalty) for s, p in zip(ious, progs)]
    return max(range(len(progs)), key=lambda j: (scored[j], -j)), ious
