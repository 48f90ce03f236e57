"""The nodes of the macro language (ShapeMOD): typed parameters, linear float expressions, calls,
macro definitions and programs; their checks (:func:`check_def`, :func:`check_program`) and their text
form (:func:`to_text`, :func:`def_text`). Standard library only.

:mod:`shapeprog.macros.lang` reads the text (its docstring describes the language) and exports every
public name of this module.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Mapping, Sequence, Union

from .. import limits
from ..lang import AXES, FACES

__all__ = [
    "AXIS",
    "BASE",
    "BB_DIMS",
    "BOOL",
    "CUBE",
    "FACE",
    "FLOAT",
    "INDENT",
    "MAX_EXPANDED_LINES",
    "TYPES",
    "Arg",
    "Call",
    "FunctionInfo",
    "Linear",
    "Literal",
    "MacroDef",
    "MacroError",
    "MacroProgram",
    "Name",
    "Param",
    "check_def",
    "check_program",
    "def_text",
    "to_text",
]


FLOAT, CUBE, FACE, AXIS, BOOL = "float", "cube", "face", "axis", "bool"
#: The parameter types.
TYPES = (FLOAT, CUBE, FACE, AXIS, BOOL)
#: The bbox dims, an implicit float input of every macro body.
BB_DIMS = ("bb_x", "bb_y", "bb_z")
#: Indentation of printed macro bodies.
INDENT = "    "
#: Base lines a macro or a program may expand to (a ShapeAssembly text's line limit).
MAX_EXPANDED_LINES = limits.MAX_LINES
_RESERVED = frozenset({"def", "bbox", "True", "False", *FACES, *AXES, *BB_DIMS, *TYPES})  # parameter names
_RESERVED_CUBOIDS = frozenset({"def", "bbox", "True", "False", *BB_DIMS})  # cuboid names may be 'top', 'X'...


class MacroError(ValueError):
    """A macro or macro program that is not valid (built in code, or found while expanding).

    Attributes:
        reason: the message without the location.
        macro: the macro's name, or None for a program line.
        index: 0-based index of the offending line in the macro body or the program.
        arg: 0-based index of the offending argument, or None.
        ret: 0-based index of the offending name bound by the line (``a, b = ...``), or None.
    """

    def __init__(self, reason: str, macro: str | None = None, index: int | None = None, arg: int | None = None,
                 ret: int | None = None):
        self.reason, self.macro, self.index, self.arg, self.ret = reason, macro, index, arg, ret
        where = ("program" if macro is None else f"macro {macro!r}") + ("" if index is None else f", line {index}")
        super().__init__(f"{where}: {reason}")


# ----------------------------------------------------------------------------- AST


@dataclass(frozen=True)
class Linear:
    """A linear float expression: ``terms`` in text order, each ``(coefficient, variable)``; the
    variable None is the constant term. ``Linear(((0.6, 's'),))`` is ``0.6 * s``;
    ``Linear(((1.0, None), (-1.0, 't')))`` is ``1.0 - t``."""

    terms: tuple[tuple[float, str | None], ...]

    @classmethod
    def const(cls, value: float) -> "Linear":
        return cls(((float(value), None),))

    @classmethod
    def var(cls, name: str, coef: float = 1.0) -> "Linear":
        return cls(((float(coef), name),))

    @property
    def value(self) -> float | None:
        """The number, for a constant expression (one constant term); else None."""
        if len(self.terms) == 1 and self.terms[0][1] is None:
            return self.terms[0][0]
        return None

    def variables(self) -> list[str]:
        """The variables, in order of first appearance."""
        return list(dict.fromkeys(v for _, v in self.terms if v is not None))

    def coefficients(self) -> dict[str | None, float]:
        """Summed coefficient per variable (None: the constant)."""
        out: dict[str | None, float] = {}
        for c, v in self.terms:
            out[v] = out.get(v, 0.0) + c
        return out

    def evaluate(self, env: Mapping[str, float]) -> float:
        return sum(c * (1.0 if v is None else env[v]) for c, v in self.terms)

    def __str__(self) -> str:
        out = []
        for i, (c, v) in enumerate(self.terms):
            neg = c < 0 or (c == 0 and math.copysign(1.0, c) < 0)
            a = abs(c)
            if v is None:
                body = repr(a)
            elif a == 1.0:
                body = v
            else:
                body = f"{repr(a)} * {v}"
            if i == 0:
                out.append(("-" if neg else "") + body)
            else:
                out.append((" - " if neg else " + ") + body)
        return "".join(out)


@dataclass(frozen=True)
class Name:
    """A name used as an argument: ``bbox``, a cuboid or a parameter of a non-float type."""

    name: str

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True)
class Literal:
    """A face, axis or boolean constant."""

    value: Union[str, bool]

    def __str__(self) -> str:
        return str(self.value)


Arg = Union[Linear, Name, Literal]


@dataclass(frozen=True)
class Param:
    """A typed parameter (``type`` in :data:`TYPES`)."""

    name: str
    type: str


@dataclass(frozen=True)
class Call:
    """One line: ``rets = func(args)``; ``rets`` names the cuboids the call creates, in order."""

    func: str
    args: tuple[Arg, ...]
    rets: tuple[str, ...] = ()


@dataclass(frozen=True)
class MacroDef:
    """``def name(params): body``: a macro whose body calls base functions and earlier macros."""

    name: str
    params: tuple[Param, ...]
    body: tuple[Call, ...]


@dataclass(frozen=True)
class MacroProgram:
    """A macro program: its own macro definitions, then its lines (the first one declares the bbox)."""

    defs: tuple[MacroDef, ...]
    lines: tuple[Call, ...]

    def __repr__(self) -> str:
        """One line: its definitions and lines (``to_text(program)`` prints it)."""
        return (f"<MacroProgram: {len(self.lines)} lines, {len(self.defs)} own definitions; "
                "print with shapeprog.macros.to_text>")


@dataclass(frozen=True)
class FunctionInfo:
    """What a caller needs to know about a function (base or macro).

    Attributes:
        name: its name.
        params: its typed parameters.
        n_cuboids: the cuboids a call creates (the names it binds).
        needs_subject: its first base line acts on a cuboid declared before the call.
        structure: the base commands of its expansion, in order (e.g. ``('Cuboid', 'squeeze', 'reflect')``).
    """

    name: str
    params: tuple[Param, ...]
    n_cuboids: int
    needs_subject: bool
    structure: tuple[str, ...]


def _p(spec: str) -> tuple[Param, ...]:
    return tuple(Param(*x.split(":")) for x in spec.split())


#: The five base functions of the modified grammar.
BASE: dict[str, FunctionInfo] = {
    "Cuboid": FunctionInfo("Cuboid", _p("l:float h:float w:float aligned:bool"), 1, False, ("Cuboid",)),
    "attach": FunctionInfo("attach", _p("target:cube x1:float y1:float z1:float x2:float y2:float z2:float"), 0,
                           True, ("attach",)),
    "squeeze": FunctionInfo("squeeze", _p("t1:cube t2:cube face:face u:float v:float"), 0, True, ("squeeze",)),
    "reflect": FunctionInfo("reflect", _p("axis:axis"), 0, True, ("reflect",)),
    "translate": FunctionInfo("translate", _p("axis:axis n:float d:float"), 0, True, ("translate",)),
}


# ----------------------------------------------------------------------------- checks


def _check_name(name: str, what: str, macro, index, ret=None) -> None:
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z_0-9]*", name):
        raise MacroError(f"{what} {name!r} is not a name", macro, index, None, ret)
    if name in (_RESERVED_CUBOIDS if ret is not None else _RESERVED):
        raise MacroError(f"{what} {name!r} is a reserved word", macro, index, None, ret)


def _check_arg(arg: Arg, ptype: str, scope: Mapping[str, str], top: bool, macro, index, k) -> None:
    """One argument against its slot type; ``scope`` maps names to types (bbox included)."""
    if ptype == FLOAT:
        if not isinstance(arg, Linear) or not arg.terms:
            raise MacroError(f"expected a float expression, got {arg!s}", macro, index, k)
        for c, v in arg.terms:
            if not (isinstance(c, (int, float)) and math.isfinite(c)):
                raise MacroError(f"coefficient {c!r} is not a finite number", macro, index, k)
        if top:
            if arg.value is None:
                raise MacroError(f"a program's float arguments are numbers, got {arg!s}", macro, index, k)
            return
        for v in arg.variables():
            if v not in BB_DIMS and scope.get(v) != FLOAT:
                raise MacroError(f"{v!r} is not a float parameter", macro, index, k)
        return
    if ptype == CUBE:
        if not isinstance(arg, Name):
            raise MacroError(f"expected a cuboid, got {arg!s}", macro, index, k)
        if scope.get(arg.name) != CUBE:
            raise MacroError(f"unknown cuboid {arg.name!r}", macro, index, k)
        return
    allowed = {FACE: FACES, AXIS: AXES, BOOL: (True, False)}[ptype]
    if isinstance(arg, Literal):
        if arg.value not in allowed or isinstance(arg.value, bool) != (ptype == BOOL):
            raise MacroError(f"expected a {ptype}, got {arg!s}", macro, index, k)
        return
    if isinstance(arg, Name) and not top and scope.get(arg.name) == ptype:
        return
    raise MacroError(f"expected a {ptype}, got {arg!s}", macro, index, k)


def _check_calls(calls: Sequence[Call], scope: dict[str, str], functions: Mapping[str, FunctionInfo],
                 macro: str | None) -> tuple[int, bool, tuple[str, ...]]:
    """Type-check a body (``macro`` set) or program lines; returns (cuboids created, needs a subject,
    structure). ``scope`` is extended with the names bound."""
    top = macro is None
    n_cub, needs, structure = 0, False, []
    has_subject = False
    for i, call in enumerate(calls):
        info = functions.get(call.func)
        if info is None or (macro is not None and call.func == macro):
            raise MacroError(f"unknown function {call.func!r}", macro, i)
        if len(call.args) != len(info.params):
            raise MacroError(f"{call.func} expects {len(info.params)} arguments, got {len(call.args)}", macro, i)
        for k, (arg, p) in enumerate(zip(call.args, info.params)):
            _check_arg(arg, p.type, scope, top, macro, i, k)
        if top and i == 0:
            if call.func != "Cuboid" or call.rets != ("bbox",):
                raise MacroError("a program must start with 'bbox = Cuboid(...)'", macro, i)
        elif len(call.rets) != info.n_cuboids:
            raise MacroError(f"{call.func} creates {info.n_cuboids} cuboid(s), the line names {len(call.rets)}",
                             macro, i)
        if info.needs_subject and not has_subject:
            if top:
                raise MacroError(f"{call.func} acts on the last declared cuboid, and there is none", macro, i)
            needs = needs or n_cub == 0
        if info.n_cuboids and not (top and i == 0):
            has_subject = True
        for j, r in enumerate(call.rets if not (top and i == 0) else ()):
            _check_name(r, "cuboid name", macro, i, j)
            if r in scope:
                raise MacroError(f"name {r!r} is already used", macro, i, None, j)
            scope[r] = CUBE
        if not (top and i == 0):
            n_cub += info.n_cuboids
        structure += info.structure
        if len(structure) > MAX_EXPANDED_LINES:
            raise MacroError(f"expands to more than {MAX_EXPANDED_LINES} base lines (MAX_EXPANDED_LINES)", macro, i)
    return n_cub, needs, tuple(structure)


def check_def(defn: MacroDef, functions: Mapping[str, FunctionInfo]) -> FunctionInfo:
    """Check a macro definition against the functions it may call; returns its :class:`FunctionInfo`.

    Raises:
        MacroError: a bad name, a duplicate or reserved parameter, an unknown function (a macro may
            not call itself), a wrong argument count or type, an unknown variable, or an empty body.
    """
    _check_name(defn.name, "macro name", defn.name, None)
    if defn.name in BASE:
        raise MacroError(f"{defn.name!r} is a base function", defn.name)
    scope = {"bbox": CUBE}
    for p in defn.params:
        _check_name(p.name, "parameter", defn.name, None)
        if p.type not in TYPES:
            raise MacroError(f"unknown type {p.type!r} of parameter {p.name!r} (expected one of {', '.join(TYPES)})",
                             defn.name)
        if p.name in scope:
            raise MacroError(f"parameter {p.name!r} appears twice", defn.name)
        scope[p.name] = p.type
    if not defn.body:
        raise MacroError("empty body", defn.name)
    n, needs, structure = _check_calls(defn.body, scope, functions, defn.name)
    return FunctionInfo(defn.name, defn.params, n, needs, structure)


def check_program(program: MacroProgram, functions: Mapping[str, FunctionInfo]) -> dict[str, FunctionInfo]:
    """Check a program's definitions (in order) and lines; returns every callable function's info."""
    funcs = dict(functions)
    for d in program.defs:
        if d.name in funcs:
            raise MacroError(f"function {d.name!r} is defined twice", d.name)
        funcs[d.name] = check_def(d, funcs)
    if not program.lines:
        raise MacroError("a program needs at least its bbox line")
    _check_calls(program.lines, {"bbox": CUBE}, funcs, None)
    return funcs


# ----------------------------------------------------------------------------- printer


def _call_text(c: Call) -> str:
    head = f"{', '.join(c.rets)} = " if c.rets else ""
    return f"{head}{c.func}({', '.join(str(a) for a in c.args)})"


def def_text(d: MacroDef) -> str:
    """One definition as text (header, indented body, no trailing blank line)."""
    params = ", ".join(f"{p.name}: {p.type}" for p in d.params)
    return "\n".join([f"def {d.name}({params}):"] + [INDENT + _call_text(c) for c in d.body]) + "\n"


def to_text(program: MacroProgram) -> str:
    """The canonical text of ``program``: each definition followed by a blank line, then the lines."""
    return "".join(def_text(d) + "\n" for d in program.defs) + "".join(_call_text(c) + "\n" for c in program.lines)
