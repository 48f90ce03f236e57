"""The text language of macro programs (ShapeMOD): typed macros, and programs that call them.
Standard library only.

A text holds macro definitions, then program lines::

    def leg(s: float, b: bool, t: float):
        c = Cuboid(s, bb_y, s, b)
        squeeze(bbox, bbox, bot, 0.6 * s, t)
        reflect(X)

    def four_legs(s: float, b: bool, t: float):
        c1 = leg(s, b, t)
        c2 = leg(0.95 * s, b, 1.0 - t)

    bbox = Cuboid(1.2, 0.9, 1.0, True)
    leg0, leg1 = four_legs(0.1, True, 0.2)
    seat = Cuboid(1.2, 0.1, 1.0, True)
    attach(leg0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)

* **Calls.** Every line calls a function: one of the five base functions of the modified grammar
  (:data:`BASE`) or a macro defined earlier (in the text or in a library). A call binds one name to
  each cuboid it creates (``a, b = f(...)``; none for a function that creates no cuboid). Base
  commands other than ``Cuboid`` act on the *last declared cuboid*, which is why they name no subject.
* **Types.** A parameter is ``float``, ``cube`` (a cuboid id), ``face``, ``axis`` or ``bool``. In a
  macro body a float argument is a linear expression (``0.6 * s``, ``1.0 - t``, ``bb_y``,
  ``0.5 * bb_x + 0.1 * s + 0.2``) over the macro's float parameters and the bbox dims ``bb_x``,
  ``bb_y``, ``bb_z`` of the sub-program; a cuboid id is ``bbox``, a ``cube`` parameter or a cuboid
  created earlier in the body; faces, axes and booleans are literals or parameters of that type.
  In program lines every float is a number (a *free parameter* of the program), every cuboid id is
  ``bbox`` or a cuboid named by an earlier line. The first program line is ``bbox = Cuboid(...)``.
* **Format.** ``def`` lines start at column 1, body lines are indented (the printer uses 4 spaces), a
  blank line follows each definition; ``#`` starts a comment; numbers print with ``repr``.
  :func:`to_text` prints the canonical form, so ``to_text(parse(t)) == t`` for printed texts and
  ``parse(to_text(p)) == p``.

:func:`parse` here checks syntax, names and types; :meth:`shapeprog.macros.library.Library.parse` also
expands the program and reports value errors (e.g. an attach to its own subject) at their line.
Errors are :class:`~shapeprog.errors.ParseError` with file, line, column and token. The decisions:
``docs/shapemod.md`` ("Macro programs").

Example:
    >>> p = parse("def bar(h: float):\\n    c = Cuboid(bb_x, h, bb_z, True)\\n    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n"
    ...           "\\nbbox = Cuboid(1.0, 2.0, 1.0, True)\\nslab = bar(0.25)\\n")
    >>> p.defs[0].body[0].args[1], p.lines[1]
    (Linear(terms=((1.0, 'h'),)), Call(func='bar', args=(Linear(terms=((0.25, None),)),), rets=('slab',)))
    >>> print(to_text(p), end="")
    def bar(h: float):
        c = Cuboid(bb_x, h, bb_z, True)
        attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)
    <BLANKLINE>
    bbox = Cuboid(1.0, 2.0, 1.0, True)
    slab = bar(0.25)
"""
from __future__ import annotations

import re
from typing import Mapping, Sequence

from .. import limits
from ..errors import ParseError
from ..lang import AXES, FACES
from .grammar import BBOX, AttachLine, CuboidLine, Line, ReflectLine, SqueezeLine, TranslateLine
from .syntax import (  # noqa: F401 - the names of syntax are this module's too (__all__)
    AXIS, Arg, BASE, BB_DIMS, BOOL, CUBE, Call, FACE, FLOAT, FunctionInfo, INDENT, Linear, Literal,
    MAX_EXPANDED_LINES, MacroDef, MacroError, MacroProgram, Name, Param, TYPES, _check_calls, _check_name,
    check_def, check_program, def_text, to_text,
)
from .syntax import __all__ as _LOWER_NAMES

__all__ = [*_LOWER_NAMES, "from_lines", "parameters", "parse", "replace_parameters"]


# ----------------------------------------------------------------------------- parser

_TOKEN = re.compile(r"\s*(?:(?P<num>(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)|(?P<name>[A-Za-z_][A-Za-z_0-9]*)"
                    r"|(?P<punct>[(),=:*+\-])|(?P<bad>\S))")


class _Toks:
    def __init__(self, text: str, file: str, lineno: int):
        self.text, self.file, self.lineno = text, file, lineno
        self.toks = [(m.lastgroup, m.group(m.lastgroup), m.start(m.lastgroup) + 1)
                     for m in _TOKEN.finditer(text) if m.lastgroup]
        self.i = 0

    def error(self, reason: str, tok=None) -> ParseError:
        if tok is None:
            tok = self.toks[self.i] if self.i < len(self.toks) else ("end", "", len(self.text.rstrip()) + 1)
        return ParseError(reason, self.file, self.lineno, tok[2], tok[1])

    def peek(self):
        return self.toks[self.i] if self.i < len(self.toks) else None

    def take(self, kind: str | None = None, text: str | None = None, what: str = ""):
        t = self.peek()
        want = what or (repr(text) if text else kind)
        if t is None:
            raise self.error(f"expected {want}, got the end of the line")
        if t[0] == "bad":
            raise self.error(f"unexpected character {t[1]!r}")
        if (kind and t[0] != kind) or (text and t[1] != text):
            raise self.error(f"expected {want}, got {t[1]!r}")
        self.i += 1
        return t

    def separated(self, item, end: str, empty: bool = False) -> list:
        """What ``item()`` reads, repeated with ``,`` between, up to the punctuation ``end`` (taken too);
        ``empty``: the list may be empty (``end`` comes at once)."""
        out = []
        if empty and self.peek() is not None and self.peek()[1] == end:
            self.i += 1
            return out
        while True:
            out.append(item())
            t = self.take("punct", what=f"',' or {end!r}")
            if t[1] == end:
                return out
            if t[1] != ",":
                raise self.error(f"expected ',' or {end!r}, got {t[1]!r}", t)

    def end(self) -> None:
        if self.peek() is not None:
            t = self.peek()
            raise self.error(f"unexpected {t[1]!r} after the line" if t[0] != "bad" else f"unexpected character {t[1]!r}")


def _number(ln: _Toks, t) -> float:
    return limits.number(t[1], ln.file, ln.lineno, t[2])


def _parse_arg(ln: _Toks):
    """One argument: a bare name (a Name) or a linear expression; returns (arg, first token)."""
    first = ln.peek()
    if first is None or first[1] in (",", ")"):
        raise ln.error("expected an argument")
    t2 = ln.toks[ln.i + 1] if ln.i + 1 < len(ln.toks) else None
    if first[0] == "name" and (t2 is None or t2[1] in (",", ")")):
        ln.i += 1
        if first[1] in ("True", "False"):
            return Literal(first[1] == "True"), first
        if first[1] in FACES or first[1] in AXES:
            return Literal(first[1]), first
        return Name(first[1]), first
    terms = []
    sign = 1.0
    if first[1] in ("-", "+"):
        sign = -1.0 if first[1] == "-" else 1.0
        ln.i += 1
    while True:
        t = ln.peek()
        if t is None or t[0] not in ("num", "name"):
            raise ln.error("expected a number or a name in the expression")
        ln.i += 1
        if t[0] == "num":
            c = _number(ln, t)
            nxt = ln.peek()
            if nxt is not None and nxt[1] == "*":
                ln.i += 1
                v = ln.take("name", what="a variable after '*'")
                terms.append((sign * c, v[1]))
            else:
                terms.append((sign * c, None))
        else:
            if t[1] in ("True", "False") or t[1] in FACES or t[1] in AXES:
                raise ln.error(f"{t[1]!r} cannot be part of an expression", t)
            terms.append((sign, t[1]))
        nxt = ln.peek()
        if nxt is None or nxt[1] in (",", ")"):
            break
        if nxt[1] not in ("+", "-"):
            raise ln.error(f"expected '+', '-', ',' or ')', got {nxt[1]!r}")
        sign = -1.0 if nxt[1] == "-" else 1.0
        ln.i += 1
    return Linear(tuple(terms)), first


def _parse_param(ln: _Toks) -> tuple:
    """``name: type``; returns the name's and the type's tokens."""
    pt = ln.take("name", what="a parameter name")
    ln.take("punct", ":")
    ty = ln.take("name", what="a type")
    if ty[1] not in TYPES:
        raise ln.error(f"unknown type {ty[1]!r} (expected one of {', '.join(TYPES)})", ty)
    return pt, ty


def _parse_call(ln: _Toks) -> tuple[Call, list, tuple, list]:
    """``[a, b =] f(args)``; returns the call, the first token of every argument, the function's
    token and the tokens of the names bound."""
    rtoks = []
    if any(t[1] == "=" for t in ln.toks):
        rtoks = ln.separated(lambda: ln.take("name", what="a cuboid name"), "=")
    fn = ln.take("name", what="a function name")
    ln.take("punct", "(")
    parsed = ln.separated(lambda: _parse_arg(ln), ")", empty=True)
    ln.end()
    call = Call(fn[1], tuple(a for a, _ in parsed), tuple(t[1] for t in rtoks))
    return call, [t for _, t in parsed], fn, rtoks


def _coerce(call: Call, functions: Mapping[str, FunctionInfo]) -> Call:
    """Arguments in their slot's form: a bare name in a float slot is a one-term expression
    (``s`` -> ``Linear(((1.0, 's'),))``); a face or axis word in a cuboid slot is a cuboid's name."""
    info = functions.get(call.func)
    if info is None or len(info.params) != len(call.args):
        return call
    args = []
    for a, p in zip(call.args, info.params):
        if p.type == FLOAT and isinstance(a, Name):
            a = Linear.var(a.name)
        elif p.type == CUBE and isinstance(a, Literal) and isinstance(a.value, str):
            a = Name(a.value)
        args.append(a)
    return Call(call.func, tuple(args), call.rets)


def _located(e: MacroError, file: str, where: dict) -> ParseError:
    """A MacroError raised by the checks, at the line and token it names."""
    ln, toks, fn, header, rtoks = where[(e.macro, e.index)]
    if e.arg is not None and e.arg < len(toks):
        tok = toks[e.arg]
    elif e.ret is not None and e.ret < len(rtoks):
        tok = rtoks[e.ret]
    elif e.index is None:
        tok = header
    else:
        tok = fn
    return ParseError(e.reason, file, ln, tok[2], tok[1])


def parse(text: str, file: str = "<string>", functions: Mapping[str, FunctionInfo] | None = None) -> MacroProgram:
    """Parse a macro program (definitions, then program lines) and check its names and types.

    Args:
        text: the program text.
        file: a name used in error messages.
        functions: functions the text may call besides the base ones and its own definitions (e.g.
            a library's, :meth:`shapeprog.macros.library.Library.infos`).

    Raises:
        ParseError: ``file:line:column: reason`` at the offending token.
    """
    return _parse(text, file, functions)[0]


def _parse(text: str, file: str, functions: Mapping[str, FunctionInfo] | None, program: bool = True):
    """:func:`parse`, also returning where each program line and definition line is
    (``{(macro or None, index): (line, argument tokens, function token, header token)}``) and every
    callable function's info. ``program=False`` reads a library text: definitions only."""
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    lines = [x[:-1] if x.endswith("\r") else x for x in lines]
    limits.check_lines(lines, file)
    funcs: dict[str, FunctionInfo] = dict(BASE)
    for name, info in (functions or {}).items():
        funcs.setdefault(name, info)
    defs: list[MacroDef] = []
    prog: list[Call] = []
    where: dict = {}
    cur = None  # (name, params, body calls, header token, header line)

    def finish():
        nonlocal cur
        if cur is None:
            return
        name, params, body, htok, hline = cur
        cur = None
        if not body:
            raise ParseError("a definition needs an indented body", file, hline, htok[2], htok[1])
        d = MacroDef(name, params, tuple(_coerce(c, funcs) for c in body))
        if name in BASE:
            raise ParseError(f"{name!r} is a base function", file, hline, htok[2], htok[1])
        if name in funcs:
            raise ParseError(f"function {name!r} is already defined", file, hline, htok[2], htok[1])
        try:
            funcs[name] = check_def(d, funcs)
        except MacroError as e:
            raise _located(e, file, where) from None
        defs.append(d)

    for i, raw in enumerate(lines):
        lineno = i + 1
        code = raw.split("#", 1)[0]
        if not code.strip():
            continue
        ln = _Toks(code, file, lineno)
        if ln.toks and ln.toks[0][1] == "def" and not code[0].isspace():
            finish()
            if prog:
                raise ln.error("definitions must come before the program lines", ln.toks[0])
            ln.take("name", "def")
            ntok = ln.take("name", what="a macro name")
            ln.take("punct", "(")
            pairs = ln.separated(lambda: _parse_param(ln), ")", empty=True)
            params = [Param(pt[1], ty[1]) for pt, ty in pairs]
            ptoks = [pt for pt, _ in pairs]
            ln.take("punct", ":")
            ln.end()
            for j, (p, pt) in enumerate(zip(params, ptoks)):  # name errors at the parameter
                try:
                    _check_name(p.name, "parameter", ntok[1], None)
                except MacroError as e:
                    raise ParseError(e.reason, file, lineno, pt[2], pt[1]) from None
                if any(q.name == p.name for q in params[:j]):
                    raise ParseError(f"parameter {p.name!r} appears twice", file, lineno, pt[2], pt[1])
            cur = (ntok[1], tuple(params), [], ntok, lineno)
            where[(ntok[1], None)] = (lineno, [], ntok, ntok, [])
            continue
        if code[0].isspace():
            if cur is None:
                raise ln.error("unexpected indentation (a body line outside a definition)", ln.toks[0])
            call, toks, fn, rtoks = _parse_call(ln)
            where[(cur[0], len(cur[2]))] = (lineno, toks, fn, fn, rtoks)
            cur[2].append(call)
            continue
        finish()
        if not program:
            raise ln.error("a library text holds definitions only", ln.toks[0])
        call, toks, fn, rtoks = _parse_call(ln)
        where[(None, len(prog))] = (lineno, toks, fn, fn, rtoks)
        prog.append(_coerce(call, funcs))
    finish()
    if not program:
        return MacroProgram(tuple(defs), ()), where, funcs
    if not prog:
        raise ParseError("a program needs at least its bbox line ('bbox = Cuboid(...)')", file, max(len(lines), 1), 1,
                         "")
    result = MacroProgram(tuple(defs), tuple(prog))
    try:
        _check_calls(result.lines, {"bbox": CUBE}, funcs, None)
    except MacroError as e:
        raise _located(e, file, where) from None
    return result, where, funcs


# ----------------------------------------------------------------------------- parameters and lines


def parameters(program: MacroProgram) -> list[float]:
    """The program's free float parameters: every number of its lines, in text order (the bbox dims
    first)."""
    return [a.value for c in program.lines for a in c.args if isinstance(a, Linear)]


def replace_parameters(program: MacroProgram, values: Sequence[float]) -> MacroProgram:
    """A copy of ``program`` whose line numbers are ``values`` (the order of :func:`parameters`)."""
    it = iter(values)
    lines = []
    for c in program.lines:
        args = tuple(Linear.const(float(next(it))) if isinstance(a, Linear) else a for a in c.args)
        lines.append(Call(c.func, args, c.rets))
    rest = list(it)
    if rest:
        raise ValueError(f"{len(rest)} value(s) more than the program's parameters")
    return MacroProgram(program.defs, tuple(lines))


def from_lines(lines: Sequence[Line], names: Sequence[str] | None = None) -> MacroProgram:
    """A line sequence of :mod:`shapeprog.macros.grammar` as a macro program of base calls.

    Args:
        lines: the sequence (bbox line first).
        names: one name per non-bbox Cuboid line (default ``cube0``, ``cube1``, ...).

    Example:
        >>> lines = (CuboidLine(1.0, 1.0, 1.0, True), CuboidLine(0.5, 0.2, 0.5, True),
        ...          AttachLine(-1, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5), ReflectLine("X"))
        >>> print(to_text(from_lines(lines)), end="")
        bbox = Cuboid(1.0, 1.0, 1.0, True)
        cube0 = Cuboid(0.5, 0.2, 0.5, True)
        attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)
        reflect(X)
    """
    n = sum(type(x) is CuboidLine for x in lines[1:])
    names = [f"cube{k}" for k in range(n)] if names is None else list(names)
    if len(names) != n:
        raise ValueError(f"`names` must hold {n} names, got {len(names)}")
    ref = lambda t: Name("bbox" if t == BBOX else names[t])  # noqa: E731
    f = Linear.const
    out = []
    k = -1
    for ln in lines:
        t = type(ln)
        if t is CuboidLine:
            out.append(Call("Cuboid", (f(ln.l), f(ln.h), f(ln.w), Literal(bool(ln.aligned))),
                            ("bbox",) if k < 0 else (names[k],)))
            k += 1
        elif t is AttachLine:
            out.append(Call("attach", (ref(ln.target),) + tuple(f(getattr(ln, a)) for a in
                                                                  ("x1", "y1", "z1", "x2", "y2", "z2"))))
        elif t is SqueezeLine:
            out.append(Call("squeeze", (ref(ln.t1), ref(ln.t2), Literal(ln.face), f(ln.u), f(ln.v))))
        elif t is ReflectLine:
            out.append(Call("reflect", (Literal(ln.axis),)))
        elif t is TranslateLine:
            out.append(Call("translate", (Literal(ln.axis), f(ln.n), f(ln.d))))
        else:
            raise TypeError(f"not a line of the grammar: {type(ln).__name__}")
    return MacroProgram((), tuple(out))
