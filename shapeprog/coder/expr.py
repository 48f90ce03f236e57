"""ShapeCoder expression trees: the node types, the base-language tables, tree walks and the text form.
Standard library only.

A program is an expression tree of frozen dataclasses: :class:`Call`, :class:`Num`, :class:`Var`,
:class:`AxisConst` and :class:`IntConst`, each of one :class:`Type`. :class:`Lang` is a domain's table of
base functions (:data:`LANG_3D`, :data:`LANG_2D`); :class:`Abstraction` is a named function over typed
:class:`Param` s. :func:`to_text` writes a tree; ``_Tokens`` splits text into the tokens that
:func:`shapeprog.coder.lang.parse` reads. :mod:`shapeprog.coder.lang` adds libraries, type checking,
expansion and the parser, and exports every public name of this module.
"""
from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass, field
from typing import Iterator, Mapping, Union

from ..errors import ParseError
from . import limits

__all__ = [
    "AXES",
    "FLOAT_CONSTANTS",
    "FLOAT_FN",
    "FN",
    "LANG_2D",
    "LANG_3D",
    "Abstraction",
    "AxisConst",
    "Call",
    "Expr",
    "IntConst",
    "Lang",
    "Num",
    "Param",
    "ProgramError",
    "Signature",
    "Type",
    "Var",
    "size",
    "substitute",
    "to_text",
    "variables",
    "walk",
]


#: The axis names, in coordinate order.
AXES = ("AX", "AY", "AZ")
#: The float literals that count as constants (weight 0.5) rather than free floats (weight 2.0).
FLOAT_CONSTANTS = (0.0, 1.0, 2.0)
#: Cost kind of a shape function (base or abstraction).
FN = "fn"
#: Cost kind of a float operator.
FLOAT_FN = "float_fn"

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


class ProgramError(ValueError):
    """An expression tree that is not well-typed, an invalid abstraction or library, or a tree beyond a
    limit. The message names the offending sub-expression (its text, shortened)."""


class Type(enum.Enum):
    """The type of an expression; its value is the name used in the text form."""

    SHAPE = "Shape"
    FLOAT = "Float"
    AXIS = "Axis"
    INT = "Int"

    def __str__(self) -> str:
        return self.value

    @property
    def categorical(self) -> bool:
        """``Axis`` and ``Int`` values are categorical (cost weight 0.5)."""
        return self in (Type.AXIS, Type.INT)


_TYPES = {t.value: t for t in Type}


# ----------------------------------------------------------------------------- expression nodes


@dataclass(frozen=True)
class Num:
    """A float literal (finite, magnitude at most :data:`~shapeprog.coder.limits.MAX_ABS_NUMBER`)."""

    value: float

    def __post_init__(self):
        v = self.value
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ProgramError(f"Num needs a float, got {type(v).__name__}")
        v = float(v)
        if not math.isfinite(v) or abs(v) > limits.MAX_ABS_NUMBER:
            raise ProgramError(f"number {v!r} is out of range (limit: magnitude {limits.MAX_ABS_NUMBER}, "
                               "MAX_ABS_NUMBER)")
        object.__setattr__(self, "value", v)


@dataclass(frozen=True)
class Var:
    """A named variable: a float (``S_i_j_``, ``P_F_i_``, an abstraction parameter) or a categorical one
    (``type`` ``Axis`` or ``Int``). The text form shows only the name; the parser takes the type from the
    variable's slot."""

    name: str
    type: Type = Type.FLOAT

    def __post_init__(self):
        if not isinstance(self.name, str) or not _NAME.match(self.name):
            raise ProgramError(f"not a variable name: {self.name!r}")
        if self.name in AXES or self.name.startswith("INT#"):
            raise ProgramError(f"{self.name!r} is reserved")
        if not isinstance(self.type, Type) or self.type is Type.SHAPE:
            raise ProgramError(f"variable {self.name!r} must be Float, Axis or Int, not {self.type}")


@dataclass(frozen=True)
class AxisConst:
    """``AX``, ``AY`` or ``AZ``."""

    name: str

    def __post_init__(self):
        if self.name not in AXES:
            raise ProgramError(f"not an axis: {self.name!r}; expected one of {', '.join(AXES)}")


@dataclass(frozen=True)
class IntConst:
    """``INT#k#``, a count (1 to :data:`~shapeprog.coder.limits.MAX_COUNT`)."""

    value: int

    def __post_init__(self):
        if isinstance(self.value, bool) or not isinstance(self.value, int) \
                or not 1 <= self.value <= limits.MAX_COUNT:
            raise ProgramError(f"INT#{self.value}#: a count must be an int from 1 to {limits.MAX_COUNT} "
                               "(MAX_COUNT)")


@dataclass(frozen=True)
class Call:
    """``fn(args...)``: a base function of the domain or an abstraction of the library."""

    fn: str
    args: tuple = ()

    def __post_init__(self):
        if not isinstance(self.fn, str) or not _NAME.match(self.fn):
            raise ProgramError(f"not a function name: {self.fn!r}")
        if not isinstance(self.args, tuple):
            object.__setattr__(self, "args", tuple(self.args))

    def __repr__(self) -> str:
        """The program's text, shortened to 80 characters (``to_text`` prints it whole)."""
        return f"<{_short(self, 80)}>"


Expr = Union[Call, Num, Var, AxisConst, IntConst]


# ----------------------------------------------------------------------------- domains


@dataclass(frozen=True)
class Signature:
    """One function: its name, parameter types, return type and cost kind (:data:`FN` or
    :data:`FLOAT_FN`)."""

    name: str
    params: tuple
    returns: Type
    kind: str = FN

    @property
    def arity(self) -> int:
        return len(self.params)


@dataclass(frozen=True)
class Lang:
    """A base language (domain): its function table and its primitives.

    Attributes:
        name: ``"3d"`` or ``"2d"``.
        dim: 3 or 2 (coordinates of a part).
        functions: the base functions, shape functions first, then the float operators.
        axes: the axis names of the domain (``AX AY AZ`` or ``AX AY``).
        prim_fields: the fields of an executed primitive: ``W H D X Y Z RX RY RZ`` (3D) or ``W H X Y``.
        match_threshold: the largest primitive distance a match accepts (``of_max_error``: 0.1 / 0.05).
        max_prims: the most primitives of one scene (16 / 12; the recognition network's limit).
    """

    name: str
    dim: int
    functions: tuple
    axes: tuple
    prim_fields: tuple
    match_threshold: float
    max_prims: int
    _table: dict = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self):
        object.__setattr__(self, "_table", {s.name: s for s in self.functions})

    def signature(self, name: str) -> Signature | None:
        """The base function ``name``, or None."""
        return self._table.get(name)

    @property
    def shape_functions(self) -> tuple:
        """Names of the base functions returning a Shape (|L| of the base library counts them)."""
        return tuple(s.name for s in self.functions if s.returns is Type.SHAPE)


_S, _F, _A, _I = Type.SHAPE, Type.FLOAT, Type.AXIS, Type.INT
_FLOAT_OPS = (Signature("Add", (_F, _F), _F, FLOAT_FN), Signature("Sub", (_F, _F), _F, FLOAT_FN),
              Signature("Mul", (_F, _F), _F, FLOAT_FN), Signature("Div", (_F, _F), _F, FLOAT_FN),
              Signature("Inv", (_F,), _F, FLOAT_FN))

#: The 3D domain of the paper (PartNet cuboids).
LANG_3D = Lang(
    name="3d", dim=3,
    functions=(Signature("Cuboid", (_F, _F, _F), _S), Signature("Move", (_S, _F, _F, _F), _S),
               Signature("Rotate", (_S, _A, _F), _S), Signature("Union", (_S, _S), _S),
               Signature("SymRef", (_S, _A), _S), Signature("SymTrans", (_S, _A, _I, _F), _S)) + _FLOAT_OPS,
    axes=AXES, prim_fields=("W", "H", "D", "X", "Y", "Z", "RX", "RY", "RZ"), match_threshold=0.1, max_prims=16)

#: The 2D toy domain (axis-aligned rectangles).
LANG_2D = Lang(
    name="2d", dim=2,
    functions=(Signature("Rectangle", (_F, _F), _S), Signature("Move", (_S, _F, _F), _S),
               Signature("Union", (_S, _S), _S), Signature("SymRef", (_S, _A), _S),
               Signature("SymTrans", (_S, _A, _I, _F), _S)) + _FLOAT_OPS,
    axes=AXES[:2], prim_fields=("W", "H", "X", "Y"), match_threshold=0.05, max_prims=12)


# ----------------------------------------------------------------------------- tree utilities


def walk(expr: Expr) -> Iterator[Expr]:
    """Every node of ``expr``, in text (pre-)order."""
    stack = [expr]
    while stack:
        node = stack.pop()
        yield node
        if isinstance(node, Call):
            stack.extend(reversed(node.args))


def size(expr: Expr) -> int:
    """The number of nodes (tokens other than punctuation) of ``expr``."""
    return sum(1 for _ in walk(expr))


def variables(expr: Expr) -> dict:
    """``{name: Type}`` of the variables of ``expr``, in order of first occurrence."""
    out: dict = {}
    for node in walk(expr):
        if isinstance(node, Var):
            out.setdefault(node.name, node.type)
    return out


def substitute(expr: Expr, mapping: Mapping[str, Expr]) -> Expr:
    """``expr`` with every variable named in ``mapping`` replaced by its expression (not recursively)."""
    if isinstance(expr, Var):
        return mapping.get(expr.name, expr)
    if isinstance(expr, Call):
        args = tuple(substitute(a, mapping) for a in expr.args)
        return expr if args == expr.args else Call(expr.fn, args)
    return expr


def _fmt(value: float) -> str:
    return repr(float(value))


def to_text(expr: Expr) -> str:
    """The text form: ``Fn(a,b,...)`` without spaces, floats as ``repr``, counts as ``INT#k#``."""
    parts: list = []

    def emit(e):
        if isinstance(e, Call):
            parts.append(e.fn)
            parts.append("(")
            for i, a in enumerate(e.args):
                if i:
                    parts.append(",")
                emit(a)
            parts.append(")")
        elif isinstance(e, Num):
            parts.append(_fmt(e.value))
        elif isinstance(e, Var):
            parts.append(e.name)
        elif isinstance(e, AxisConst):
            parts.append(e.name)
        elif isinstance(e, IntConst):
            parts.append(f"INT#{e.value}#")
        else:
            raise ProgramError(f"not an expression node: {type(e).__name__}")

    emit(expr)
    return "".join(parts)


def _short(expr: Expr, n: int = 60) -> str:
    try:
        text = to_text(expr)
    except (ProgramError, RecursionError):
        return f"<{type(expr).__name__}>"
    return text if len(text) <= n else text[:n - 3] + "..."


# ----------------------------------------------------------------------------- abstractions and libraries


@dataclass(frozen=True)
class Param:
    """A parameter of an abstraction: its name and type (Float, Axis or Int)."""

    name: str
    type: Type = Type.FLOAT


@dataclass(frozen=True)
class Abstraction:
    """A named shape function ``name(params) = body``; the body uses each parameter as a :class:`Var` of
    the parameter's type, and may call the base functions and the library's earlier abstractions.

    Validated when it joins a :class:`Library` (types, every parameter used, no free variables).
    """

    name: str
    params: tuple
    body: Expr

    def __post_init__(self):
        if not isinstance(self.params, tuple):
            object.__setattr__(self, "params", tuple(self.params))

    @property
    def signature(self) -> Signature:
        return Signature(self.name, tuple(p.type for p in self.params), Type.SHAPE, FN)

    def to_text(self) -> str:
        """``Name(a: Float, b: Axis) = Body``, the form :func:`parse_abstraction` reads."""
        params = ", ".join(f"{p.name}: {p.type}" for p in self.params)
        return f"{self.name}({params}) = {to_text(self.body)}"


# ----------------------------------------------------------------------------- parsing

# One token: a count, a number, a name, or any other single non-space character (punctuation, or an error
# reported by the parser); whitespace separates tokens and is skipped.
_TOKEN = re.compile(r"INT#[0-9]*#?|[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?|[A-Za-z_][A-Za-z0-9_]*|\S")
_BAD_CHAR = re.compile(r"[^\sA-Za-z0-9_(),:=#.+\-]")
_NAME_START = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz_")
_NUM_START = frozenset("0123456789+-.")


class _Tokens:
    """The tokens of one text (strings; ``""`` marks the end), a cursor, and errors at (line, column).
    Offsets are found again only for an error, which keeps the common path fast."""

    def __init__(self, text: str, file: str, line: int, column: int):
        self.text, self.file, self.line, self.column = text, file, line, column
        if len(text) > limits.MAX_TEXT_LENGTH:
            raise self._error_at(f"text longer than {limits.MAX_TEXT_LENGTH} characters (MAX_TEXT_LENGTH)",
                                 limits.MAX_TEXT_LENGTH, text[limits.MAX_TEXT_LENGTH:limits.MAX_TEXT_LENGTH + 10])
        bad = _BAD_CHAR.search(text)
        if bad is not None:
            raise self._error_at(f"unexpected character {bad.group()!r}", bad.start(), bad.group())
        self.toks = _TOKEN.findall(text)
        self.toks.append("")
        self.last = len(self.toks) - 1
        self.i = 0
        self.spans: list | None = None  # when a list: (token index, node) of every Call and Var

    def next(self) -> int:
        i = self.i
        if i < self.last:
            self.i = i + 1
        return i

    def offset(self, i: int) -> int:
        """The offset in the text of token ``i``."""
        if i >= self.last:
            return len(self.text)
        for k, m in enumerate(_TOKEN.finditer(self.text)):
            if k == i:
                return m.start()
        raise AssertionError("token index out of range")  # pragma: no cover

    def _error_at(self, reason: str, off: int, token: str) -> ParseError:
        nl = self.text.count("\n", 0, off)
        col = off - self.text.rfind("\n", 0, off) if nl else off + self.column
        return ParseError(reason, self.file, self.line + nl, col, token)

    def error(self, reason: str, i: int) -> ParseError:
        return self._error_at(reason, self.offset(i), self.toks[i])

    def shown(self, i: int) -> str:
        return "the end of the text" if i >= self.last else repr(self.toks[i])

    def expect(self, text: str, what: str) -> int:
        i = self.next()
        if self.toks[i] != text:
            raise self.error(f"expected {what}, got {self.shown(i)}", i)
        return i
