"""The ShapeCoder language: typed expression trees, their text form, abstractions and libraries.
Standard library only.

A program is an expression tree of frozen dataclasses: :class:`Call` (a function applied to its
arguments), :class:`Num` (a float literal), :class:`Var` (a named float or categorical variable),
:class:`AxisConst` (``AX``, ``AY``, ``AZ``) and :class:`IntConst` (``INT#k#``). Every node has one of
four :class:`Type` s: ``Shape``, ``Float``, ``Axis`` or ``Int``.

The base functions of a domain are the rows of its :class:`Lang` table: :data:`LANG_3D` (``Cuboid``,
``Move``, ``Rotate``, ``Union``, ``SymRef``, ``SymTrans`` and the float operators ``Add``, ``Sub``,
``Mul``, ``Div``, ``Inv``) and the 2D toy domain :data:`LANG_2D` (``Rectangle`` in place of ``Cuboid``,
two-coordinate ``Move``, no ``Rotate``, axes ``AX``/``AY`` only). An :class:`Abstraction` is a named
function with typed parameters whose body is an expression over them; a :class:`Library` is a domain
plus an ordered tuple of abstractions (each may call the ones before it). :func:`expand` replaces every
abstraction call by its body, giving a base-language program.

Text form: ``Fn(arg,arg,...)``, numbers as Python writes floats, ``INT#k#`` for counts, any other name
a variable whose type is the type of its slot. :func:`parse` reads it (errors are
:class:`~shapeprog.errors.ParseError` naming file, line, column and token) and :func:`to_text` writes it
without spaces; ``parse(to_text(e)) == e`` for every well-typed tree. See docs/shapecoder.md
("Language").

Example:
    >>> e = parse("Union(Move(Cuboid(0.5,0.1,0.5),0,-0.2,0), SymRef(Move(Cuboid(a,b,a),-0.3,0,0),AX))")
    >>> e.fn, e.args[1].args[1]
    ('Union', AxisConst(name='AX'))
    >>> to_text(e)
    'Union(Move(Cuboid(0.5,0.1,0.5),0.0,-0.2,0.0),SymRef(Move(Cuboid(a,b,a),-0.3,0.0,0.0),AX))'
    >>> lib = Library().add(parse_abstraction("Leg(w: Float, x: Float) = Move(Cuboid(w,0.5,w),x,-0.25,x)"))
    >>> to_text(expand(parse("Leg(0.1,-0.4)", lib), lib))
    'Move(Cuboid(0.1,0.5,0.1),-0.4,-0.25,-0.4)'
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Iterator, Mapping

from ..errors import ParseError
from . import limits
from .expr import (  # noqa: F401 - the names of expr are this module's too (__all__)
    AXES, Abstraction, AxisConst, Call, Expr, FLOAT_CONSTANTS, FLOAT_FN, FN, IntConst, LANG_2D, LANG_3D,
    Lang, Num, Param, ProgramError, Signature, Type, Var, _NAME, _NAME_START, _NUM_START, _TYPES, _Tokens,
    _short, size, substitute, to_text, variables, walk,
)
from .expr import __all__ as _LOWER_NAMES

__all__ = [*_LOWER_NAMES, "Library", "ParseError", "as_expr", "check", "expand", "parse", "parse_abstraction"]


@dataclass(frozen=True)
class Library:
    """A domain's base language plus an ordered tuple of abstractions; immutable (``add`` and ``remove``
    return new libraries). Construction validates every abstraction against the ones before it.

    Attributes:
        lang: the base language (:data:`LANG_3D` by default).
        abstractions: the abstractions, in definition order.
    """

    lang: Lang = LANG_3D
    abstractions: tuple = ()
    _table: dict = field(init=False, repr=False, compare=False, hash=False)
    _depth: dict = field(init=False, repr=False, compare=False, hash=False)  # per abstraction: expanded depth bound
    # per abstraction: its body's node count with every call expanded, and each parameter's uses in it
    _nodes: dict = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self):
        if not isinstance(self.abstractions, tuple):
            object.__setattr__(self, "abstractions", tuple(self.abstractions))
        table: dict = {}
        object.__setattr__(self, "_table", table)
        object.__setattr__(self, "_depth", {})
        object.__setattr__(self, "_nodes", {})
        for ab in self.abstractions:
            self._depth[ab.name], self._nodes[ab.name] = self._validate(ab)
            table[ab.name] = ab

    def expanded_depth(self, expr: Expr) -> int:
        """A bound on the depth of ``expr`` with every abstraction call expanded (the root at depth 1):
        a call adds its abstraction's expanded body depth to its deepest argument's."""
        if not isinstance(expr, Call):
            return 1
        args = max((self.expanded_depth(a) for a in expr.args), default=0)
        body = self._depth.get(expr.fn)
        return 1 + args if body is None else body + max(args - 1, 0)

    def expanded_nodes(self, expr: Expr) -> int:
        """The node count of ``expr`` with every abstraction call expanded (:func:`expand`'s result), computed
        in time linear in ``expr`` (the abstractions' counts are kept when they join the library)."""
        return self._measure(expr)[0]

    def _measure(self, expr: Expr) -> tuple[int, dict]:
        """``(expanded node count, uses of each variable in the expansion)`` of ``expr``."""
        if isinstance(expr, Var):
            return 1, {expr.name: 1}
        if not isinstance(expr, Call):
            return 1, {}
        args = [self._measure(a) for a in expr.args]
        if expr.fn not in self._nodes:
            uses: dict = {}
            for _, u in args:
                for name, k in u.items():
                    uses[name] = uses.get(name, 0) + k
            return 1 + sum(n for n, _ in args), uses
        nodes, params = self._nodes[expr.fn]  # each use of a parameter is replaced by its argument's expansion
        total, uses = nodes, {}
        for p, (n, u) in zip(self._table[expr.fn].params, args):
            k = params.get(p.name, 0)
            total += k * (n - 1)
            for name, m in u.items():
                uses[name] = uses.get(name, 0) + k * m
        return total, uses

    def _validate(self, ab: Abstraction) -> tuple[int, tuple[int, dict]]:
        """Check ``ab`` against this library; returns its body's expanded depth bound and
        :meth:`_measure`."""
        if not isinstance(ab, Abstraction):
            raise ProgramError(f"not an Abstraction: {type(ab).__name__}")
        if not _NAME.match(ab.name) or ab.name in AXES or ab.name.startswith("INT#"):
            raise ProgramError(f"not an abstraction name: {ab.name!r}")
        if self.lang.signature(ab.name) is not None:
            raise ProgramError(f"{ab.name!r} is a base function of the {self.lang.name} language")
        if ab.name in self._table:
            raise ProgramError(f"the library already has an abstraction {ab.name!r}")
        if len(self._table) >= limits.MAX_ABSTRACTIONS:
            raise ProgramError(f"more than {limits.MAX_ABSTRACTIONS} abstractions (MAX_ABSTRACTIONS)")
        declared: dict = {}
        for p in ab.params:
            if not isinstance(p, Param) or not isinstance(p.type, Type) or p.type is Type.SHAPE:
                raise ProgramError(f"{ab.name}: a parameter must be a Param of type Float, Axis or Int, got {p!r}")
            Var(p.name, p.type)  # checks the name
            if p.name in declared:
                raise ProgramError(f"{ab.name}: parameter {p.name!r} is declared twice")
            declared[p.name] = p.type
        got = check(ab.body, self, params=declared)
        if got is not Type.SHAPE:
            raise ProgramError(f"{ab.name}: the body must be a Shape, got {got}")
        unused = [n for n in declared if n not in variables(ab.body)]
        if unused:
            raise ProgramError(f"{ab.name}: parameter(s) {', '.join(unused)} not used in the body")
        depth = self.expanded_depth(ab.body)
        if depth > limits.MAX_DEPTH:
            raise ProgramError(f"{ab.name}: its body expands to a depth over {limits.MAX_DEPTH} (MAX_DEPTH)")
        measured = self._measure(ab.body)
        if measured[0] > limits.MAX_NODES:
            raise ProgramError(f"{ab.name}: its body expands to more than {limits.MAX_NODES} nodes (MAX_NODES)")
        return depth, measured

    def signature(self, name: str) -> Signature | None:
        """The signature of base function or abstraction ``name``, or None."""
        sig = self.lang.signature(name)
        if sig is None and name in self._table:
            sig = self._table[name].signature
        return sig

    def __contains__(self, name: object) -> bool:
        return name in self._table

    def __repr__(self) -> str:
        """One line: the domain, the abstraction count and the first names (``to_text()`` prints them)."""
        names = [ab.name for ab in self.abstractions]
        shown = ", ".join(names[:8]) + (f", ... ({len(names) - 8} more)" if len(names) > 8 else "")
        return (f"<shapeprog.coder.Library ({self.lang.name}): {len(names)} abstractions"
                f"{': ' + shown if names else ''}>")

    def __getitem__(self, name: str) -> Abstraction:
        return self._table[name]

    def __iter__(self) -> Iterator[Abstraction]:
        return iter(self.abstractions)

    def __len__(self) -> int:
        return len(self.abstractions)

    @property
    def size(self) -> int:
        """|L|: the base shape functions plus the abstractions (6 + n in 3D)."""
        return len(self.lang.shape_functions) + len(self.abstractions)

    def add(self, ab: Abstraction) -> "Library":
        """A new library with ``ab`` appended (validated against this library)."""
        self._validate(ab)
        return dataclasses.replace(self, abstractions=self.abstractions + (ab,))

    def remove(self, name: str) -> "Library":
        """A new library without abstraction ``name``; later abstractions that call it get it inlined."""
        if name not in self._table:
            raise KeyError(f"no abstraction {name!r} in the library")
        kept = []
        for ab in self.abstractions:
            if ab.name != name:
                kept.append(Abstraction(ab.name, ab.params, expand(ab.body, self, names=(name,))))
        return dataclasses.replace(self, abstractions=tuple(kept))

    def to_text(self) -> str:
        """One ``Name(params) = Body`` line per abstraction."""
        return "".join(ab.to_text() + "\n" for ab in self.abstractions)

    @classmethod
    def from_text(cls, text: str, lang: Lang = LANG_3D, file: str = "<string>") -> "Library":
        """The library written by :meth:`to_text` (blank lines and ``#`` comments skipped)."""
        lib = cls(lang)
        for n, line in enumerate(text.split("\n"), 1):
            if line.strip() and not line.lstrip().startswith("#"):
                ab = parse_abstraction(line, lib, file=file, line=n)
                try:
                    lib = lib.add(ab)
                except ProgramError as e:  # a library-level limit: at the abstraction's line
                    col = len(line) - len(line.lstrip()) + 1
                    raise ParseError(str(e), file, n, col, ab.name) from None
        return lib


def _library(library) -> Library:
    if library is None:
        return Library()
    if isinstance(library, Lang):
        return Library(library)
    if not isinstance(library, Library):
        raise TypeError(f"expected a Library or a Lang, got {type(library).__name__}")
    return library


def as_expr(expr, library: "Library | Lang | None" = None, call: str = "this function") -> Expr:
    """``expr`` as an expression tree: a tree (:class:`Call`, :class:`Num`, :class:`Var`, :class:`AxisConst`,
    :class:`IntConst`) as it is, a ``str`` parsed with ``library`` (:func:`parse`).

    Raises:
        TypeError: anything else, naming ``call`` and the call that makes a program (for an inference result,
            ``shapeprog.coder.parse(result.text, library)``).
        ParseError: text that is not a Shape expression of ``library``.
    """
    if isinstance(expr, (Call, Num, Var, AxisConst, IntConst)):
        return expr
    if isinstance(expr, str):
        return parse(expr, library)
    name = type(expr).__name__
    if hasattr(expr, "text") and hasattr(expr, "expanded"):  # an inference result (shapeprog.coder.Inferred)
        hint = ("an inference result, not a program: its program is shapeprog.coder.parse(result.text, library) "
                "(its error is result.error)")
    else:
        hint = "make one with shapeprog.coder.parse(text, library)"
    raise TypeError(f"{call} takes a ShapeCoder program (an expression tree) or its text, got {name}: {hint}")


# ----------------------------------------------------------------------------- type checking and expansion


def check(expr: Expr, library: Library | Lang | None = None, expect: Type | None = None,
          params: Mapping[str, Type] | None = None) -> Type:
    """The type of ``expr``, checking every call's arity and argument types, each variable's type against
    its slot (and against ``params`` when given: then every variable must be one of them), the axes of
    the domain, and the limits :data:`~shapeprog.coder.limits.MAX_DEPTH` and
    :data:`~shapeprog.coder.limits.MAX_NODES`.

    Raises:
        ProgramError: naming the offending sub-expression.
    """
    lib = _library(library)
    count = [0]

    def go(e, want, depth):
        count[0] += 1
        if count[0] > limits.MAX_NODES:
            raise ProgramError(f"more than {limits.MAX_NODES} nodes (MAX_NODES)")
        if depth > limits.MAX_DEPTH:
            raise ProgramError(f"nested deeper than {limits.MAX_DEPTH} (MAX_DEPTH)")
        if isinstance(e, Call):
            sig = lib.signature(e.fn)
            if sig is None:
                raise ProgramError(f"unknown function {e.fn!r} in {_short(e)}")
            if len(e.args) != sig.arity:
                raise ProgramError(f"{e.fn} takes {sig.arity} argument(s), got {len(e.args)} in {_short(e)}")
            for a, t in zip(e.args, sig.params):
                go(a, t, depth + 1)
            got = sig.returns
        elif isinstance(e, Num):
            got = Type.FLOAT
        elif isinstance(e, AxisConst):
            if e.name not in lib.lang.axes:
                raise ProgramError(f"axis {e.name} is not in the {lib.lang.name} language")
            got = Type.AXIS
        elif isinstance(e, IntConst):
            got = Type.INT
        elif isinstance(e, Var):
            if params is not None:
                if e.name not in params:
                    raise ProgramError(f"{e.name!r} is not a parameter")
                if params[e.name] is not e.type:
                    raise ProgramError(f"parameter {e.name!r} is {params[e.name]}, used as {e.type}")
            got = e.type
        else:
            raise ProgramError(f"not an expression node: {type(e).__name__}")
        if want is not None and got is not want:
            raise ProgramError(f"expected {want}, got {got}: {_short(e)}")
        return got

    return go(expr, expect, 1)


def expand(expr: Expr, library: Library, names=None) -> Expr:
    """``expr`` with the abstraction calls replaced by their bodies (arguments substituted for the
    parameters), recursively, so that only base functions remain; with ``names``, only the abstractions
    named there are expanded.

    Raises:
        ProgramError: the expansion exceeds :data:`~shapeprog.coder.limits.MAX_NODES` nodes.
    """
    lib = _library(library)
    expr = as_expr(expr, lib, "shapeprog.coder.expand")
    only = None if names is None else frozenset(names)
    cache: dict = {}
    if lib.expanded_nodes(expr) > limits.MAX_NODES:  # a partial expansion is no larger than the full one
        raise ProgramError(f"the expansion exceeds {limits.MAX_NODES} nodes (MAX_NODES)")

    def go(e):
        if not isinstance(e, Call):
            return e
        args = tuple(go(a) for a in e.args)
        if e.fn in lib and (only is None or e.fn in only):
            ab = lib[e.fn]
            if ab.name not in cache:
                cache[ab.name] = go(ab.body)
            out = substitute(cache[ab.name], {p.name: a for p, a in zip(ab.params, args)})
        else:
            out = e if args == e.args else Call(e.fn, args)
        return out

    return go(expr)


def _parse_expr(toks: _Tokens, lib: Library, want: Type | None, params: Mapping[str, Type] | None,
                depth: int) -> Expr:
    i = toks.next()
    text = toks.toks[i]
    if depth > limits.MAX_DEPTH:
        raise toks.error(f"nested deeper than {limits.MAX_DEPTH} (MAX_DEPTH)", i)
    if not text:
        raise toks.error("unexpected end of the text", i)
    c = text[0]
    if c in _NAME_START and not text.startswith("INT#"):
        if toks.toks[toks.i] == "(":
            sig = lib.signature(text)
            if sig is None:
                raise toks.error(f"unknown function {text!r}", i)
            if want is not None and sig.returns is not want:
                raise toks.error(f"expected {want}, got {text}, a {sig.returns} function", i)
            toks.i += 1
            args = []
            for k, ptype in enumerate(sig.params):
                if k:
                    j = toks.next()
                    if toks.toks[j] != ",":
                        if toks.toks[j] == ")":
                            raise toks.error(f"{text} takes {sig.arity} argument(s), got {k}", j)
                        raise toks.error(f"expected ',' in {text}(...), got {toks.shown(j)}", j)
                args.append(_parse_expr(toks, lib, ptype, params, depth + 1))
            j = toks.next()
            if toks.toks[j] != ")":
                if toks.toks[j] == ",":
                    raise toks.error(f"{text} takes {sig.arity} argument(s), got more", j)
                raise toks.error(f"expected ')' closing {text}, got {toks.shown(j)}", j)
            node = Call(text, tuple(args))
            if toks.spans is not None:
                toks.spans.append((i, node))
            return node
        if text in AXES:
            if want not in (None, Type.AXIS):
                raise toks.error(f"expected {want}, got the axis {text}", i)
            if text not in lib.lang.axes:
                raise toks.error(f"axis {text} is not in the {lib.lang.name} language", i)
            return AxisConst(text)
        if lib.signature(text) is not None:
            raise toks.error(f"function {text!r} needs its arguments in parentheses", i)
        if want is Type.SHAPE:
            raise toks.error(f"a variable ({text!r}) cannot stand for a Shape", i)
        vtype = want if want is not None else (params or {}).get(text, Type.FLOAT)
        if params is not None:
            if text not in params:
                raise toks.error(f"{text!r} is not a parameter", i)
            if params[text] is not vtype:
                raise toks.error(f"parameter {text!r} is {params[text]}, expected {vtype} here", i)
        node = Var(text, vtype)
        if toks.spans is not None:
            toks.spans.append((i, node))
        return node
    if c in _NUM_START and (len(text) > 1 or c.isdigit()):
        if want is not Type.FLOAT and want is not None:
            raise toks.error(f"expected {want}, got the number {text}", i)
        value = float(text)
        if not math.isfinite(value) or abs(value) > limits.MAX_ABS_NUMBER:
            raise toks.error(f"number {text} is out of range (limit: magnitude {limits.MAX_ABS_NUMBER}, "
                             "MAX_ABS_NUMBER)", i)
        return Num(value)
    if text.startswith("INT#"):
        digits = text[4:-1] if text.endswith("#") and len(text) > 5 else None
        if digits is None:
            raise toks.error(f"malformed count {text!r}; expected INT#k#", i)
        if want not in (None, Type.INT):
            raise toks.error(f"expected {want}, got the count {text}", i)
        k = int(digits) if len(digits) <= 6 else limits.MAX_COUNT + 1
        if not 1 <= k <= limits.MAX_COUNT:
            raise toks.error(f"count {text} must be from 1 to {limits.MAX_COUNT} (MAX_COUNT)", i)
        return IntConst(k)
    raise toks.error(f"expected an expression, got {text!r}", i)


def parse(text: str, library: Library | Lang | None = None, *, expect: Type | None = Type.SHAPE,
          file: str = "<string>", line: int = 1, column: int = 1) -> Expr:
    """Parse one expression (whitespace, including newlines, is ignored between tokens).

    Args:
        text: e.g. ``"Move(Cuboid(0.1,0.5,0.1),-0.4,0,x)"``.
        library: the functions that may be called: a :class:`Library` (base functions plus abstractions)
            or a bare :class:`Lang`; :data:`LANG_3D` by default.
        expect: the type the expression must have (``Shape`` by default; ``Float`` for a float
            expression such as ``"Add(a,1.0)"``).
        file, line, column: where the text starts, for error messages.

    Raises:
        ParseError: ``file:line:column: reason`` with the offending token.
    """
    if not isinstance(text, str):
        raise TypeError(f"text must be a str, got {type(text).__name__}")
    lib = _library(library)
    toks = _Tokens(text, file, line, column)
    expr = _parse_expr(toks, lib, expect, None, 1)
    if toks.i < toks.last:
        raise toks.error(f"unexpected {toks.toks[toks.i]!r} after the expression", toks.i)
    return expr


def _parse_spans(text: str, library: Library | Lang | None = None, *, file: str = "<string>", line: int = 1,
                 column: int = 1) -> tuple:
    """:func:`parse` of a Shape expression, also giving its tokens, whose ``spans`` list ``(token index,
    node)`` for every Call and Var node (look nodes up by identity; ``toks.offset(index)`` is the offset
    of the node's name), for error messages about sub-expressions."""
    toks = _Tokens(text, file, line, column)
    toks.spans = []
    expr = _parse_expr(toks, _library(library), Type.SHAPE, None, 1)
    if toks.i < toks.last:
        raise toks.error(f"unexpected {toks.toks[toks.i]!r} after the expression", toks.i)
    return expr, toks


def parse_abstraction(text: str, library: Library | Lang | None = None, *, file: str = "<string>", line: int = 1,
                      column: int = 1) -> Abstraction:
    """Parse ``Name(p: Type, ...) = Body`` (the form of :meth:`Abstraction.to_text`); the body may call
    the base functions and the abstractions of ``library``. The abstraction is not added to it.

    Raises:
        ParseError: bad syntax, an unknown type, a variable that is not a parameter, a parameter used
            with two types or not at all.
    """
    lib = _library(library)
    toks = _Tokens(text, file, line, column)
    head = toks.next()
    name = toks.toks[head]
    if not name or name[0] not in _NAME_START or name.startswith("INT#"):
        raise toks.error("expected the abstraction's name", head)
    toks.expect("(", "'('")
    params: dict = {}
    locs: dict = {}
    if toks.toks[toks.i] == ")":
        toks.next()
    else:
        while True:
            k = toks.next()
            pname = toks.toks[k]
            if not pname or pname[0] not in _NAME_START or pname.startswith("INT#") or pname in AXES:
                raise toks.error("expected a parameter name", k)
            if pname in params:
                raise toks.error(f"parameter {pname!r} is declared twice", k)
            toks.expect(":", "':' and a type")
            t = toks.next()
            if toks.toks[t] not in ("Float", "Axis", "Int"):
                raise toks.error(f"unknown parameter type {toks.toks[t]!r}; expected Float, Axis or Int", t)
            params[pname] = _TYPES[toks.toks[t]]
            locs[pname] = k
            sep = toks.next()
            if toks.toks[sep] == ")":
                break
            if toks.toks[sep] != ",":
                raise toks.error("expected ',' or ')' in the parameter list", sep)
    toks.expect("=", "'='")
    if lib.signature(name) is not None:
        raise toks.error(f"{name!r} is already a function of the library", head)
    body = _parse_expr(toks, lib, Type.SHAPE, params, 1)
    if toks.i < toks.last:
        raise toks.error(f"unexpected {toks.toks[toks.i]!r} after the body", toks.i)
    used = variables(body)
    for pname, k in locs.items():
        if pname not in used:
            raise toks.error(f"parameter {pname!r} is not used in the body", k)
    try:
        return Abstraction(name, tuple(Param(n, t) for n, t in params.items()), body)
    except ProgramError as e:
        raise toks.error(str(e), head) from None
