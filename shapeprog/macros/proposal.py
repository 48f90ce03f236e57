"""ShapeMOD's proposal phase: clusters of structurally matching programs, abstracted programs, candidate
macros under the valid-macro rules (i)-(iv), and generalisation (coefficient snapping, <= 2 edits).

One proposal step (:func:`propose_step`): a random node and one of its current orderings give a signature;
``cluster_size`` orderings with that signature are drawn around a random seed member, weighted by
``1 - d / max d`` of their float vectors (:func:`cluster`). :func:`abstract` covers the cluster's lines
from a start line greedily with library functions (most parameters removed first) that fit at least
``err_shape_perc`` of the members, and fills each parameter with the first expression of the spec's
preference order that fits (``cand_max_error`` on ``err_shape_perc`` of the members, mean error below
``cand_max_avg_error``), a constant or a re-used variable for discrete slots, else a fresh variable.
:func:`candidates` cuts the valid prefixes into :class:`Candidate` macros with their coverage;
:func:`generalise` snaps coefficients and adds the generalisations within ``cand_max_changes`` edits.

Decisions (see ``docs/shapemod.md``, "Discovery"): a seed whose farthest member would get weight 0 gets a
tiny positive weight (the reference can fail on a list of exactly ``cluster_size``); "several identical
occurrences replaced by one new variable" is not enumerated; a one-line candidate that equals a library
function is dropped.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from .grammar import BBOX, CuboidLine, Line, command, float_params
from .lang import (
    AXIS, BB_DIMS, BOOL, CUBE, FACE, FLOAT, Call, Linear, Literal, MacroDef, MacroError, Name, Param,
    check_def, def_text, BASE,
)
from .library import Library
from .objective import WEIGHTS, Template, fit, interface_cost

__all__ = ["PROPOSAL_TRIES", "Candidate", "abstract", "base_cost", "candidates", "cluster", "gain", "generalise", "heur_score",
           "propose_step"]

_TYPE_PREFIX = {FLOAT: "x", BOOL: "b", FACE: "k", AXIS: "a", CUBE: "t"}


@dataclass
class Candidate:
    """A candidate macro (anonymous: named ``macro``) and the lines it covered.

    Attributes:
        definition: the :class:`~shapeprog.macros.lang.MacroDef` (name ``'macro'``).
        coverage: ``(node, order, line)`` triples of the cluster lines it covered.
        key: its canonical text (equal candidates have equal keys).
    """

    definition: MacroDef
    coverage: set = field(default_factory=set)

    @property
    def key(self) -> str:
        return def_text(self.definition)


def base_cost(structure: Sequence[str], weights: Mapping[str, float] = WEIGHTS) -> float:
    """f of the base calls of ``structure``: 8 per line plus their interfaces."""
    return sum(weights["fn"] + interface_cost(BASE[c].params, weights) for c in structure)


def heur_score(structure: Sequence[str], params, weights: Mapping[str, float] = WEIGHTS) -> float:
    """Weighted parameters removed by a function relative to its base calls:
    ``8 * (len - 1) + 8 * di + df + 0.25 * db + 0.5 * dc``."""
    return base_cost(structure, weights) - weights["fn"] - interface_cost(params, weights)


def gain(defn: MacroDef, library: Library, weights: Mapping[str, float] = WEIGHTS) -> float:
    """The score of a candidate: :func:`heur_score` of its expansion (decomposition into base calls)."""
    info = check_def(defn, library.infos())
    return heur_score(info.structure, info.params, weights)


def cluster(members: Sequence[tuple[int, int]], vectors: np.ndarray, size: int, rng: np.random.Generator,
            weighted: bool = True) -> list[int]:
    """Indices into ``members`` of a cluster: a random seed, then ``size`` members drawn without
    replacement with weights ``1 - d / max d`` (L2 distance of ``vectors`` to the seed's; ``weighted=False``:
    uniformly, the Table 5 ablation)."""
    q = int(rng.integers(len(members)))
    d = np.linalg.norm(vectors - vectors[q], axis=1)
    m = float(d.max())
    w = 1.0 - d / m if m > 0 and weighted else np.ones(len(d))
    w = np.maximum(w, 1e-9)
    return sorted(rng.choice(len(members), size=size, replace=False, p=w / w.sum()).tolist())


# ----------------------------------------------------------------------------- abstraction


@dataclass
class _Var:
    name: str
    type: str
    values: np.ndarray  # per member (nan where unknown)


def _expr_candidates(fvars: list[_Var], bb: np.ndarray):
    """(Linear, values per member) in the preference order of the spec."""
    for c in (0.0, 0.5, 1.0):
        yield Linear.const(c), np.full(bb.shape[0], c)
    for i, b in enumerate(BB_DIMS):
        yield Linear.var(b), bb[:, i]
    for v in fvars:
        yield Linear.var(v.name), v.values
    for i, b in enumerate(BB_DIMS):
        yield Linear(((1.0, None), (1.0, b))), 1.0 + bb[:, i]
        yield Linear(((1.0, None), (-1.0, b))), 1.0 - bb[:, i]
    for v in fvars:
        yield Linear(((1.0, None), (1.0, v.name))), 1.0 + v.values
        yield Linear(((1.0, None), (-1.0, v.name))), 1.0 - v.values
    for i, b in enumerate(BB_DIMS):
        for v in fvars:
            yield Linear(((1.0, b), (1.0, v.name))), bb[:, i] + v.values
            yield Linear(((1.0, b), (-1.0, v.name))), bb[:, i] - v.values
    for v, w in itertools.combinations(fvars, 2):
        yield Linear(((1.0, v.name), (1.0, w.name))), v.values + w.values
        yield Linear(((1.0, v.name), (-1.0, w.name))), v.values - w.values
    for v in fvars:
        x = v.values
        ok = np.isfinite(x)
        yield ("scale", v), x if ok.any() else x


def _accept(pred: np.ndarray, y: np.ndarray, alive: np.ndarray, need: int, max_err: float, max_avg: float) -> bool:
    err = np.abs(pred - y)
    good = alive & (err < max_err)
    n = int(good.sum())
    return n >= need and float(err[good].mean()) < max_avg


@dataclass
class _Step:
    """One library-level line of an abstracted program."""

    func: str
    args: tuple  # Linear | Literal | Name(var) | ('cube', id)
    k: int
    pos: int
    alive: np.ndarray  # members that fit up to here


def abstract(members: Sequence[Sequence[Line]], start: int, library: Library, tpls: Sequence[Template],
             cfg: Mapping) -> list[_Step]:
    """The abstracted program of a cluster (same structure) from line ``start`` to the end."""
    m = len(members)
    lines0 = members[0]
    n = len(lines0)
    need = math.ceil(cfg["err_shape_perc"] * m - 1e-9)
    bb = np.array([[x[0].l, x[0].h, x[0].w] for x in members])
    cubes_before = sum(type(x) is CuboidLine for x in lines0[1:start])
    order = sorted(tpls, key=lambda t: -heur_score(t.structure, t.params))
    alive = np.ones(m, dtype=bool)
    fvars: list[_Var] = []
    dvars: list[_Var] = []
    steps: list[_Step] = []
    pos, cstart = start, cubes_before
    while pos < n:
        cmds = tuple(command(x) for x in lines0[pos:])
        chosen = None
        for t in order:
            k = len(t.structure)
            if cmds[:k] != t.structure:
                continue
            fits = [fit(t, members[i], pos, cstart, cfg["cand_max_error"], cfg["prec"]) if alive[i] else None
                    for i in range(m)]
            ok = np.array([f is not None for f in fits])
            if int(ok.sum()) >= need or (t.name in ("Cuboid", "attach", "squeeze", "reflect", "translate")
                                         and ok[alive].all()):
                chosen = (t, fits, ok)
                break
        if chosen is None:
            break
        t, fits, ok = chosen
        alive = alive & ok
        args = []
        for j, p in enumerate(t.params):
            vals = [f.args[j] if f is not None else None for f in fits]
            if p.type == FLOAT:
                y = np.array([v if v is not None else np.nan for v in vals], dtype=float)
                found = None
                for expr, pred in _expr_candidates(fvars, bb):
                    if isinstance(expr, tuple):  # least-squares scale of a variable
                        v = expr[1]
                        x = v.values
                        sel = alive & np.isfinite(x) & np.isfinite(y)
                        den = float((x[sel] ** 2).sum())
                        if den <= 0:
                            continue
                        s = round(float((x[sel] * y[sel]).sum()) / den, cfg["prec"])
                        if s == 0.0 or s == 1.0:
                            continue
                        expr, pred = Linear.var(v.name, s), s * x
                    with np.errstate(invalid="ignore"):
                        if _accept(pred, y, alive, need, cfg["cand_max_error"], cfg["cand_max_avg_error"]):
                            found = expr
                            break
                if found is None:
                    v = _Var(f"x{len(fvars)}", FLOAT, y)
                    fvars.append(v)
                    found = Linear.var(v.name)
                args.append(found)
            elif p.type == CUBE:
                first = next(v for v, a in zip(vals, alive) if a)
                args.append(("cube", first))
            else:
                live = [v for v, a in zip(vals, alive) if a]
                top, cnt = max(((x, live.count(x)) for x in set(live)), key=lambda z: (z[1], str(z[0])))
                if cnt > cfg["err_const_perc"] * len(live):
                    args.append(Literal(top))
                    continue
                reuse = None
                for v in dvars:
                    if v.type == p.type:
                        agree = sum(1 for a, x, y in zip(alive, v.values, vals) if a and x == y)
                        if agree > cfg["err_shape_perc"] * len(live):
                            reuse = v
                            break
                if reuse is None:
                    reuse = _Var(f"{_TYPE_PREFIX[p.type]}{len(dvars)}", p.type, np.array(vals, dtype=object))
                    dvars.append(reuse)
                args.append(Name(reuse.name))
        steps.append(_Step(t.name, tuple(args), len(t.structure), pos, alive.copy()))
        cstart += sum(1 for c in t.structure if c == "Cuboid")
        pos += len(t.structure)
    return steps


def _make_def(steps: Sequence[_Step], library: Library, cube_start: int) -> MacroDef:
    """A macro from abstracted lines: variables and outside cuboids become parameters (first use order),
    cuboids created inside are named ``n0``, ``n1``, ..."""
    params: dict[str, Param] = {}
    rename: dict[str, str] = {}
    counts = {FLOAT: 0, BOOL: 0, FACE: 0, AXIS: 0, CUBE: 0}
    created = 0
    body = []

    def pname(old: str, ptype: str) -> str:
        if old not in rename:
            nm = f"{_TYPE_PREFIX[ptype]}{counts[ptype]}"
            counts[ptype] += 1
            rename[old] = nm
            params[nm] = Param(nm, ptype)
        return rename[old]

    for st in steps:
        f = library[st.func]
        args = []
        for a, p in zip(st.args, f.params):
            if isinstance(a, Linear):
                terms = tuple((c, v if v is None or v in BB_DIMS else pname(v, FLOAT)) for c, v in a.terms)
                args.append(Linear(terms))
            elif isinstance(a, tuple):
                cid = a[1]
                if cid == BBOX:
                    args.append(Name("bbox"))
                elif cid >= cube_start:
                    args.append(Name(f"n{cid - cube_start}"))
                else:
                    args.append(Name(pname(f"#cube{cid}", CUBE)))
            elif isinstance(a, Name):
                args.append(Name(pname(a.name, p.type)))
            else:
                args.append(a)
        rets = tuple(f"n{created + j}" for j in range(f.n_cuboids))
        created += f.n_cuboids
        body.append(Call(st.func, tuple(args), rets))
    return MacroDef("macro", tuple(params.values()), tuple(body))


def _has_constant(defn: MacroDef, library: Library) -> bool:
    call = defn.body[0]
    f = library[call.func]
    for a, p in zip(call.args, f.params):
        if isinstance(a, Literal):
            return True
        if isinstance(a, Linear) and not any(v is not None and v not in BB_DIMS for _, v in a.terms):
            return True
        if isinstance(a, Linear) and (len(a.terms) > 1 or a.terms[0][0] != 1.0):
            return True
        if isinstance(a, Name) and a.name == "bbox":
            return True
    return False


def candidates(steps: Sequence[_Step], library: Library, member_ids: Sequence[tuple[int, int]],
               cube_start: int, max_lines: int = 4, rules: bool = True) -> list[Candidate]:
    """The valid prefixes of an abstracted program (rules i-iv of the spec) with their coverage; with
    ``rules=False`` (the Table 5 ablation) every prefix the macro language accepts."""
    out = []
    if not steps:
        return out
    first_cmd = library[steps[0].func].structure[0]
    for n in range(1, len(steps) + 1):
        if n >= 2 and rules:
            if n > max_lines:
                break
            if first_cmd != "Cuboid" and "Cuboid" in library[steps[n - 1].func].structure:
                break
            if library[steps[n - 1].func].structure[-1] == "Cuboid":
                continue
        d = _make_def(steps[:n], library, cube_start)
        if n == 1 and rules and not _has_constant(d, library):
            continue
        try:
            check_def(d, library.infos())
        except MacroError:  # an invalid prefix is skipped
            continue
        alive = steps[n - 1].alive
        lines = range(steps[0].pos, steps[n - 1].pos + steps[n - 1].k)
        cov = {(member_ids[i][0], member_ids[i][1], ln) for i in np.flatnonzero(alive) for ln in lines}
        out.append(Candidate(d, cov))
    return out


#: Draws of a proposal step before it gives up (the specification retries without a bound).
PROPOSAL_TRIES = 50


def propose_step(nodes, current: Sequence[Sequence[int]], index: Mapping, library: Library,
                 tpls: Sequence[Template], cfg: Mapping, rng: np.random.Generator, tries: int = PROPOSAL_TRIES,
                 missed: list | None = None) -> list[Candidate]:
    """One proposal step (a cluster, its abstracted programs from every start line, their candidates).

    Args:
        nodes: per node, its orderings' lines.
        current: per node, the indices of its current orderings.
        index: signature -> list of (node, order) among current orderings.
        tries: draws whose signature has fewer than ``cluster_size`` orderings are retried this often.
        missed: when given, a step whose ``tries`` draws all failed appends 1 to it (the step proposes nothing
            and still counts toward ``cand_cluster_num``; the specification retries without a bound).
    """
    size = cfg["cand_cluster_size"]
    live = [i for i, c in enumerate(current) if c]
    for _ in range(tries):
        i = live[int(rng.integers(len(live)))]
        o = current[i][int(rng.integers(len(current[i])))]
        sig = nodes.sigs[i][o]
        members = index.get(sig, ())
        if len(members) < size:
            continue
        vecs = np.array([float_params(nodes.lines[a][b]) for a, b in members], dtype=float)
        pick = cluster(members, vecs, size, rng, cfg.get("cluster_weighting", True))
        ids = [members[j] for j in pick]
        progs = [nodes.lines[a][b] for a, b in ids]
        out: list[Candidate] = []
        start = 1
        n = len(progs[0])
        while start < n:
            steps = abstract(progs, start, library, tpls, cfg)
            if not steps:
                break
            cstart = sum(type(x) is CuboidLine for x in progs[0][1:start])
            out += candidates(steps, library, ids, cstart, cfg["cand_max_lines"], cfg.get("valid_rules", True))
            start += steps[0].k
        return out
    if missed is not None:
        missed.append(1)
    return []


# ----------------------------------------------------------------------------- generalisation


def _numbers(defn: MacroDef):
    """(call, arg, term) positions of every coefficient/constant in float expressions."""
    for ci, c in enumerate(defn.body):
        for ai, a in enumerate(c.args):
            if isinstance(a, Linear):
                for ti, (coef, v) in enumerate(a.terms):
                    yield ci, ai, ti, coef


def _with_numbers(defn: MacroDef, values) -> MacroDef:
    it = iter(values)
    body = []
    for c in defn.body:
        args = []
        for a in c.args:
            if isinstance(a, Linear):
                a = Linear(tuple((next(it), v) for _, v in a.terms))
            args.append(a)
        body.append(Call(c.func, tuple(args), c.rets))
    return MacroDef(defn.name, defn.params, tuple(body))


def _snap(x: float, step: float) -> float:
    return round(math.floor(x / step + 1e-9) * step, 2)


def _renumber(defn: MacroDef, library: Library) -> MacroDef:
    """Parameters renamed and ordered by first use; unused parameters dropped."""
    used: list[str] = []
    types = {p.name: p.type for p in defn.params}
    for c in defn.body:
        for a in c.args:
            names = [v for _, v in a.terms if v is not None and v not in BB_DIMS] if isinstance(a, Linear) else (
                [a.name] if isinstance(a, Name) and a.name in types else [])
            for nm in names:
                if nm not in used:
                    used.append(nm)
    counts: dict[str, int] = {}
    ren = {}
    for nm in used:
        t = types[nm]
        ren[nm] = f"{_TYPE_PREFIX[t]}{counts.get(t, 0)}"
        counts[t] = counts.get(t, 0) + 1
    body = []
    for c in defn.body:
        args = []
        for a in c.args:
            if isinstance(a, Linear):
                a = Linear(tuple((k, ren.get(v, v)) for k, v in a.terms))
            elif isinstance(a, Name) and a.name in ren:
                a = Name(ren[a.name])
            args.append(a)
        body.append(Call(c.func, tuple(args), c.rets))
    params = tuple(Param(ren[nm], types[nm]) for nm in used)
    return MacroDef(defn.name, params, tuple(body))


def _edits(defn: MacroDef, library: Library):
    """Occurrences an edit can free: (call, arg) of constant/expression floats, shared float variables
    (every use after the first), literals and bbox cuboid ids."""
    seen: set = set()
    out = []
    for ci, c in enumerate(defn.body):
        f = library[c.func]
        for ai, (a, p) in enumerate(zip(c.args, f.params)):
            if isinstance(a, Linear):
                vs = [v for _, v in a.terms if v is not None and v not in BB_DIMS]
                plain = len(a.terms) == 1 and a.terms[0][0] == 1.0 and vs
                if not plain or vs[0] in seen:
                    out.append((ci, ai, p.type))
                seen.update(vs)
            elif isinstance(a, Literal) or (isinstance(a, Name) and a.name == "bbox"):
                out.append((ci, ai, p.type))
            elif isinstance(a, Name) and p.type != CUBE:
                if a.name in seen:
                    out.append((ci, ai, p.type))
                seen.add(a.name)
    return out


def _apply_edits(defn: MacroDef, edits) -> MacroDef:
    body = [list(c.args) for c in defn.body]
    params = list(defn.params)
    for j, (ci, ai, ptype) in enumerate(edits):
        nm = f"_g{j}"
        params.append(Param(nm, ptype))
        body[ci][ai] = Linear.var(nm) if ptype == FLOAT else Name(nm)
    return MacroDef(defn.name, tuple(params), tuple(Call(c.func, tuple(a), c.rets)
                                                    for c, a in zip(defn.body, body)))


def generalise(cands: Mapping[str, Candidate], library: Library, cfg: Mapping):
    """Snap coefficients and add generalisations within ``cand_max_changes`` edits.

    Returns ``(candidates by key, edges)`` where an edge ``(a, b)`` says that ``b`` generalises ``a``;
    a generalisation's coverage is the union of the coverages of what it generalises. With the setting
    ``generalise`` False (the Table 5 ablation) the candidates come back as they are, without edges.
    """
    if not cfg.get("generalise", True):
        return {k: Candidate(c.definition, set(c.coverage)) for k, c in cands.items()}, []
    # (a) coefficient snapping inside groups of equal shape
    infos = library.infos()
    groups: dict[str, list[Candidate]] = {}
    for c in cands.values():
        shape = def_text(_with_numbers(c.definition, [0.0] * sum(1 for _ in _numbers(c.definition))))
        groups.setdefault(shape, []).append(c)
    snapped: dict[str, Candidate] = {}
    eps, step = cfg["cluster_eps"], 1.0 / cfg["scale_prec"]
    for members in groups.values():
        vecs = np.array([[x for *_, x in _numbers(c.definition)] for c in members], dtype=float)
        vecs = vecs.reshape(len(members), -1)
        label = list(range(len(members)))

        def root(i):
            while label[i] != i:
                label[i] = label[label[i]]
                i = label[i]
            return i

        for a in range(len(members)):
            for b in range(a + 1, len(members)):
                if np.abs(vecs[a] - vecs[b]).sum() <= eps:
                    label[root(a)] = root(b)
        comps: dict[int, list[int]] = {}
        for a in range(len(members)):
            comps.setdefault(root(a), []).append(a)
        for idx in comps.values():
            w = np.array([max(len(members[i].coverage), 1) for i in idx], dtype=float)
            mean = (vecs[idx] * w[:, None]).sum(0) / w.sum()
            vals = [_snap(x, step) if abs(x - round(x)) > 1e-9 else float(round(x)) for x in mean]
            d = _renumber(_with_numbers(members[idx[0]].definition, vals), library)
            try:
                check_def(d, infos)
            except MacroError:  # a snapped coefficient that makes the macro invalid
                continue
            key = def_text(d)
            cov = set().union(*(members[i].coverage for i in idx))
            if key in snapped:
                snapped[key].coverage |= cov
            else:
                snapped[key] = Candidate(d, cov)
    # (b) generalisations within the edit budget
    out: dict[str, Candidate] = {k: Candidate(c.definition, set(c.coverage)) for k, c in snapped.items()}
    edges = []
    for key, c in snapped.items():
        occ = _edits(c.definition, library)
        for n in range(1, cfg["cand_max_changes"] + 1):
            for combo in itertools.combinations(occ, n):
                g = _renumber(_apply_edits(c.definition, combo), library)
                if len(g.body) == 1 and not _has_constant(g, library):
                    continue
                gk = def_text(g)
                if gk not in out:
                    try:
                        check_def(g, infos)
                    except MacroError:
                        continue
                    out[gk] = Candidate(g, set())
                out[gk].coverage |= c.coverage
                edges.append((key, gk))
    return out, edges
