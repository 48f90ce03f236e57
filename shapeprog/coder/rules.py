"""The egglog program of a ShapeCoder refactor (:func:`shapeprog.coder.refactor.refactor`): the
declarations, the value bookkeeping, the semantic rewrites (:func:`semantic_rules`), one conditional rewrite
per abstraction (:func:`abstraction_rule`), the naive relations of the paper's ablation
(:func:`naive_egglog_program`), and programs to egglog terms and back (``_term``, ``_from_term``).
"""
from __future__ import annotations

import operator
import re
from typing import Mapping

from ..errors import RefactorError
from .lang import (
    AXES, FLOAT_CONSTANTS, Abstraction, AxisConst, Call, Expr, IntConst, Lang, Library, Num, ProgramError,
    Type, Var, _short, walk,
)

__all__ = [
    "ABSTRACTION_TOL",
    "COSTS",
    "NAIVE_OPS",
    "naive_egglog_program",
    "naive_relations",
    "relations_command",
    "SCHEMES",
    "SEMANTIC_TOL",
    "abstraction_rule",
    "egglog_program",
    "semantic_rules",
]


#: Tolerance of the conditional semantic rewrites (the reference's 0.01).
SEMANTIC_TOL = 0.01
#: Tolerance of the abstraction rewrites (``ab_rw_max_error``), per domain.
ABSTRACTION_TOL = {"3d": 0.055, "2d": 0.04}
#: How parameter relations reach the e-graph: ``"conditional"`` (guards on a value table, the paper's
#: method) or ``"naive"`` (the ablation of the paper's Table 1: every pairwise relation of the program's
#: floats put into the e-graph as e-nodes before the run, and unguarded rules; see :func:`naive_egglog_program`).
SCHEMES = ("conditional", "naive")
#: Integer e-node costs: the paper's costs times 10.
COSTS = {"fn": 10, "float_fn": 1, "float_var": 20, "float_const": 5, "cat": 5}


# ----------------------------------------------------------------------------- the rules (egglog text)

_FLOAT_OPS = {"Add": "+", "Sub": "-", "Mul": "*", "Div": "/"}
#: Prefix of the abstractions' constructors (keeps them apart from egglog's and the rules' names).
_AB = "L_"


#: Added to every tolerance so that 2-decimal values exactly ``tol`` apart pass despite float rounding.
_EPS = 1e-9


def _close(a: str, b: str, tol: float) -> str:
    return f"(<= (abs (- {a} {b})) {_f64(tol + _EPS)})"


def _f64(v: float) -> str:
    v = float(v)
    text = repr(v)
    if "e" in text or "n" in text:  # egglog reads plain decimals only
        text = f"{v:.15f}"
    return text


def _declarations(lib: Library) -> str:
    lang = lib.lang
    c = COSTS
    axes = " ".join(f"({a} :cost {c['cat']})" for a in lang.axes)
    if lang.dim == 3:
        shapes = [f"(Cuboid Flt Flt Flt :cost {c['fn']})", f"(Move Shape Flt Flt Flt :cost {c['fn']})",
                  f"(Rotate Shape Ax Flt :cost {c['fn']})"]
    else:
        shapes = [f"(Rectangle Flt Flt :cost {c['fn']})", f"(Move Shape Flt Flt :cost {c['fn']})"]
    shapes += [f"(Union Shape Shape :cost {c['fn']})", f"(SymRef Shape Ax :cost {c['fn']})",
               f"(SymTrans Shape Ax Cnt Flt :cost {c['fn']})"]
    sort = {Type.FLOAT: "Flt", Type.AXIS: "Ax", Type.INT: "Cnt"}
    for ab in lib.abstractions:
        shapes.append(f"({_AB}{ab.name} {' '.join(sort[p.type] for p in ab.params)} :cost {c['fn']})")
    flt = [f"(Num f64 :cost {c['float_var']})", f"(K f64 :cost {c['float_const']})"]
    flt += [f"({op} Flt Flt :cost {c['float_fn']})" for op in _FLOAT_OPS] + [f"(Inv Flt :cost {c['float_fn']})"]
    return "\n".join([
        f"(datatype Flt {' '.join(flt)})",
        f"(datatype Ax {axes})",
        f"(datatype Cnt (N i64 :cost {c['cat']}))",
        f"(datatype Shape {' '.join(shapes)})",
        "(function val (Flt) f64 :merge old)",
        "(relation norot (Shape))",
        "(ruleset rw)",
        "(ruleset facts)",
    ])


def _bookkeeping(lib: Library) -> list:
    """The value-table rules: leaves, then each float operator (a Div by about 0 gets no value)."""
    rules = ["(rule ((= e (Num x))) ((set (val e) x)) :ruleset rw)",
             "(rule ((= e (K x))) ((set (val e) x)) :ruleset rw)",
             "(rule ((= e (Inv a)) (= va (val a))) ((set (val e) (neg va))) :ruleset rw)"]
    for op, sym in _FLOAT_OPS.items():
        guard = " (> (abs vb) 0.000001)" if op == "Div" else ""
        rules.append(f"(rule ((= e ({op} a b)) (= va (val a)) (= vb (val b)){guard}) "
                     f"((set (val e) ({sym} va vb))) :ruleset rw)")
    # norot: the shape has no rotated part, so reflecting it about its own centre changes nothing
    prim = "Cuboid" if lib.lang.dim == 3 else "Rectangle"
    args = " ".join("_" for _ in range(lib.lang.dim))
    move = " ".join("_" for _ in range(lib.lang.dim))
    rules += [f"(rule ((= s ({prim} {args}))) ((norot s)) :ruleset rw)",
              f"(rule ((= s (Move a {move})) (norot a)) ((norot s)) :ruleset rw)",
              "(rule ((= s (Union a b)) (norot a) (norot b)) ((norot s)) :ruleset rw)",
              "(rule ((= s (SymRef a _)) (norot a)) ((norot s)) :ruleset rw)",
              "(rule ((= s (SymTrans a _ _ _)) (norot a)) ((norot s)) :ruleset rw)"]
    norot: dict = {}  # per abstraction, in definition order (an abstraction calls only earlier ones)
    for ab in lib.abstractions:
        norot[ab.name] = not any(isinstance(n, Call) and (n.fn == "Rotate" or (n.fn in lib and not norot[n.fn]))
                                 for n in walk(ab.body))
        if norot[ab.name]:
            pats = " ".join("_" for _ in ab.params)
            rules.append(f"(rule ((= s ({_AB}{ab.name} {pats}))) ((norot s)) :ruleset rw)")
    # the same rules in the ruleset of the eager schedule (VALUES), run to saturation before each iteration
    return rules + [r.replace(":ruleset rw)", ":ruleset facts)") for r in rules]


def semantic_rules(lang: Lang) -> list:
    """The semantic rewrites as egglog commands (3D: the paper's 25 rules, 36 directed rules; 2D: the 17
    of the reference's 2D list). Numbered as in docs/shapecoder.md; ``C`` rules are guarded with
    :data:`SEMANTIC_TOL`."""
    t = _f64(SEMANTIC_TOL + _EPS)
    k = lang.dim
    co = ["x", "y", "z"][:k]
    p1 = " ".join(f"{c}1" for c in co)
    p2 = " ".join(f"{c}2" for c in co)
    prim = "Cuboid" if k == 3 else "Rectangle"
    dims1 = " ".join(["a1", "b1", "c1"][:k])
    dims2 = " ".join(["a2", "b2", "c2"][:k])
    rules = []

    def vals(names):
        return " ".join(f"(= v{n} (val {n}))" for n in names)

    for i, ax in enumerate(lang.axes):
        c = co[i]
        # 1-3 (B) reflect-offset flip, guarded: the reflected shape has no rotated part
        flipped = " ".join(f"(Inv {c}1)" if j == i else f"{co[j]}1" for j in range(k))
        rules.append(f"(rule ((= s (SymRef (Move S {p1}) ({ax}))) (norot S)) "
                     f"((union s (SymRef (Move S {flipped}) ({ax})))) :ruleset rw)")
        # 4-6 (C) symmetry introduction: equal dims, equal off-axis coordinates, opposite on the axis
        guards = [_close(f"v{d1}", f"v{d2}", SEMANTIC_TOL) for d1, d2 in zip(dims1.split(), dims2.split())]
        for j in range(k):
            if j == i:
                guards.append(f"(<= (abs (+ v{co[j]}1 v{co[j]}2)) {t})")
                guards.append(f"(< v{co[j]}1 0.0)")
            else:
                guards.append(_close(f"v{co[j]}1", f"v{co[j]}2", SEMANTIC_TOL))
        names = dims1.split() + dims2.split() + [f"{c_}1" for c_ in co] + [f"{c_}2" for c_ in co]
        rules.append(f"(rule ((= s (Union (Move ({prim} {dims1}) {p1}) (Move ({prim} {dims2}) {p2}))) "
                     f"{vals(names)} {' '.join(guards)}) "
                     f"((union s (SymRef (Move ({prim} {dims1}) {p1}) ({ax})))) :ruleset rw)")
        # 7-9 symmetry expansion (of a single box, which is its own mirror image)
        rules.append(f"(rewrite (SymRef (Move ({prim} {dims1}) {p1}) ({ax})) "
                     f"(Union (Move ({prim} {dims1}) {p1}) (Move ({prim} {dims1}) {flipped})) :ruleset rw)")
    pq = " ".join(f"(Add {c}1 {c}2)" for c in co)
    # 10 (B) SymTrans absorbs an outer Move
    rules.append(f"(birewrite (Move (SymTrans (Move S {p1}) A n d) {p2}) (SymTrans (Move S {pq}) A n d) :ruleset rw)")
    # 11 (C) pull a common Move out of a Union
    rules.append(f"(rule ((= s (Union (Move S1 {p1}) (Move S2 {p2}))) {vals([f'{c}1' for c in co] + [f'{c}2' for c in co])} "
                 + " ".join(_close(f"v{c}1", f"v{c}2", SEMANTIC_TOL) for c in co)
                 + f") ((union s (Move (Union S1 S2) {p1}))) :ruleset rw)")
    # 12 push a Move into a Union
    rules.append(f"(rewrite (Move (Union S1 S2) {p1}) (Union (Move S1 {p1}) (Move S2 {p1})) :ruleset rw)")
    # 13 (B) merge nested Moves
    rules.append(f"(birewrite (Move (Move S {p1}) {p2}) (Move S {pq}) :ruleset rw)")
    # 14 (C) drop a zero Move
    rules.append(f"(rule ((= s (Move S {p1})) {vals([f'{c}1' for c in co])} "
                 + " ".join(f"(<= (abs v{c}1) {t})" for c in co) + ") ((union s S)) :ruleset rw)")
    # 15 Union commutativity, 16 (B) associativity
    rules.append("(rewrite (Union S1 S2) (Union S2 S1) :ruleset rw)")
    rules.append("(birewrite (Union S1 (Union S2 S3)) (Union (Union S1 S2) S3) :ruleset rw)")
    # 17 Inv(Inv(a)) -> a
    rules.append("(rewrite (Inv (Inv a)) a :ruleset rw)")
    if k == 3:
        # 18 (B) merge nested Rotates about one axis
        rules.append("(birewrite (Rotate (Rotate S A a) A b) (Rotate S A (Add a b)) :ruleset rw)")
        # 19 (C) drop a zero Rotate
        rules.append(f"(rule ((= s (Rotate S A a)) (= va (val a)) (<= (abs va) {t})) ((union s S)) :ruleset rw)")
        # 20 (C) pull a common Rotate out of a Union
        rules.append(f"(rule ((= s (Union (Rotate S1 A a) (Rotate S2 A b))) (= va (val a)) (= vb (val b)) "
                     f"{_close('va', 'vb', SEMANTIC_TOL)}) ((union s (Rotate (Union S1 S2) A a))) :ruleset rw)")
        # 21 push a Rotate into a Union
        rules.append("(rewrite (Rotate (Union S1 S2) A a) (Union (Rotate S1 A a) (Rotate S2 A a)) :ruleset rw)")
        # 22 (B) swap Move and Rotate (parts turn about their own centres)
        rules.append(f"(birewrite (Rotate (Move S {p1}) A a) (Move (Rotate S A a) {p1}) :ruleset rw)")
    # 23 (B) SymRef over a Union
    rules.append("(birewrite (SymRef (Union S1 S2) A) (Union (SymRef S1 A) (SymRef S2 A)) :ruleset rw)")
    # 24-25 (C) Add with an addend of about 0
    rules.append(f"(rule ((= e (Add a b)) (= va (val a)) (<= (abs va) {t})) ((union e b)) :ruleset rw)")
    rules.append(f"(rule ((= e (Add a b)) (= vb (val b)) (<= (abs vb) {t})) ((union e a)) :ruleset rw)")
    return rules


def abstraction_rule(ab: Abstraction, lib: Library, tol: float | None = None) -> str | None:
    """The conditional rewrite that introduces ``ab``: its body with every Float slot of a shape function
    replaced by a pattern variable; the first plain occurrence of each Float parameter binds it, and every
    other slot (a repeated parameter, a float expression over the parameters, a literal) becomes a guard
    comparing the slot's value with the value the body computes (within ``tol``, by default
    :data:`ABSTRACTION_TOL` of the domain). Axis and Int parameters are pattern variables (a repeat must be
    the same e-class); axis and count literals are matched exactly.

    Returns:
        the egglog rule text, or None when a Float parameter never fills a slot on its own (the rule
        could not bind it).
    """
    tol = ABSTRACTION_TOL[lib.lang.name] if tol is None else tol
    ptypes = {p.name: p.type for p in ab.params}
    bound: dict = {}  # Float param -> slot pattern var
    slots: list = []  # (pattern var, float expression of the body)
    cat: dict = {}
    counter = [0]

    def pat(e: Expr, want: Type) -> str:
        if isinstance(e, Call):
            sig = lib.signature(e.fn)
            if sig.kind == "float_fn":
                raise AssertionError  # float expressions appear only in slots, handled below
            parts = [_AB + e.fn if e.fn in lib else e.fn]
            for a, t in zip(e.args, sig.params):
                if t is Type.FLOAT:
                    counter[0] += 1
                    v = f"f{counter[0]}"
                    if isinstance(a, Var) and a.name not in bound:
                        bound[a.name] = v
                    else:
                        slots.append((v, a))
                    parts.append(v)
                else:
                    parts.append(pat(a, t))
            return "(" + " ".join(parts) + ")"
        if isinstance(e, AxisConst):
            return f"({e.name})"
        if isinstance(e, IntConst):
            return f"(N {e.value})"
        if isinstance(e, Var):
            if e.name not in cat:
                cat[e.name] = f"c_{e.name}"
            return cat[e.name]
        raise ProgramError(f"{ab.name}: unexpected node in the body: {_short(e)}")

    lhs = pat(ab.body, Type.SHAPE)
    floats = [p.name for p in ab.params if p.type is Type.FLOAT]
    if any(n not in bound for n in floats):
        return None
    queries = [f"(= s {lhs})"]
    needed = set()
    guards = []
    for v, e in slots:
        needed.add(v)
        guards.append(_close(f"v{v}", _value_expr(e, bound, needed), tol))
    for n in floats:
        if bound[n] in needed:
            pass
    queries += [f"(= v{v} (val {v}))" for v in sorted(needed)]
    args = []
    for p in ab.params:
        args.append(bound[p.name] if p.type is Type.FLOAT else cat[p.name])
    del ptypes
    return (f"(rule ({' '.join(queries + guards)}) ((union s ({_AB}{ab.name} {' '.join(args)}))) :ruleset rw)")


def _value_expr(e: Expr, bound: Mapping, needed: set) -> str:
    """egglog f64 arithmetic computing a float expression of an abstraction body from the bound slots."""
    if isinstance(e, Num):
        return _f64(e.value)
    if isinstance(e, Var):
        needed.add(bound[e.name])
        return f"v{bound[e.name]}"
    if isinstance(e, Call):
        if e.fn == "Inv":
            return f"(neg {_value_expr(e.args[0], bound, needed)})"
        a, b = (_value_expr(x, bound, needed) for x in e.args)
        return f"({_FLOAT_OPS[e.fn]} {a} {b})"
    raise ProgramError(f"not a float expression: {_short(e)}")


def egglog_program(lib: Library, semantic=None) -> str:
    """The egglog declarations and rules for ``lib``: sorts, the value table, the bookkeeping rules, the
    semantic rules (all, or those at the positions ``semantic`` of :func:`semantic_rules`) and one rule per
    abstraction (those :func:`abstraction_rule` can express)."""
    sem = semantic_rules(lib.lang)
    rules = _bookkeeping(lib) + (sem if semantic is None else [sem[i] for i in semantic])
    for ab in lib.abstractions:
        r = abstraction_rule(ab, lib)
        if r is not None:
            rules.append(r)
    return _declarations(lib) + "\n" + "\n".join(rules) + "\n"


def _naive_semantic_rules(lang: Lang) -> list:
    """The semantic rewrites without value guards: a relation between floats is a shared e-class (the
    relations are put in by :func:`naive_relations`), so each conditional rule becomes a plain pattern;
    the symmetry introduction drops its sign guard (both orders give the same SymRef up to rule 1)."""
    k = lang.dim
    co = ["x", "y", "z"][:k]
    p1 = " ".join(f"{c}1" for c in co)
    prim = "Cuboid" if k == 3 else "Rectangle"
    dims = " ".join(["a", "b", "c"][:k])
    zero = "(K 0.0)"
    out = []
    conditional = semantic_rules(lang)
    for i, ax in enumerate(lang.axes):
        flipped = " ".join(f"(Inv {co[j]}1)" if j == i else f"{co[j]}1" for j in range(k))
        out.append(f"(rewrite (Union (Move ({prim} {dims}) {p1}) (Move ({prim} {dims}) {flipped})) "
                   f"(SymRef (Move ({prim} {dims}) {p1}) ({ax})) :ruleset rw)")
    out.append(f"(rewrite (Union (Move S1 {p1}) (Move S2 {p1})) (Move (Union S1 S2) {p1}) :ruleset rw)")
    out.append(f"(rewrite (Move S {' '.join([zero] * k)}) S :ruleset rw)")
    out += [f"(rewrite (Add a {zero}) a :ruleset rw)", f"(rewrite (Add {zero} a) a :ruleset rw)"]
    if k == 3:
        out.append(f"(rewrite (Rotate S A {zero}) S :ruleset rw)")
        out.append("(rewrite (Union (Rotate S1 A a) (Rotate S2 A a)) (Rotate (Union S1 S2) A a) :ruleset rw)")
    # the unguarded rules of the conditional list are kept as they are
    return out + [r for r in conditional if "(val " not in r]


def _naive_abstraction_rule(ab: Abstraction, lib: Library) -> str:
    """An abstraction's rewrite as a plain pattern: its float expressions are matched as e-nodes (which
    :func:`naive_relations` must have put in the e-graph)."""
    args = " ".join(f"p_{p.name}" for p in ab.params)
    body = _term(ab.body, lib, var=lambda v: f"p_{v.name}")
    return f"(rewrite {body} ({_AB}{ab.name} {args}) :ruleset rw)"


def naive_egglog_program(lib: Library) -> str:
    """The egglog declarations and rules of the naive scheme (the paper's Table 1 ablation): the
    declarations and structural bookkeeping of :func:`egglog_program`, the semantic rules of
    :func:`_naive_semantic_rules` and one plain rewrite per abstraction. Use with ``refactor(...,
    scheme="naive")``, which adds the program's :func:`naive_relations`."""
    book = [r for r in _bookkeeping(lib) if "(val " not in r and "(set " not in r]
    rules = book + _naive_semantic_rules(lib.lang) + [_naive_abstraction_rule(ab, lib) for ab in lib.abstractions]
    return _declarations(lib) + "\n" + "\n".join(rules) + "\n"


#: The float operators whose pairwise e-nodes the naive scheme puts in (``Inv`` of each leaf as well).
NAIVE_OPS = {"Add": operator.add, "Sub": operator.sub, "Mul": operator.mul, "Div": operator.truediv}


def _trivial(a: float, op: str, b: float) -> bool:
    """An identity, a zero or a division by 0, which the naive scheme leaves out."""
    if op == "Add":
        return 0.0 in (a, b)
    if op == "Sub":
        return b == 0.0
    if op == "Mul":
        return bool({a, b} & {0.0, 1.0})
    return b in (0.0, 1.0) or a == 0.0


def naive_relations(values, prec: int = 2) -> list:
    """egglog actions that put a program's parameter relations into the e-graph (the naive scheme): for
    the program's distinct floats ``values``, the e-nodes ``Inv a`` and ``op a b`` for every operator of
    :data:`NAIVE_OPS` and every ordered pair of leaves (the program's floats and the constants 0, 1, 2) with
    at least one of the program's floats (less the identities and zeros: ``a + 0``, ``a - 0``, ``a · 1``,
    ``a / 1``, ``a · 0``, ``0 / a``), each unioned with the leaf equal to the node's value rounded to
    ``prec`` decimals, if there is one. About ``4 (n + 3)²`` new e-nodes for ``n`` distinct floats. The
    relations are one operator deep: an abstraction whose body nests float operators (``Add(Mul(a, 2), b)``)
    never fires in this scheme.

    The relations are exact at ``prec`` decimals, not within a tolerance as the guards of the conditional
    scheme: a union is transitive and a tolerance is not, so with ±0.01 chains of near-equal values merged
    every float of a 32-parameter scene into one e-class (and the extracted program into a point).
    :func:`relations_command` makes them one egglog command."""
    own = {round(float(v), 12) + 0.0 for v in values}
    leaves = sorted(own | set(FLOAT_CONSTANTS))
    term = {v: (f"(K {_f64(v)})" if v in FLOAT_CONSTANTS else f"(Num {_f64(v)})") for v in leaves}
    by_value = {round(v, prec) + 0.0: v for v in leaves}
    out = []

    def relate(value, node):
        c = by_value.get(round(value, prec) + 0.0)
        if c is not None:
            out.append(f"(union {node} {term[c]})")

    for a in sorted(own):
        out.append(f"(Inv {term[a]})")
        relate(-a, f"(Inv {term[a]})")
    for a in leaves:
        for b in leaves:
            if a not in own and b not in own:
                continue
            for op in NAIVE_OPS:
                if not _trivial(a, op, b):
                    node = f"({op} {term[a]} {term[b]})"
                    out.append(node)
                    relate(NAIVE_OPS[op](a, b), node)
    return out


def relations_command(actions: list) -> str:
    """egglog commands running ``actions`` (e.g. :func:`naive_relations`) at once: rules with no query and
    10 actions each, in a ruleset of their own, run once (as some 3,000 top-level commands, the relations of
    one 28-value scene took 38 s)."""
    rules = [f"(rule () ({' '.join(actions[i:i + 10])}) :ruleset naive_rel)" for i in range(0, len(actions), 10)]
    return "(ruleset naive_rel)\n" + "\n".join(rules) + "\n(run naive_rel 1)"


# ----------------------------------------------------------------------------- program <-> term


def _term(e: Expr, lib: Library, var=None) -> str:
    """The egglog term of ``e``; a variable is an error, or the pattern variable ``var(v)`` names."""
    if isinstance(e, Call):
        return "(" + (_AB + e.fn if e.fn in lib else e.fn) + "".join(" " + _term(a, lib, var) for a in e.args) + ")"
    if isinstance(e, Num):
        v = round(e.value, 12) + 0.0
        return f"(K {_f64(v)})" if v in FLOAT_CONSTANTS else f"(Num {_f64(v)})"
    if isinstance(e, AxisConst):
        return f"({e.name})"
    if isinstance(e, IntConst):
        return f"(N {e.value})"
    if isinstance(e, Var) and var is not None:
        return var(e)
    raise RefactorError(f"unbound variable {e.name!r}" if isinstance(e, Var) else f"bad node {e!r}")


_SEXP = re.compile(r"\(|\)|[^\s()]+")


def _from_term(text: str, lib: Library) -> Expr:
    toks = _SEXP.findall(text)
    pos = [0]

    def go():
        tok = toks[pos[0]]
        pos[0] += 1
        if tok != "(":
            raise RefactorError(f"unexpected token {tok!r} in the extracted term")
        head = toks[pos[0]]
        pos[0] += 1
        if head in ("Num", "K"):
            out = Num(float(toks[pos[0]]))
            pos[0] += 1
        elif head == "N":
            out = IntConst(int(toks[pos[0]]))
            pos[0] += 1
        elif head in AXES:
            out = AxisConst(head)
        else:
            args = []
            while toks[pos[0]] != ")":
                args.append(go())
            out = Call(head[len(_AB):] if head.startswith(_AB) else head, tuple(args))
        if toks[pos[0]] != ")":
            raise RefactorError(f"malformed extracted term near {toks[pos[0]]!r}")
        pos[0] += 1
        return out

    return go()
