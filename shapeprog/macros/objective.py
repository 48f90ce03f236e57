"""ShapeMOD's objective f and the best-program search P* of a sub-program under a library.

**Objective** (the spec's ``scoreProg``, the paper's weights :data:`WEIGHTS`)::

    f(p) = 1 * (#macros in L) + 8 * (#calls) + 8 * #cube + 1 * #float + 0.25 * #bool + 0.5 * #categorical
           + 10 * float_error

``#calls`` is the number of program lines after the bbox line (the spec's ``lines - 1``); the parameter
counts are the interface sizes of the called functions (a ``face`` or ``axis`` parameter is
categorical); ``float_error`` is the sum of the absolute residuals of the least-squares fits. The bbox
line is given, static information: it is neither a call nor counted in the parameters (decision: this
matches the spec's "drop the bbox line" of the proposal phase; :func:`score` can include it).

**Fits** (the spec's ``checkFit``). A function fits the base lines ``lines[pos:pos + k]`` when its
expanded structure equals their commands, its discrete slots match (literals equal, a parameter used
twice takes one value, a cuboid it creates is the cuboid declared there, a cuboid parameter names a
cuboid declared before the call or the bbox), and its float parameters, solved jointly by least squares
with the bbox dims fixed, leave every residual at most :data:`ABS_MAX_ERROR` (the reference's 0.06; the
paper says 0.05). A solved parameter that is *tied* (used in several slots or inside an expression) is
rounded to :data:`FIT_DECIMALS` decimals first (the reference's ``prec``); a parameter that is alone in
one slot keeps the line's value, so that base functions fit exactly (decision: the corpus is written
with three decimals, rounding every parameter would charge every base line an error). Floats are in the
language's units (a translate count is the count, not the reference's ``n / 10``).

**Search.** Given the fit options at every position (:func:`fit_options`), :func:`beam_search` covers the
lines left to right keeping the :data:`BEAM` best partial programs ranked by ``f(partial) / lines
covered`` (the reference's ``getApproxBestOps``); :func:`exact_search` is the optimum by dynamic
programming (f is a sum over calls). :func:`best_program` takes the best over a sub-program's orderings.

Example:
    >>> from shapeprog.macros.grammar import CuboidLine, AttachLine
    >>> from shapeprog.macros.library import Library
    >>> lines = (CuboidLine(1.0, 1.0, 1.0, True), CuboidLine(0.5, 0.2, 0.5, True),
    ...          AttachLine(-1, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5))
    >>> r = best_program([lines], Library())
    >>> r.f, [o.func for o in r.calls]  # 2 calls: 16 + Cuboid (3 floats, 1 bool) + attach (1 cube, 6 floats)
    (33.25, ['Cuboid', 'attach'])
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from .grammar import BBOX, AttachLine, CuboidLine, Line, ReflectLine, SqueezeLine, command
from .lang import AXIS, BB_DIMS, BOOL, CUBE, FACE, FLOAT, Call, Linear, Literal, MacroProgram, Name, BASE
from .library import Library

__all__ = [
    "ABS_MAX_ERROR",
    "BEAM",
    "FIT_DECIMALS",
    "WEIGHTS",
    "Option",
    "Result",
    "Template",
    "beam_search",
    "best_program",
    "call_cost",
    "exact_search",
    "fit",
    "fit_options",
    "interface_cost",
    "score",
    "template",
    "templates",
    "to_program",
]

#: The paper's weights: macros in L, calls (lines - 1), cuboid ids, floats, categoricals, booleans, error.
WEIGHTS = {"n": 1.0, "fn": 8.0, "cid": 8.0, "f": 1.0, "d": 0.5, "b": 0.25, "err": 10.0}
#: Largest absolute residual of an accepted fit (the reference's ``abs_max_error``; the paper: 0.05).
ABS_MAX_ERROR = 0.06
#: Decimals of tied solved parameters (the reference's ``prec``).
FIT_DECIMALS = 2
#: Partial programs kept by the beam search (``abs_beam_size``).
BEAM = 10

_TYPE_WEIGHT = {CUBE: "cid", FLOAT: "f", FACE: "d", AXIS: "d", BOOL: "b"}


def interface_cost(params, weights: Mapping[str, float] = WEIGHTS) -> float:
    """``8 * #cube + #float + 0.5 * #categorical + 0.25 * #bool`` of a parameter list."""
    return sum(weights[_TYPE_WEIGHT[p.type]] for p in params)


def call_cost(params, weights: Mapping[str, float] = WEIGHTS) -> float:
    """One call's share of f without its error: ``8`` for the line plus :func:`interface_cost`."""
    return weights["fn"] + interface_cost(params, weights)


# ----------------------------------------------------------------------------- templates


@dataclass(frozen=True)
class Template:
    """A function expanded to base lines, in the form the fits need.

    Attributes:
        name: the function's name.
        structure: its base commands.
        params: its typed parameters.
        floats: per base line, per float slot ``(coefficients over the float parameters, bb coefficients,
            constant)``.
        cubes: per base line, per cuboid slot ``('bbox',)``, ``('p', param index)`` or ``('r', m)`` (the m-th
            cuboid the function creates).
        cats: per base line, per face/axis/bool slot ``('lit', value)`` or ``('p', param index)``.
        float_index: parameter index of each float unknown (the columns of the coefficients).
        tied: per float unknown, whether it is rounded (used in several slots or in an expression).
        cost: :func:`call_cost` of the function.
    """

    name: str
    structure: tuple[str, ...]
    params: tuple
    floats: tuple
    cubes: tuple
    cats: tuple
    float_index: tuple[int, ...]
    tied: tuple[bool, ...]
    cost: float
    matrix: np.ndarray  # (slots, unknowns) stacked float coefficients
    bbmat: np.ndarray  # (slots, 3)
    const: np.ndarray  # (slots,)


def template(library: Library, name: str, weights: Mapping[str, float] = WEIGHTS) -> Template:
    """The :class:`Template` of ``library[name]``."""
    defn = library.expand_macro(name)
    params = defn.params
    fidx = [i for i, p in enumerate(params) if p.type == FLOAT]
    col = {params[i].name: j for j, i in enumerate(fidx)}
    pidx = {p.name: i for i, p in enumerate(params)}
    rets: dict[str, int] = {}
    floats, cubes, cats, rows, bbs, consts = [], [], [], [], [], []
    uses = [0] * len(fidx)
    plain = [True] * len(fidx)
    for call in defn.body:
        info = BASE[call.func]
        fl, cu, ca = [], [], []
        for a, p in zip(call.args, info.params):
            if p.type == FLOAT:
                vec = np.zeros(len(fidx))
                bb = np.zeros(3)
                c0 = 0.0
                for c, v in a.terms:
                    if v is None:
                        c0 += c
                    elif v in BB_DIMS:
                        bb[BB_DIMS.index(v)] += c
                    else:
                        vec[col[v]] += c
                nz = [j for j in range(len(fidx)) if vec[j] != 0.0]
                for j in nz:
                    uses[j] += 1
                    if len(nz) > 1 or vec[j] != 1.0 or c0 != 0.0 or bb.any():
                        plain[j] = False
                fl.append((vec, bb, c0))
                rows.append(vec)
                bbs.append(bb)
                consts.append(c0)
            elif p.type == CUBE:
                n = a.name
                cu.append(("bbox",) if n == "bbox" else ("r", rets[n]) if n in rets else ("p", pidx[n]))
            else:
                ca.append(("lit", a.value) if isinstance(a, Literal) else ("p", pidx[a.name]))
        for r in call.rets:
            rets[r] = len(rets)
        floats.append(tuple(fl))
        cubes.append(tuple(cu))
        cats.append(tuple(ca))
    tied = tuple(not (u == 1 and pl) for u, pl in zip(uses, plain))
    m = np.array(rows, dtype=float).reshape(len(rows), len(fidx))
    return Template(name, library[name].structure, params, tuple(floats), tuple(cubes), tuple(cats), tuple(fidx),
                    tied, call_cost(params, weights), m, np.array(bbs, dtype=float).reshape(len(rows), 3),
                    np.array(consts, dtype=float))


def templates(library: Library, weights: Mapping[str, float] = WEIGHTS) -> list[Template]:
    """Templates of every function of ``library`` (base functions first)."""
    return [template(library, n, weights) for n in library]


# ----------------------------------------------------------------------------- fits


def _observed(ln: Line):
    """(floats, cube ids, categoricals) of a base line, in slot order."""
    t = type(ln)
    if t is CuboidLine:
        return (ln.l, ln.h, ln.w), (), (bool(ln.aligned),)
    if t is AttachLine:
        return (ln.x1, ln.y1, ln.z1, ln.x2, ln.y2, ln.z2), (ln.target,), ()
    if t is SqueezeLine:
        return (ln.u, ln.v), (ln.t1, ln.t2), (ln.face,)
    if t is ReflectLine:
        return (), (), (ln.axis,)
    return (float(ln.n), ln.d), (), (ln.axis,)


@dataclass(frozen=True)
class Option:
    """A function fitted at a position: the call covers ``lines[pos:pos + k]``.

    Attributes:
        func: the function's name.
        pos: first line covered; k: lines covered.
        cost: :func:`call_cost` (without the error); error: the sum of absolute residuals.
        args: the call's arguments: floats, canonical cuboid ids (``-1`` the bbox) and literals, in
            parameter order.
    """

    func: str
    pos: int
    k: int
    cost: float
    error: float
    args: tuple


def fit(tpl: Template, lines: Sequence[Line], pos: int, cube_start: int, max_error: float = ABS_MAX_ERROR,
        decimals: int | None = FIT_DECIMALS) -> Option | None:
    """Fit ``tpl`` to ``lines[pos:pos + len(tpl.structure)]``; None if it does not fit.

    Args:
        tpl: the function's template.
        lines: a sub-program's base lines (bbox first).
        pos: the first line to cover (>= 1).
        cube_start: canonical id of the first cuboid the call would create (the Cuboid lines in
            ``lines[1:pos]``).
        max_error: largest accepted absolute residual.
        decimals: rounding of tied parameters (None: none).
    """
    k = len(tpl.structure)
    window = lines[pos:pos + k]
    if len(window) < k or tuple(command(x) for x in window) != tpl.structure:
        return None
    values: list = [None] * len(tpl.params)
    ys = []
    for ln, cubes, cats in zip(window, tpl.cubes, tpl.cats):
        fl, ids, cs = _observed(ln)
        ys.extend(fl)
        for slot, obs in zip(cubes, ids):
            if slot[0] == "bbox":
                if obs != BBOX:
                    return None
            elif slot[0] == "r":
                if obs != cube_start + slot[1]:
                    return None
            else:
                if obs != BBOX and obs >= cube_start:
                    return None  # a parameter names a cuboid declared before the call
                prev = values[slot[1]]
                if prev is None:
                    values[slot[1]] = obs
                elif prev != obs:
                    return None
        for slot, obs in zip(cats, cs):
            if slot[0] == "lit":
                if slot[1] != obs:
                    return None
            else:
                prev = values[slot[1]]
                if prev is None:
                    values[slot[1]] = obs
                elif prev != obs:
                    return None
    bb = lines[0]
    y = np.asarray(ys, dtype=float) - tpl.const - tpl.bbmat @ np.array((bb.l, bb.h, bb.w))
    n = len(tpl.float_index)
    if n:
        a = tpl.matrix
        x = np.linalg.lstsq(a, y, rcond=None)[0] if a.shape[0] else np.zeros(n)
        if decimals is not None:
            for j in range(n):
                if tpl.tied[j]:
                    x[j] = round(float(x[j]), decimals)
        res = y - a @ x
    else:
        x = np.zeros(0)
        res = y
    res = np.abs(res)
    if res.size and float(res.max()) > max_error:
        return None
    for j, i in enumerate(tpl.float_index):
        values[i] = float(x[j])
    return Option(tpl.name, pos, k, tpl.cost, float(res.sum()) if res.size else 0.0, tuple(values))


def fit_options(lines: Sequence[Line], tpls: Sequence[Template], max_error: float = ABS_MAX_ERROR,
                decimals: int | None = FIT_DECIMALS) -> list[list[Option]]:
    """Per position ``pos`` of ``lines`` (index 0, the bbox, gets no options), every fitting function."""
    by_first: dict[str, list[Template]] = {}
    for t in tpls:
        by_first.setdefault(t.structure[0], []).append(t)
    out: list[list[Option]] = [[]]
    cubes = 0
    for pos in range(1, len(lines)):
        opts = []
        for t in by_first.get(command(lines[pos]), ()):
            o = fit(t, lines, pos, cubes, max_error, decimals)
            if o is not None:
                opts.append(o)
        out.append(opts)
        if type(lines[pos]) is CuboidLine:
            cubes += 1
    return out


# ----------------------------------------------------------------------------- search


@dataclass(frozen=True)
class Result:
    """A best program: its calls (after the bbox line), f, and the ordering it came from."""

    calls: tuple[Option, ...]
    f: float
    order: int = 0

    @property
    def error(self) -> float:
        return sum(o.error for o in self.calls)


def _option_f(o: Option, weights) -> float:
    return o.cost + weights["err"] * o.error


def beam_search(options: Sequence[Sequence[Option]], n_macros: int = 0, beam: int = BEAM,
                weights: Mapping[str, float] = WEIGHTS) -> tuple[tuple[Option, ...], float]:
    """The reference's approximate best cover of positions ``1 .. len(options) - 1``.

    A frontier of partial programs is expanded by every option at its next position; the ``beam`` best
    children by ``f(partial) / lines covered`` form the next frontier; completed programs are scored by f
    (ties: the first found). Returns (calls, f) or ((), inf) if no cover exists.
    """
    n = len(options)
    base = weights["n"] * n_macros
    if n <= 1:
        return (), base
    frontier = [(0.0, 1, ())]
    best, best_f = (), math.inf
    while frontier:
        children = []
        for g, pos, calls in frontier:
            for o in options[pos]:
                g2 = g + _option_f(o, weights)
                c2 = calls + (o,)
                end = pos + o.k
                if end >= n:
                    if g2 + base < best_f:
                        best, best_f = c2, g2 + base
                else:
                    children.append(((g2 + base) / (end - 1), g2, end, c2))
        children.sort(key=lambda c: c[0])
        frontier = [(g, e, c) for _, g, e, c in children[:beam]]
    return best, best_f


def exact_search(options: Sequence[Sequence[Option]], n_macros: int = 0,
                 weights: Mapping[str, float] = WEIGHTS) -> tuple[tuple[Option, ...], float]:
    """The optimal cover (f is a sum over calls): dynamic programming over positions."""
    n = len(options)
    best: list = [(math.inf, None)] * (n + 1)
    best[1] = (0.0, None)
    for pos in range(1, n):
        g = best[pos][0]
        if g == math.inf:
            continue
        for o in options[pos]:
            g2 = g + _option_f(o, weights)
            if g2 < best[pos + o.k][0]:
                best[pos + o.k] = (g2, o)
    if n <= 1:
        return (), weights["n"] * n_macros
    if best[n][0] == math.inf:
        return (), math.inf
    calls = []
    pos = n
    while pos > 1:
        o = best[pos][1]
        calls.append(o)
        pos = o.pos
    return tuple(reversed(calls)), best[n][0] + weights["n"] * n_macros


def best_program(orders: Sequence[Sequence[Line]], library: Library, tpls: Sequence[Template] | None = None,
                 mode: str = "beam", beam: int = BEAM, weights: Mapping[str, float] = WEIGHTS,
                 max_error: float = ABS_MAX_ERROR, decimals: int | None = FIT_DECIMALS) -> Result:
    """P*: the best program over a sub-program's orderings (each a line sequence, bbox first).

    Args:
        orders: the orderings' lines.
        library: the library (its macro count enters f).
        tpls: precomputed :func:`templates` of ``library``.
        mode: ``'beam'`` (the reference's search) or ``'exact'``.
    """
    tpls = templates(library, weights) if tpls is None else tpls
    nm = len(library.macros)
    best = Result((), math.inf, 0)
    for i, lines in enumerate(orders):
        opts = fit_options(lines, tpls, max_error, decimals)
        calls, f = (beam_search(opts, nm, beam, weights) if mode == "beam" else exact_search(opts, nm, weights))
        if f < best.f:
            best = Result(calls, f, i)
    return best


def score(calls: Sequence[Option], n_macros: int, weights: Mapping[str, float] = WEIGHTS,
          bbox_params: bool = False) -> float:
    """f of a program given as its calls (``bbox_params``: also count the bbox line's 3 floats and bool)."""
    f = weights["n"] * n_macros + sum(_option_f(o, weights) for o in calls)
    return f + (3 * weights["f"] + weights["b"] if bbox_params else 0.0)


def to_program(lines: Sequence[Line], calls: Sequence[Option], library: Library) -> MacroProgram:
    """The macro program of a best program: the bbox line of ``lines``, then one line per call (cuboids
    named ``cube0``, ``cube1``, ... by canonical id)."""
    bb = lines[0]
    out = [Call("Cuboid", (Linear.const(bb.l), Linear.const(bb.h), Linear.const(bb.w), Literal(bool(bb.aligned))),
                ("bbox",))]
    ncube = 0
    for o in calls:
        f = library[o.func]
        args = []
        for p, v in zip(f.params, o.args):
            if p.type == FLOAT:
                args.append(Linear.const(round(float(v), 10)))
            elif p.type == CUBE:
                args.append(Name("bbox" if v == BBOX else f"cube{v}"))
            else:
                args.append(Literal(v))
        rets = tuple(f"cube{ncube + j}" for j in range(f.n_cuboids))
        ncube += f.n_cuboids
        out.append(Call(o.func, tuple(args), rets))
    return MacroProgram((), tuple(out))
