"""Abstraction proposal: structure signatures of program pieces, clusters of their instances, and greedy
token-by-token abstraction of a cluster (the paper's Section 5.3 / the reference's ``proposal.py``).
NumPy and the standard library.

* :func:`pieces` splits a program on its top-level ``Union`` s; each piece, and each pair of pieces
  (as ``Union(a, b)``, the pair ordered by signature), is one *instance*.
* :func:`structure` replaces every Float slot of a shape function by ``P_F_i_`` and every categorical
  slot by ``P_C_i_``: the template text is the *structure signature*; the slot values come with it.
* :func:`collect` gathers the instances of all programs by signature; :func:`eligible` keeps those in at
  least :data:`MIN_SIG_FREQ` of the programs with at most :data:`MAX_SLOTS` slots.
* :func:`propose` samples a structure (weight: frequency × (Unions + 1)), a cluster of its instances
  (size uniform in min(8, n)..min(16, n); a random seed, the others sampled without replacement with
  probability softmax(1 / distance)), and builds a :class:`Candidate` slot by slot (:func:`abstract`).

Example:
    >>> from shapeprog.coder.lang import parse, to_text
    >>> t, vals, _ = structure(parse("SymRef(Move(Cuboid(0.1,0.5,0.1),-0.4,0.2,0.0),AX)"))
    >>> to_text(t), vals
    ('SymRef(Move(Cuboid(P_F_0_,P_F_1_,P_F_2_),P_F_3_,P_F_4_,P_F_5_),P_C_6_)', (0.1, 0.5, 0.1, -0.4, 0.2, 0.0, 'AX'))
"""
from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .lang import (Abstraction, AxisConst, Call, Expr, IntConst, Library, Num, Param, ProgramError, Type, Var, _library,
                   substitute, to_text, walk)
from .objective import preference

__all__ = ["CAND_TOL", "Candidate", "MAX_SLOTS", "MIN_SIG_FREQ", "abstract", "collect", "eligible", "pieces", "propose",
           "structure", "value"]

#: A float slot matches a candidate expression within this (``ab_cand_max_error``, 3D; 2D 0.03).
CAND_TOL = {"3d": 0.05, "2d": 0.03}
#: A structure must occur in this share of the programs (``abc_min_sig_perc``).
MIN_SIG_FREQ = 0.05
#: A structure may have at most this many slots.
MAX_SLOTS = 12
#: An expression option must cover at least this many cluster members.
MIN_COVER = 4
_ZERO_TOL = 0.01


def value(e: Expr) -> float:
    """The value of a closed float expression (literals and float operators)."""
    if isinstance(e, Num):
        return e.value
    if isinstance(e, Call):
        a = [value(x) for x in e.args]
        if e.fn == "Add":
            return a[0] + a[1]
        if e.fn == "Sub":
            return a[0] - a[1]
        if e.fn == "Mul":
            return a[0] * a[1]
        if e.fn == "Div":
            return a[0] / a[1] if a[1] != 0 else 0.0
        if e.fn == "Inv":
            return -a[0]
    raise ProgramError(f"not a closed float expression: {e!r}")


def pieces(expr: Expr) -> list:
    """The operands of the top-level ``Union`` chain of ``expr`` (``[expr]`` when it is no Union)."""
    out, stack = [], [expr]
    while stack:
        e = stack.pop()
        if isinstance(e, Call) and e.fn == "Union":
            stack.extend(reversed(e.args))
        else:
            out.append(e)
    return out


def structure(expr: Expr, library: Library | None = None) -> tuple:
    """The template of a piece: ``(template, values, types)``; Float slots become ``P_F_i_`` (value: the
    slot's float expression evaluated), Axis and Int slots ``P_C_i_`` (value ``'AX'`` or the count)."""
    lib = _library(library)
    vals, types = [], []

    def go(e):
        sig = lib.signature(e.fn)
        args = []
        for a, t in zip(e.args, sig.params):
            if t is Type.SHAPE:
                args.append(go(a))
                continue
            i = len(vals)
            if t is Type.FLOAT:
                vals.append(round(value(a), 6))
                args.append(Var(f"P_F_{i}_"))
            else:
                vals.append(a.name if isinstance(a, AxisConst) else a.value)
                args.append(Var(f"P_C_{i}_", t))
            types.append(t)
        return Call(e.fn, tuple(args))

    return go(expr), tuple(vals), tuple(types)


@dataclass
class Structure:
    """All instances of one structure signature: the template, slot types, and per instance the program
    index and the slot values."""

    template: Expr
    types: tuple
    programs: list = field(default_factory=list)
    values: list = field(default_factory=list)

    @property
    def unions(self) -> int:
        return sum(1 for n in walk(self.template) if isinstance(n, Call) and n.fn == "Union")


def collect(programs: Sequence[Expr], library: Library | None = None, pairs: bool = True) -> dict:
    """``{signature text: Structure}`` of every piece (and pair of pieces) of every program."""
    out: dict = {}
    for k, prog in enumerate(programs):
        ps = pieces(prog)
        keyed = sorted(((to_text(structure(p, library)[0]), i, p) for i, p in enumerate(ps)), key=lambda x: (x[0], x[1]))
        insts = [p for _, _, p in keyed]
        if pairs:
            insts += [Call("Union", (keyed[i][2], keyed[j][2])) for i in range(len(keyed)) for j in range(i + 1, len(keyed))]
        for inst in insts:
            t, vals, types = structure(inst, library)
            s = out.setdefault(to_text(t), Structure(t, types))
            s.programs.append(k)
            s.values.append(vals)
    return out


def eligible(structs: dict, n_programs: int, min_freq: float = MIN_SIG_FREQ, max_slots: int = MAX_SLOTS) -> list:
    """``[(signature, Structure, weight)]`` of the structures in at least ``min_freq`` of the programs with
    at most ``max_slots`` slots; weight = frequency × (Unions + 1)."""
    out = []
    for sig, s in structs.items():
        freq = len(set(s.programs)) / n_programs
        if freq >= min_freq and 0 < len(s.types) <= max_slots and len(s.programs) >= 2:
            out.append((sig, s, freq * (s.unions + 1)))
    return out


@dataclass(frozen=True)
class Candidate:
    """A proposed abstraction with the programs whose instances it covers.

    Attributes:
        body: the abstraction body (parameters ``F0``, ``F1``, ... and ``C0``, ...).
        params: its parameters (:class:`~shapeprog.coder.lang.Param`).
        gain: the cost of the structure's tokens minus the cost of a call (1 + 2 per float parameter +
            0.5 per categorical one).
        programs: indices of the programs with a covered instance.
    """

    body: Expr
    params: tuple
    gain: float
    programs: frozenset

    def abstraction(self, name: str) -> Abstraction:
        return Abstraction(name, self.params, self.body)


def _options(col: np.ndarray, floats: list, tol: float):
    """Float options for one slot: ``(expr, matches (m,) bool, new_var)``; floats are earlier variables
    ``[(name, (m,) values)]``."""
    opts = []
    for name, v in floats:
        opts.append((Var(name), np.abs(col - v) <= tol))
    opts.append((Num(0.0), np.abs(col) <= _ZERO_TOL))
    for name, v in floats:
        opts.append((Call("Inv", (Var(name),)), np.abs(col + v) <= tol))
    operands = [(Var(n), v) for n, v in floats] + [(Num(1.0), 1.0), (Num(2.0), 2.0)]
    for i, (ea, va) in enumerate(operands):
        for j, (eb, vb) in enumerate(operands):
            if i == j or (isinstance(ea, Num) and isinstance(eb, Num)):
                continue
            for op in ("Add", "Sub", "Mul", "Div"):
                if op in ("Add", "Mul") and j < i:
                    continue  # commutative: one order
                consts = [e.value for e in (ea, eb) if isinstance(e, Num)]
                if op in ("Add", "Sub") and any(c in (0.0, 2.0) for c in consts):
                    continue
                if op in ("Mul", "Div") and any(c in (0.0, 1.0) for c in consts):
                    continue
                with np.errstate(divide="ignore", invalid="ignore"):
                    got = {"Add": va + vb, "Sub": va - vb, "Mul": va * vb,
                           "Div": va / vb if not np.isscalar(vb) or vb != 0 else np.full_like(col, np.inf)}[op]
                got = np.where(np.isfinite(got), got, np.inf)
                opts.append((Call(op, (ea, eb)), np.abs(col - got) <= tol))
    return opts


def abstract(s: Structure, members: Sequence[int], library: Library | None = None) -> Candidate | None:
    """Greedy token-by-token abstraction of a cluster (indices into ``s.values``): each slot takes, among
    a new variable, a re-used variable, the constant 0, ``Inv`` of a variable and one binary operator over
    the variables and the constants 1, 2 (most-frequent constant or re-used variable for categorical
    slots), the option maximising (old cost of the prefix − new cost) × covered share; an expression
    must cover at least :data:`MIN_COVER` members (or all of a smaller cluster)."""
    lib = _library(library)
    tol = CAND_TOL[lib.lang.name]
    rows = [s.values[i] for i in members]
    m = len(rows)
    min_cover = min(MIN_COVER, m)
    covered = np.ones(m, dtype=bool)
    floats: list = []  # (name, values)
    cats: list = []  # (name, values list)
    fill: dict = {}
    old = float(sum(1 for n in walk(s.template) if isinstance(n, Call)))
    for i, t in enumerate(s.types):
        new_base = 1 + 2 * len(floats) + 0.5 * len(cats)
        best = None
        if t is Type.FLOAT:
            weight, pool, prefix = 2.0, floats, "F"
            col = np.array([r[i] for r in rows], dtype=np.float64)
            options = list(_options(col, floats, tol))
        else:
            weight, pool, prefix = 0.5, cats, "C"
            col = [r[i] for r in rows]
            options = [(Var(name, t), np.array([a == b for a, b in zip(col, v)])) for name, v in cats]
            vals = [col[k] for k in range(m) if covered[k]]
            common = max(set(vals), key=lambda v: (vals.count(v), str(v)))
            options.append((AxisConst(common) if t is Type.AXIS else IntConst(common), np.array([v == common for v in col])))
        old += weight
        for expr, hit in options:
            cov = covered & hit
            if cov.sum() < min_cover:
                continue
            if t is not Type.FLOAT and isinstance(expr, Var) and cov.sum() <= 0.75 * covered.sum():
                continue
            score = (old - new_base) * cov.sum() / m
            if best is None or score > best[0] + 1e-12:
                best = (score, expr, cov)
        score_new = (old - new_base - weight) * covered.sum() / m
        if best is None or score_new > best[0] + 1e-12:
            name = f"{prefix}{len(pool)}"
            pool.append((name, col))
            best = (score_new, Var(name) if t is Type.FLOAT else Var(name, t), covered)
        fill[f"P_{'F' if t is Type.FLOAT else 'C'}_{i}_"] = best[1]
        covered = best[2]
    if not floats and not cats:
        return None
    body = substitute(s.template, fill)
    params = tuple(Param(n) for n, _ in floats) + tuple(Param(n, _cat_type(body, n)) for n, _ in cats)
    new = 1 + 2 * len(floats) + 0.5 * len(cats)
    cov_programs = frozenset(s.programs[members[k]] for k in range(m) if covered[k])
    return Candidate(body, params, old - new, cov_programs)


def _cat_type(body: Expr, name: str) -> Type:
    for n in walk(body):
        if isinstance(n, Var) and n.name == name:
            return n.type
    raise ProgramError(f"parameter {name} is not in the body")  # pragma: no cover


def _cluster(s: Structure, rng: random.Random) -> list:
    n = len(s.values)
    size = rng.randint(min(8, n), min(16, n))
    seed = rng.randrange(n)
    vals = s.values
    d = np.empty(n)
    for k in range(n):
        diffs = [abs(a - b) if isinstance(a, float) else float(a != b) for a, b in zip(vals[seed], vals[k])]
        d[k] = min(max(math.sqrt(sum(x * x for x in diffs)), 0.1), 10.0)
    logits = 1.0 / d
    logits[seed] = -np.inf
    members = [seed]
    avail = np.ones(n, dtype=bool)
    avail[seed] = False
    for _ in range(size - 1):
        w = np.where(avail, np.exp(logits - logits[avail].max()), 0.0)
        if w.sum() <= 0:
            break
        k = int(np.searchsorted(np.cumsum(w / w.sum()), rng.random()))
        k = min(k, n - 1)
        members.append(k)
        avail[k] = False
    return members


def propose(programs: Sequence[Expr], library: Library | None = None, n_proposals: int = 10_000,
            rng: random.Random | None = None, weights: Sequence[float] | None = None, min_freq: float = MIN_SIG_FREQ,
            top: int = 20, preferences: bool = True) -> list:
    """The ``top`` candidates of ``n_proposals`` proposals over ``programs``, best first:
    ``[(rank, Candidate)]`` with rank = gain × (weighted share of covered programs) + 0.25 × pref
    (without ``preferences``: the gain term alone, the paper's "no preferences" ablation); candidates with
    the same body pool their coverage; those the library's ω rejects are dropped."""
    lib = _library(library)
    rng = rng or random.Random(0)
    n = len(programs)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    structs = eligible(collect(programs, lib), n, min_freq)
    if not structs:
        return []
    total = sum(x[2] for x in structs)
    pool: dict = {}
    for _ in range(n_proposals):
        r, acc = rng.random() * total, 0.0
        for sig, s, wt in structs:
            acc += wt
            if acc >= r:
                break
        cand = abstract(s, _cluster(s, rng), lib)
        if cand is None or cand.gain <= 0:
            continue
        key = to_text(cand.body)
        if key in pool:
            old = pool[key]
            pool[key] = Candidate(old.body, old.params, old.gain, old.programs | cand.programs)
        else:
            pool[key] = cand
    ranked = []
    for cand in pool.values():
        freq = float(w[list(cand.programs)].sum() / w.sum())
        try:
            pref = preference(Abstraction("_cand", cand.params, cand.body), lib, frequency=len(cand.programs) / n)
        except ProgramError:
            continue
        if pref is None:
            continue
        ranked.append((cand.gain * freq + (0.25 * pref if preferences else 0.0), to_text(cand.body), cand))
    ranked.sort(key=lambda x: (-x[0], x[1]))
    return [(r, c) for r, _, c in ranked[:top]]
