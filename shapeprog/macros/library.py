"""A library of typed macro functions, and the expansion of macros and macro programs to base lines.
Standard library only.

A :class:`Library` holds the five base functions of the modified grammar (``Cuboid``, ``attach``,
``squeeze``, ``reflect``, ``translate``; :data:`shapeprog.macros.lang.BASE`) and macros
(:class:`~shapeprog.macros.lang.MacroDef`) in definition order; a macro may call any function defined
before it. It is immutable: :meth:`Library.add` returns a new library.

* :meth:`Library.expand_macro` inlines a macro down to base calls, each float argument a linear
  expression over the macro's own float parameters and the bbox dims (the reference's per-slot
  "logic"), each cuboid id a parameter, ``bbox`` or a cuboid the macro creates.
* :meth:`Library.expand` expands a program into an :class:`Expansion`: base lines of
  :mod:`shapeprog.macros.grammar` with the program's numbers, each float slot also given as an
  :class:`Affine` form over the program's free parameters (what differentiable execution needs).
* :meth:`Library.parse` parses a text and checks that its program expands (value errors at their line).

Example:
    >>> lib = Library.from_text("def leg(s: float, t: float):\\n    c = Cuboid(s, bb_y, s, False)\\n"
    ...                         "    squeeze(bbox, bbox, top, t, 0.5)\\n    reflect(X)\\n")
    >>> lib["leg"].structure, lib["leg"].n_cuboids
    (('Cuboid', 'squeeze', 'reflect'), 1)
    >>> p = lib.parse("bbox = Cuboid(1.0, 0.8, 1.0, True)\\nleg0 = leg(0.1, 0.1)\\n")
    >>> lib.expand(p).lines[1:]
    (CuboidLine(l=0.1, h=0.8, w=0.1, aligned=False), SqueezeLine(t1=-1, t2=-1, face='top', u=0.1, v=0.5), \
ReflectLine(axis='X'))
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

from .. import limits
from ..errors import ParseError
from .grammar import (BBOX, AttachLine, CuboidLine, Line, LineError, ReflectLine, SqueezeLine, TranslateLine,
                      check_lines)
from .lang import (BASE, BB_DIMS, CUBE, FLOAT, Call, FunctionInfo, Linear, Literal, MacroDef, MacroError,
                   MacroProgram, Name, _parse, check_def, check_program, def_text,
                   from_lines)

__all__ = ["Affine", "Expansion", "Function", "Library", "parse"]


@dataclass(frozen=True)
class Affine:
    """``const + sum(coef * params[index] for index, coef in terms)``: a float slot of an expanded
    program as a function of the program's free parameters (:func:`shapeprog.macros.lang.parameters`)."""

    const: float
    terms: tuple[tuple[int, float], ...]

    def evaluate(self, params: Sequence[float]) -> float:
        return self.const + sum(c * params[i] for i, c in self.terms)


@dataclass(frozen=True)
class Function:
    """A function of a library: a base function (``definition`` None) or a macro."""

    info: FunctionInfo
    definition: MacroDef | None = None

    # the signature's fields, read through: name (str), params (tuple of Param), n_cuboids (int), structure
    # (tuple of str)
    name = property(lambda self: self.info.name)
    params = property(lambda self: self.info.params)
    n_cuboids = property(lambda self: self.info.n_cuboids)
    structure = property(lambda self: self.info.structure)

    @property
    def is_base(self) -> bool:
        return self.definition is None


@dataclass(frozen=True)
class Expansion:
    """A program expanded to base lines.

    Attributes:
        lines: the base lines (:mod:`shapeprog.macros.grammar`, bbox first) with the program's numbers.
        floats: per line, its float slots in parameter order (Cuboid l, h, w; attach x1..z2; squeeze
            u, v; translate n, d) as :class:`Affine` forms over the program's free parameters.
        source: per line, the index of the program line it comes from.
        names: per non-bbox Cuboid line, the name the program binds that cuboid to.
    """

    lines: tuple[Line, ...]
    floats: tuple[tuple[Affine, ...], ...]
    source: tuple[int, ...]
    names: tuple[str, ...]


class _Sink:
    """Receives base calls during inlining: symbolic (names, Linear) or numeric (ints, Affine)."""

    def __init__(self, numeric: bool, values: Sequence[float] = (), reserved: Iterable[str] = ()):
        self.numeric, self.values = numeric, values
        self.reserved = set(reserved)
        self.calls: list[Call] = []
        self.lines: list[Line] = []
        self.floats: list[tuple[Affine, ...]] = []
        self.source: list[int] = []
        self.n = 0  # non-bbox cuboids created
        self.index = 0  # the program line being expanded (numeric)

    bbox_ref = property(lambda self: BBOX if self.numeric else "bbox")

    def new_cube(self):
        k = self.n
        self.n += 1
        if self.numeric:
            return k
        name = f"c{k}"
        while name in self.reserved:
            name += "_"
        return name

    def emit(self, func: str, args: list, rets) -> None:
        if not self.numeric:
            out = []
            for a in args:
                if isinstance(a, dict):
                    terms = tuple((c, v) for v, c in a.items() if c != 0.0) or ((0.0, None),)
                    out.append(Linear(terms))
                elif isinstance(a, str):  # a cuboid ref
                    out.append(Name(a))
                else:  # a face, axis or bool: Literal or a parameter's Name
                    out.append(a)
            self.calls.append(Call(func, tuple(out), tuple(rets)))
            return
        forms, vals = [], []
        for a in args:
            if isinstance(a, dict):
                f = Affine(a.get(None, 0.0), tuple((i, c) for i, c in a.items() if i is not None))
                forms.append(f)
                vals.append(f.evaluate(self.values))
            else:
                vals.append(a.value if isinstance(a, Literal) else a)
        if func == "Cuboid":
            ln = CuboidLine(*vals)
        elif func == "attach":
            ln = AttachLine(*vals)
        elif func == "squeeze":
            ln = SqueezeLine(*vals)
        elif func == "reflect":
            ln = ReflectLine(*vals)
        else:
            n = vals[1]
            if not (math.isfinite(n) and abs(n - round(n)) <= 1e-6 and 1 <= round(n) <= limits.MAX_TRANSLATE_COPIES):
                raise MacroError(f"translate count {n!r} is not a whole number from 1 to "
                                 f"{limits.MAX_TRANSLATE_COPIES}", None, self.index)
            ln = TranslateLine(vals[0], int(round(n)), vals[2])
        self.lines.append(ln)
        self.floats.append(tuple(forms))
        self.source.append(self.index)


class Library:
    """The base functions plus macros, in definition order (see the module docstring).

    Args:
        macros: definitions, each checked against the functions before it.

    Raises:
        MacroError: a definition is invalid or reuses a name.
    """

    def __init__(self, macros: Iterable[MacroDef] = ()):
        self._functions: dict[str, Function] = {n: Function(i) for n, i in BASE.items()}
        self._macros: list[MacroDef] = []
        self._expanded: dict[str, MacroDef] = {}
        for m in macros:
            if m.name in self._functions:
                raise MacroError(f"function {m.name!r} is already defined", m.name)
            info = check_def(m, self.infos())
            self._functions[m.name] = Function(info, m)
            self._macros.append(m)

    # -- container
    @property
    def macros(self) -> tuple[MacroDef, ...]:
        """The macro definitions (base functions excluded), in order."""
        return tuple(self._macros)

    def infos(self) -> dict[str, FunctionInfo]:
        """Name -> :class:`~shapeprog.macros.lang.FunctionInfo` of every function (for the parser)."""
        return {n: f.info for n, f in self._functions.items()}

    def __getitem__(self, name: str) -> Function:
        try:
            return self._functions[name]
        except KeyError:
            raise KeyError(f"no function {name!r} in the library") from None

    def __contains__(self, name: object) -> bool:
        return name in self._functions

    def __iter__(self) -> Iterator[str]:
        return iter(self._functions)

    def __len__(self) -> int:
        """|L|: the number of functions, the five base functions included."""
        return len(self._functions)

    def __repr__(self) -> str:
        """One line: the macro count and the first names (``to_text()`` prints the definitions)."""
        names = [m.name for m in self._macros]
        shown = ", ".join(names[:8]) + (f", ... ({len(names) - 8} more)" if len(names) > 8 else "")
        return f"Library({len(names)} macros{': ' + shown if names else ''})"

    def add(self, *macros: MacroDef) -> "Library":
        """A new library with ``macros`` appended."""
        return Library(self._macros + list(macros))

    def with_program(self, program: MacroProgram) -> "Library":
        """This library plus the program's own definitions (those it already holds, unchanged, are
        not added again)."""
        new = []
        for d in program.defs:
            f = self._functions.get(d.name)
            if f is None:
                new.append(d)
            elif f.definition != d:
                raise MacroError(f"the program redefines {d.name!r}, which the library defines differently", d.name)
        return self.add(*new) if new else self

    # -- text
    def to_text(self) -> str:
        """The macros as text (definitions separated by blank lines)."""
        return "\n".join(def_text(m) for m in self._macros)

    @classmethod
    def from_text(cls, text: str, file: str = "<string>", base: "Library | None" = None) -> "Library":
        """A library from a text of definitions only (after the macros of ``base``, if given)."""
        base = Library() if base is None else base
        program, _, _ = _parse(text, file, base.infos(), program=False)
        return base.add(*program.defs)

    def parse(self, text: str, file: str = "<string>", check: bool = True) -> MacroProgram:
        """Parse a macro program that may call this library's functions and check that it expands.

        Args:
            text: the program text.
            file: a name used in error messages.
            check: also expand the program, so that value errors are reported here (False: only
                syntax, names and types are checked).

        Raises:
            ParseError: at the offending line and token (syntax, names, types, and expansion errors
                such as an attach to its own subject or a fractional translate count).
        """
        if not check:
            return _parse(text, file, self.infos())[0]
        return self.parse_expanded(text, file)[0]

    def parse_expanded(self, text: str, file: str = "<string>") -> tuple:
        """``(program, expansion)``: :meth:`parse` with its check, and the :meth:`expand` it made.

        Raises:
            ParseError: as :meth:`parse`.
        """
        program, where, _ = _parse(text, file, self.infos())
        try:
            return program, self.expand(program)
        except MacroError as e:
            line, toks, fn, _, _ = where[(None, e.index)]
            tok = toks[e.arg] if e.arg is not None and e.arg < len(toks) else fn
            raise ParseError(e.reason, file, line, tok[2], tok[1]) from None

    # -- expansion
    def expand_macro(self, name: str) -> MacroDef:
        """The macro ``name`` with a body of base calls only (same parameters).

        Float arguments are linear expressions over its float parameters and ``bb_x/bb_y/bb_z``;
        the cuboids it creates are named ``c0``, ``c1``, ... (with ``_`` appended on a clash).
        """
        if name in self._expanded:
            return self._expanded[name]
        f = self[name]
        if f.is_base:
            args = tuple(Linear.var(p.name) if p.type == FLOAT else Name(p.name) for p in f.params)
            return MacroDef(name, f.params, (Call(name, args, ("c0",) if name == "Cuboid" else ()),))
        env: dict = {b: {b: 1.0} for b in BB_DIMS}
        for p in f.params:
            env[p.name] = {p.name: 1.0} if p.type == FLOAT else Name(p.name) if p.type != CUBE else p.name
        sink = _Sink(False, reserved=[p.name for p in f.params])
        self._inline(f.definition.body, env, sink)
        out = MacroDef(name, f.params, tuple(sink.calls))
        self._expanded[name] = out
        return out

    def _inline(self, calls: Sequence[Call], env: dict, sink: _Sink, top: bool = False) -> list:
        """Inline ``calls`` into ``sink``; ``env`` maps parameter names (and bb dims) to values: float ->
        {variable: coefficient}, cube -> a sink cuboid ref, face/axis/bool -> Literal or Name."""
        local: dict = {}
        created: list = []
        for i, call in enumerate(calls):
            if top:
                sink.index = i
            f = self._functions[call.func]
            vals = []
            for a, p in zip(call.args, f.params):
                if p.type == FLOAT:
                    acc: dict = {}
                    for c, v in a.terms:
                        if v is None:
                            acc[None] = acc.get(None, 0.0) + c
                        else:
                            for v2, c2 in env[v].items():
                                acc[v2] = acc.get(v2, 0.0) + c * c2
                    vals.append(acc)
                elif p.type == CUBE:
                    n = a.name
                    vals.append(sink.bbox_ref if n == "bbox" else local[n] if n in local else env[n])
                else:
                    vals.append(a if isinstance(a, Literal) else env[a.name])
            if f.is_base:
                if top and i == 0:
                    rets = []  # the bbox line creates no cuboid id
                else:
                    rets = [sink.new_cube()] if call.func == "Cuboid" else []
                sink.emit(call.func, vals, rets if not sink.numeric else ())
            else:
                cenv = {b: env[b] for b in BB_DIMS}
                cenv.update({p.name: v for p, v in zip(f.params, vals)})
                rets = self._inline(f.definition.body, cenv, sink)
            for name, ref in zip(call.rets if not (top and i == 0) else (), rets):
                local[name] = ref
            created += rets
        return created

    def expand(self, program: MacroProgram) -> Expansion:
        """Expand ``program`` (its own definitions added to this library) into base lines.

        Raises:
            MacroError: a line that does not expand to an executable sequence, at its program line
                (``index``), e.g. an attach to its own subject or a fractional translate count.
        """
        lib = self.with_program(program)
        check_program(MacroProgram((), program.lines), lib.infos())
        values = [a.value for c in program.lines for a in c.args if isinstance(a, Linear)]
        # every program number is parameter k; the bbox dims are parameters 0, 1, 2
        env: dict = {b: {k: 1.0} for k, b in enumerate(BB_DIMS)}
        k = 0
        lines = []
        for c in program.lines:
            args = []
            for a in c.args:
                if isinstance(a, Linear):
                    args.append(Linear(((1.0, f"#{k}"),)))
                    env[f"#{k}"] = {k: 1.0}
                    k += 1
                else:
                    args.append(a)
            lines.append(Call(c.func, tuple(args), c.rets))
        sink = _Sink(True, values)
        lib._inline(lines, env, sink, top=True)
        try:
            check_lines(sink.lines)
        except LineError as e:
            raise MacroError(e.reason, None, sink.source[e.index]) from None
        names = []
        for c in program.lines[1:]:
            names += c.rets
        return Expansion(tuple(sink.lines), tuple(sink.floats), tuple(sink.source), tuple(names))

    def inline(self, program: MacroProgram) -> MacroProgram:
        """``program`` with every macro call replaced by base calls (no definitions; the same names and
        numbers as :meth:`expand`)."""
        e = self.expand(program)
        return from_lines(e.lines, e.names)


def as_macro_program(program, library: Library | None = None, call: str = "this function") -> MacroProgram:
    """``program`` as a :class:`~shapeprog.macros.lang.MacroProgram`: a MacroProgram as it is, a ``str`` parsed
    with ``library`` (:meth:`Library.parse`).

    Raises:
        TypeError: anything else, naming ``call`` and the call to make first (a ShapeAssembly program is
            refactored with :func:`shapeprog.macros.refactor`; a refactored result is expanded with
            :func:`shapeprog.macros.expand` or its root block taken as ``result.program``).
        ParseError: text that is not a macro program of ``library``.
    """
    if isinstance(program, MacroProgram):
        return program
    if isinstance(program, str):  # it may carry definitions that repeat the library's (a refactored block)
        return _parse_block(program, "<string>", Library() if library is None else library)[0]
    name = type(program).__name__
    if name == "Program":
        hint = ("a ShapeAssembly program: rewrite it with macros first (shapeprog.macros.refactor(program, library)), "
                "or run it with shapeprog.execute(program)")
    elif name in ("Refactored", "MacroHierarchy"):
        hint = (f"a hierarchical {name}: shapeprog.macros.expand(result, library) gives the whole base program; "
                "result.program is the root block's macro program")
    else:
        hint = "make one with shapeprog.macros.parse(text, library)"
    raise TypeError(f"{call} takes a MacroProgram or its text, got {name}: {hint}")


def parse(text: str, library: Library | None = None, file: str = "<string>") -> MacroProgram:
    """Parse a macro program that may call ``library``'s functions (:meth:`Library.parse`)."""
    return (Library() if library is None else library).parse(text, file)


def _parse_block(body: str, file: str, lib) -> tuple:
    """``(program, expansion)`` of one block: on its own (it carries its definitions, which may repeat the
    library's), else with the library's functions."""
    try:
        program, exp = Library().parse_expanded(body, file)
    except ParseError:
        return lib.parse_expanded(body, file)
    try:
        lib.with_program(program)  # the same definitions as the library's: the same expansion
    except MacroError as e:
        d = next(k for k, d in enumerate(program.defs) if d.name == e.macro)
        line = 1 + sum(x.count("\n") + 1 for x in map(def_text, program.defs[:d]))
        raise ParseError(e.reason, file, line, 5, e.macro) from None
    return program, exp
