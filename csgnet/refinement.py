"""Visually guided refinement of CSG programs: Powell search over primitive parameters, 2D and 3D.

The structure of a program (its primitive types and operators, in order) stays fixed; the vector of
all primitive parameters (``(x, y, r)`` per 2D primitive, ``(x, y, z, r[, h])`` per 3D one),
concatenated in program order, is searched with ``scipy.optimize.minimize(method="Powell")`` to lower
the chamfer distance (2D) or raise the IoU (2D or 3D) between the program's rendering and a target
image or volume (the spec's section (g)). ``mode="reference"`` is the published 2D procedure,
``mode="improved"`` (default) scores every point it evaluates as exactly the program it stands for
and never returns a worse program; every distinct program is scored once, from primitives drawn by
the batched renderer. The modes, the search box, invalid programs and the speed are described in
docs/csgnet.md ("Refinement").

Example:
    >>> import csgnet
    >>> target = csgnet.render("c(32,32,16)")[0]
    >>> res = csgnet.refine("c(30,35,12)", target)
    >>> res.text, res.score
    ('c(32,32,16)', 0.0)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np
import torch
from scipy import optimize

from .lang import Draw, Program, is_valid
from .metrics import CHAMFER_PENALTY
from .primitives import MAX_PARAMS, SIZE, primitive
from .renderer import draw_packed
from .rewrite import choose, extend, fit, graft, prune
from .score import _check_program, _check_target, program_scores
from .vocab import codes

__all__ = [
    "METRICS",
    "MODES",
    "RULES",
    "MAX_IOU_DROP",
    "RefineResult",
    "Refined",
    "refine",
    "refine_beams",
    "refine_each",
    "refine_guarded",
]

METRICS = ("chamfer", "iou")
"""Objectives: the edge chamfer distance (2D only) and IoU (2D ``/|A∨B|``, 3D ``/(|A∨B| + 1)``)."""
MODES = ("improved", "reference")
"""The improved mode (2D and 3D) and the published procedure (2D only)."""

POSITION_RANGE = (8, 56)
"""Reference mode: positions searched and every value inside the objective (the grammar's positions)."""
RADIUS_RANGE = (8, 32)
"""Reference mode: the range radii are clipped to at the end (the grammar's sizes)."""
TOL = 1e-4
"""Powell's ``tol`` (the reference's value)."""
PREFETCH = 8
"""2D: a missing primitive is drawn together with its axis neighbours up to this many pixels away."""
PREFETCH_3D = 0
"""3D: the same; 0, drawing only the missing primitive, is the fastest in 3D (docs/csgnet.md)."""
RULES = ("short", "guarded", "chamfer")
"""How :func:`refine_guarded` picks between the refined and the unrefined program (docs/csgnet.md)."""
MAX_IOU_DROP = 0.05
"""The ``"guarded"`` rule keeps the unrefined program when refinement lowers IoU by more than this."""


@dataclass(frozen=True)
class RefineResult:
    """The outcome of :func:`refine`.

    Attributes:
        program: the refined program (the input itself when nothing better was found, in the
            improved mode).
        score: the metric (chamfer distance in pixels, lower is better; or IoU, higher is better:
            ``|A∧B| / |A∨B|`` in 2D, ``|A∧B| / (|A∨B| + 1)`` in 3D, as :mod:`csgnet.metrics`).
            Improved mode: the score of ``program``. Reference mode: Powell's final objective value,
            as the published code returns it.
        initial_score: the score of the input program.
        iterations: Powell iterations run.
        evaluations: objective calls.
        rendered: distinct programs rendered and scored (the objective caches the rest).
        metric: ``"chamfer"`` or ``"iou"``.
        mode: ``"improved"`` or ``"reference"``.
    """

    program: Program
    score: float
    initial_score: float
    iterations: int
    evaluations: int
    rendered: int
    metric: str
    mode: str

    @property
    def text(self) -> str:
        """The refined program's text."""
        return self.program.text()

    @property
    def improved(self) -> bool:
        """Whether ``score`` is strictly better than ``initial_score``."""
        return _better(self.score, self.initial_score, self.metric)


def _better(a: float, b: float, metric: str) -> bool:
    return a < b if metric == "chamfer" else a > b


# ---------------------------------------------------------------------------------------------
# scoring against one target


def _words(img: np.ndarray) -> np.ndarray:
    """(64, 64) bool -> (64,) int64 words (bit c of word r = pixel [r, c]), (64, 64, 64) bool ->
    (64, 64) int64 words (bit k of word [i, j] = voxel [i, j, k]), as the renderer packs."""
    return np.packbits(img, axis=-1, bitorder="little").view(np.int64)[..., 0].copy()


def _popcount(words: np.ndarray) -> int:
    """ON pixels of packed words (as unsigned: ``np.bitwise_count`` counts a signed value's magnitude)."""
    return int(np.bitwise_count(words.view(np.uint64)).sum())


def _image_u8(words: np.ndarray) -> np.ndarray:
    """(64,) int64 words -> (64, 64) uint8 0/255."""
    bits = np.unpackbits(words.view(np.uint8), bitorder="little").reshape(SIZE, SIZE)
    return bits * np.uint8(255)


class _Scorer:
    """Scores packed candidate canvases (2D) or volumes (3D) against one target and caches drawn primitives.

    The chamfer distance is the reference's (:func:`csgnet.metrics.chamfer`): the target's Canny edges
    and distance map are computed once; per candidate one ``cv2.Canny``, one distance transform and two
    gathers remain. The sums add float32 distances in float64, which is exact, so the value equals
    :func:`csgnet.metrics.chamfer` bit for bit. IoU is ``|A and B| / |A or B|`` (2D; the target is
    never empty, so it is never NaN) or ``|A and B| / (|A or B| + 1)`` (3D, :func:`csgnet.metrics.iou_3d`)
    by popcounts of the packed words; a quotient of two integers below 2^53, so equal to
    :mod:`csgnet.metrics`' float64 division bit for bit. The chamfer distance is 2D only.
    """

    def __init__(self, target: np.ndarray, metric: str):
        self.metric = metric
        self.dim = target.ndim
        self.target_words = _words(target)
        self._plus = 1 if self.dim == 3 else 0
        self.leaves: dict[tuple, np.ndarray] = {}
        if metric == "chamfer":
            img = target.astype(np.uint8) * np.uint8(255)
            count = int(target.sum())
            edges = cv2.Canny(img, 1, 3)
            self._t_idx = np.flatnonzero(edges)
            # an empty/full target or an empty edge map: every pair gets the fixed 16
            self._t_bad = count in (0, SIZE * SIZE) or len(self._t_idx) == 0
            self._t_dist = cv2.distanceTransform(255 - edges, cv2.DIST_L2, 3).ravel()
            self._t_esum = len(self._t_idx) * 255.0

    def score(self, words: np.ndarray) -> float:
        """The metric of one packed canvas (64,) or volume (64, 64) int64 against the target."""
        if self.metric == "iou":
            inter = _popcount(words & self.target_words)
            union = _popcount(words | self.target_words)
            return inter / (union + self._plus)
        count = _popcount(words)
        if self._t_bad or count in (0, SIZE * SIZE):
            return CHAMFER_PENALTY
        edges = cv2.Canny(_image_u8(words), 1, 3)
        idx = np.flatnonzero(edges)
        if len(idx) == 0:
            return CHAMFER_PENALTY
        dist = cv2.distanceTransform(255 - edges, cv2.DIST_L2, 3).ravel()
        s_pt = float(dist[self._t_idx].sum(dtype=np.float64)) * 255.0  # sum(D_pred * E_target)
        s_tp = float(self._t_dist[idx].sum(dtype=np.float64)) * 255.0  # sum(D_target * E_pred)
        return (s_pt / (self._t_esum + 1) + s_tp / (len(idx) * 255.0 + 1)) / 2.0

    def empty_score(self) -> float:
        return self.score(np.zeros_like(self.target_words))

    def draw(self, keys: list[tuple]) -> None:
        """Draw the primitives ``(kind, *params)`` not cached yet, in one batch of the renderer."""
        keys = [k for k in dict.fromkeys(keys) if k not in self.leaves]
        if not keys:
            return
        kind = codes().kind
        kinds = torch.tensor([kind[k[0]] for k in keys], dtype=torch.int64)
        params = torch.tensor([k[1:] + (0,) * (MAX_PARAMS + 1 - len(k)) for k in keys], dtype=torch.int64)
        words = draw_packed(kinds, params, self.dim).numpy()
        for k, w in zip(keys, words):
            self.leaves[k] = w


_OPS = {
    "+": np.bitwise_or,
    "*": np.bitwise_and,
    "-": lambda a, b: a & ~b,
}


class _Problem:
    """One program's refinement: its structure, the search box and the cached objective."""

    def __init__(self, program: Program, scorer: _Scorer, lo: np.ndarray, hi: np.ndarray,
                 to_int: str):
        self.program = program
        self.scorer = scorer
        self.draws = program.draws
        self.kinds = [d.kind for d in self.draws]
        self.offsets = np.cumsum([0] + [len(d.params) for d in self.draws]).tolist()  # draw i: [o_i, o_i+1)
        self.x0 = np.array([v for d in self.draws for v in d.params], dtype=np.float64)
        self.lo, self.hi = lo, hi
        self.to_int = np.rint if to_int == "round" else np.trunc
        self.cache: dict[bytes, float] = {}
        self.order: list[bytes] = []  # distinct programs in evaluation order
        self.calls = 0

    def values(self, x: np.ndarray) -> np.ndarray:
        """Search point -> the integer parameters it stands for (sum of the draws' parameters,) int64."""
        return np.clip(self.to_int(x), self.lo, self.hi).astype(np.int64)

    def leaf(self, i: int, v: np.ndarray) -> np.ndarray:
        """The packed drawing of draw ``i`` with the integer parameters ``v``."""
        key = (self.kinds[i],) + tuple(v.tolist())
        w = self.scorer.leaves.get(key)
        if w is None:
            # draw this primitive's axis neighbours in the box with it (Powell's line searches probe them)
            keys = [key]
            o, near = self.offsets[i], PREFETCH if self.scorer.dim == 2 else PREFETCH_3D
            for j in range(len(v) if near else 0):
                lo, hi = int(self.lo[o + j]), int(self.hi[o + j])
                lo, hi = max(lo, key[1 + j] - near), min(hi, key[1 + j] + near)
                for u in range(lo, hi + 1):
                    k = list(key)
                    k[1 + j] = u
                    keys.append(tuple(k))
            self.scorer.draw(keys)
            w = self.scorer.leaves[key]
        return w

    def compose(self, v: np.ndarray) -> np.ndarray:
        """The packed canvas (64,) or volume (64, 64) int64 of the program with integer parameters ``v``."""
        stack: list[np.ndarray] = []
        i, o = 0, self.offsets
        for t in self.program.tokens:
            if isinstance(t, Draw):
                stack.append(self.leaf(i, v[o[i]:o[i + 1]]))
                i += 1
            else:
                b = stack.pop()
                stack.append(_OPS[t.op](stack.pop(), b))
        return stack[0]

    def score_values(self, v: np.ndarray) -> float:
        key = v.tobytes()
        s = self.cache.get(key)
        if s is None:
            s = self.scorer.score(self.compose(v))
            self.cache[key] = s
            self.order.append(key)
        return s

    def objective(self, x: np.ndarray) -> float:
        """Powell's objective: the score to minimise (chamfer, or -IoU)."""
        self.calls += 1
        s = self.score_values(self.values(x))
        return s if self.scorer.metric == "chamfer" else -s

    def program_of(self, v: np.ndarray) -> Program:
        return self.program.with_params(v)


# ---------------------------------------------------------------------------------------------
# public API


def _check_args(metric: str | None, maxiter, mode: str, dim: int) -> str:
    """Check the arguments for a ``dim``-D target; returns the metric (None: chamfer in 2D, IoU in 3D)."""
    if metric is None:
        metric = "chamfer" if dim == 2 else "iou"
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if dim == 3 and metric == "chamfer":
        raise ValueError("metric 'chamfer' is defined for 2D images only; 3D refinement uses metric='iou'")
    if dim == 3 and mode == "reference":
        raise ValueError("mode 'reference' is the published 2D procedure; 3D refinement uses mode='improved'")
    if maxiter is not None and (isinstance(maxiter, bool) or not isinstance(maxiter, (int, np.integer))
                                or maxiter < 0):
        raise ValueError(f"maxiter must be a non-negative integer or None (run to convergence), got {maxiter!r}")
    return metric


def _box(program: Program, mode: str, bounds) -> tuple[np.ndarray, np.ndarray]:
    """The search box ``(lo, hi)``, one int64 bound pair per parameter in program order.

    Improved mode: per parameter the grammar range of its table row (positions 8..56, sizes 8..32), or
    ``bounds = ((pos_lo, pos_hi), (size_lo, size_hi))`` by the parameter's kind, widened to contain the
    input's value. Reference mode (2D): [8, 56] for every parameter.
    """
    x0 = np.array([v for d in program.draws for v in d.params], np.int64)
    if mode == "reference":
        return np.full(len(x0), POSITION_RANGE[0], np.int64), np.full(len(x0), POSITION_RANGE[1], np.int64)
    if bounds is not None:
        for name, (a, b) in zip(("position", "size"), bounds):
            if int(a) != a or int(b) != b or a > b:
                raise ValueError(f"{name} bounds must be integers (lo, hi) with lo <= hi, got {(a, b)}")
    lo, hi = [], []
    for d in program.draws:
        row = primitive(d.kind)
        for name, grammar in zip(row.params, row.ranges):
            if bounds is None:
                a, b = min(grammar), max(grammar)
            else:
                a, b = bounds[1] if name in row.sizes else bounds[0]
            lo.append(a)
            hi.append(b)
    return np.minimum(np.array(lo, np.int64), x0), np.maximum(np.array(hi, np.int64), x0)  # input inside


def _run(program: Program, scorer: _Scorer, metric: str, maxiter, mode: str, bounds) -> RefineResult:
    if not is_valid(program):
        s = scorer.empty_score()
        return RefineResult(program, s, s, 0, 0, 0, metric, mode)
    lo, hi = _box(program, mode, bounds)
    prob = _Problem(program, scorer, lo, hi, "round" if mode == "improved" else "trunc")
    x0_int = prob.x0.astype(np.int64)
    # The input's own score. In the improved mode its cell is the start point (cached for the search);
    # in the reference mode the start point is the input clipped to [8, 56], which may differ.
    initial = prob.score_values(x0_int) if mode == "improved" else scorer.score(prob.compose(x0_int))
    if maxiter == 0:
        return RefineResult(program, initial, initial, 0, 0, len(prob.cache), metric, mode)

    res = optimize.minimize(prob.objective, prob.x0, method="Powell", tol=TOL, options={"maxiter": maxiter})
    iterations, calls = int(res.nit), prob.calls
    if mode == "reference":
        v = np.trunc(res.x).astype(np.int64)
        v[2::3] = np.clip(v[2::3], *RADIUS_RANGE)
        v = np.clip(v, *POSITION_RANGE)
        fun = float(res.fun)
        score = fun if metric == "chamfer" else -fun
        return RefineResult(prob.program_of(v), score, initial, iterations, calls, len(prob.cache), metric, mode)
    # improved: the best distinct program evaluated (the first one reached on ties)
    best_key, best = None, initial
    for key in prob.order:
        s = prob.cache[key]
        if _better(s, best, metric):
            best_key, best = key, s
    if best_key is None:
        return RefineResult(program, initial, initial, iterations, calls, len(prob.cache), metric, mode)
    v = np.frombuffer(best_key, dtype=np.int64)
    return RefineResult(prob.program_of(v), best, initial, iterations, calls, len(prob.cache), metric, mode)


def refine(program: Program | str, target, metric: str | None = None, maxiter: int | None = None,
           mode: str = "improved", bounds=None) -> RefineResult:
    """Refine the primitive parameters of a 2D or 3D program toward a target (structure fixed).

    Args:
        program: a :class:`~csgnet.lang.Program` of the target's dimension or its text (parsed
            leniently: a structurally invalid program is returned unchanged with the score of an
            empty canvas; malformed text raises :class:`~csgnet.lang.ParseError`).
        target: (64, 64) image or (64, 64, 64) volume, NumPy or torch (non-zero = on); must not be
            empty.
        metric: ``"chamfer"`` (2D: the reference's edge chamfer distance, minimised) or ``"iou"``
            (maximised: ``|A and B| / |A or B|`` in 2D, ``|A and B| / (|A or B| + 1)`` in 3D);
            None (default): chamfer in 2D, IoU in 3D.
        maxiter: Powell iterations: 0 (no refinement), 1, 2, ..., or None (to convergence).
        mode: ``"improved"`` (default) or ``"reference"`` (the published 2D procedure); see the
            module docstring.
        bounds: improved mode only: ``((pos_lo, pos_hi), (size_lo, size_hi))``, the search box of
            positions and of sizes (radii, heights); default: the grammar's ``((8, 56), (8, 32))``.
            Widened per parameter to contain the input's value.

    Returns:
        A :class:`RefineResult` (``.program``, ``.text``, ``.score``, ``.initial_score``,
        ``.iterations``, ``.evaluations``).

    Raises:
        ValueError: a bad target shape, an empty target, a program of the other dimension, chamfer
            or the reference mode for a 3D target, or a bad argument.
    """
    t = _check_target(target)
    metric = _check_args(metric, maxiter, mode, t.ndim)
    return _run(_check_program(program, t.ndim), _Scorer(t, metric), metric, maxiter, mode, bounds)


def refine_beams(programs: Sequence[Program | str], target, metric: str | None = None,
                 maxiter: int | None = None, mode: str = "improved", bounds=None) -> RefineResult:
    """Refine every candidate program (e.g. a beam) toward one target and keep the best.

    The candidates share the target's preprocessing and the cache of drawn primitives. Invalid
    candidates keep the score of an empty canvas. Ties go to the earlier candidate.

    Args:
        programs: one or more programs or program texts of the target's dimension.
        target, metric, maxiter, mode, bounds: as for :func:`refine`.

    Returns:
        The :class:`RefineResult` with the best ``score`` (lowest chamfer / highest IoU).
    """
    best = None
    for r in refine_each(programs, target, metric, maxiter, mode, bounds):
        if best is None or _better(r.score, best.score, r.metric):
            best = r
    return best


def refine_each(programs: Sequence[Program | str], target, metric: str | None = None,
                maxiter: int | None = None, mode: str = "improved", bounds=None) -> list[RefineResult]:
    """:func:`refine` of every candidate program toward one target, in order (sharing the target's
    preprocessing and the cache of drawn primitives)."""
    t = _check_target(target)
    metric = _check_args(metric, maxiter, mode, t.ndim)
    progs = [_check_program(p, t.ndim) for p in programs]
    if not progs:
        raise ValueError("refine_beams needs at least one program")
    scorer = _Scorer(t, metric)
    return [_run(p, scorer, metric, maxiter, mode, bounds) for p in progs]


# ---------------------------------------------------------------------------------------------
# choosing what a parser writes


@dataclass(frozen=True)
class Refined:
    """What :func:`refine_guarded` chose.

    Attributes:
        program: the program to use: the refined one, or ``start`` when the rule kept it.
        result: the best refinement of the candidates by the refinement's metric (:func:`refine_beams`;
            chamfer in 2D, IoU in 3D).
        before: ``(iou, chamfer)`` of ``start`` against the target (chamfer NaN in 3D).
        after: ``(iou, chamfer)`` of ``program``.
        kept_start: the rule kept ``start`` (``"short"``: it scored best; ``"guarded"``: refinement cost
            too much IoU).
        rule: ``"short"``, ``"guarded"`` or ``"chamfer"``.
    """

    program: Program
    result: RefineResult
    before: tuple[float, float]
    after: tuple[float, float]
    kept_start: bool
    rule: str


def refine_guarded(start: Program | str, programs: Sequence[Program | str], target, rule: str = "short",
                   maxiter: int | None = None, max_iou_drop: float = MAX_IOU_DROP,
                   penalty: float | None = None, use_graft: bool = True, use_extend: bool = True,
                   use_fit: bool = True) -> Refined:
    """Refine candidates and decide what a parser should write.

    2D candidates are refined by chamfer (the paper's objective), 3D ones by IoU.

    Args:
        start: the program chosen before refinement (e.g. the most likely beam).
        programs: the candidates refined (e.g. every valid beam; ``start`` need not be among them).
        target: (64, 64) image or (64, 64, 64) volume (non-zero = on).
        rule: ``"short"`` (default): among ``start``, every refined candidate and each of those pruned
            (:func:`csgnet.rewrite.prune`), the one with the highest ``IoU - penalty * primitives``
            (:func:`csgnet.rewrite.choose`; ties go to ``start``, then to the refined candidates in
            order): a longer program must pay for its primitives in IoU. ``"guarded"``: the best
            refined candidate by the refinement's metric unless its IoU is more than ``max_iou_drop``
            below ``start``'s, then ``start``. ``"chamfer"``: the paper's choice, the refined candidate
            with the best score (lowest chamfer in 2D), whatever its IoU or length.
        maxiter: Powell iterations (see :func:`refine`).
        max_iou_drop: the IoU loss the ``"guarded"`` rule tolerates.
        penalty: the ``"short"`` rule's IoU per primitive (default
            :data:`csgnet.rewrite.LENGTH_PENALTY` of the dimension).
        use_graft: the ``"short"`` rule then tries adding primitives of the other candidates to its choice
            (:func:`csgnet.rewrite.graft`), refines a grafted program again and keeps it if it scores better.
        use_extend: the ``"short"`` rule also tries adding any primitive of the vocabulary
            (:func:`csgnet.rewrite.extend`; one to two seconds per 3D shape on a CPU core, and 217 MB for the
            3D primitives' canvases, drawn once per process) after grafting.
        use_fit: the ``"short"`` rule also fits primitives to the parts its choice gets wrong, and to the
            target from nothing (:func:`csgnet.rewrite.fit`; parts thinner or larger than the grammar's
            primitives), refines each fitted program again and keeps one if it scores better.

    Returns:
        A :class:`Refined` with the chosen program and both programs' IoU and chamfer.
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
    dim = _check_target(target).ndim
    start = _check_program(start, dim)
    results = refine_each(programs, target, maxiter=maxiter)
    result = results[0]
    for r in results[1:]:
        if _better(r.score, result.score, r.metric):
            result = r
    if rule == "short":
        cands: list[Program] = []
        for p in [start] + [r.program for r in results]:
            for c in (p, prune(p, target, penalty)):
                if c not in cands:
                    cands.append(c)
        chosen = cands[choose(cands, target, penalty)[0]]
        changed = []
        if use_graft or use_extend:
            grafted = graft(chosen, cands, target, penalty) if use_graft else chosen
            if use_extend:
                grafted = extend(grafted, target, penalty)
            changed.append(grafted)
        if use_fit:
            changed += [fit(chosen, target, penalty), fit(None, target, penalty)]
        more = []
        for p in changed:
            if p is not None and p != chosen and p not in more:
                polished = refine_each([p], target, maxiter=maxiter)[0].program
                more += [p, polished, prune(polished, target, penalty)]
        if more:
            chosen = ([chosen] + more)[choose([chosen] + more, target, penalty)[0]]
    elif rule == "guarded":
        before_iou = program_scores([start, result.program], target)
        chosen = start if before_iou[1][0] < before_iou[0][0] - max_iou_drop else result.program
    else:
        chosen = result.program
    before, after = program_scores([start, chosen], target)
    kept = chosen is start if rule == "guarded" else rule == "short" and chosen == start
    return Refined(chosen, result, before, after, kept, rule)
