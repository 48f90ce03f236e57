"""The CSG language of CSGNet: tokens, programs, parsing, printing and validity.

A program is a postfix sequence of tokens. A draw token pushes a primitive, an operator pops two
shapes and pushes their combination; the result is the top of the stack at the end.

Text formats (the spec's section (a); the primitives are the rows of :mod:`csgnet.primitives`):

* 2D: ``c(x,y,r)`` circle, ``s(x,y,r)`` square, ``t(x,y,r)`` triangle.
* 3D: ``sp(x,y,z,r)`` sphere, ``cu(x,y,z,r)`` cube, ``cy(x,y,z,r,h)`` cylinder, or the vocabulary's
  truncated forms ``p(...)``, ``u(...)``, ``y(...)``; both parse to the same program.
* Operators ``+`` (union), ``*`` (intersection), ``-`` (subtraction, earlier minus later); ``$`` stops.

Parsing is strict where the reference parser was silent: an unknown character, an unknown primitive,
a wrong number of parameters, a non-integer parameter, a negative radius and (with ``strict=True``) a
stack underflow or an unfinished stack raise :class:`ParseError`, which names the program, the token and
its 0-based character position. Whitespace between tokens is ignored, and everything after the first
``$`` is dropped, as for network output. Unlike the reference, positions may be negative integers
(``c(-4,10,12)``): such shapes are clipped to the canvas. Radii and heights must be non-negative.
Parameters are ASCII decimal integers of magnitude at most :data:`MAX_PARAM`, and a program has at
most :data:`MAX_TOKENS` tokens (docs/csgnet.md, "The language").

This module needs only the standard library and the table of :mod:`csgnet.primitives` (NumPy).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence, Union

from . import primitives as P

__all__ = [
    "ParseError",
    "Draw",
    "Op",
    "Program",
    "Node",
    "parse",
    "parse_lines",
    "to_text",
    "is_valid",
    "prefix_status",
    "split_tokens",
    "draw_token",
    "OPERATORS",
    "STOP",
    "MAX_PARAM",
    "MAX_TOKENS",
]

STOP = "$"
OPERATORS = {"+": "union", "*": "intersect", "-": "subtract"}
MAX_PARAM = 1000
"""Largest magnitude of a primitive parameter (the canvas is 64 cells; the grammar uses 8..56)."""
MAX_TOKENS = 1024
"""Most tokens in one program (the paper's programs have at most 13)."""


class ParseError(ValueError):
    """A program text that is not a valid CSG program.

    Attributes:
        program: the text being parsed.
        position: 0-based character offset of the offending token (``None`` if not applicable).
        token: the offending token text.
        file: the file the program came from, if any.
        line: the 1-based line in ``file``, if any.
    """

    def __init__(self, message: str, program: str = "", position: int | None = None,
                 token: str | None = None, file: str | None = None, line: int | None = None):
        self.reason = message
        self.program = program
        self.position = position
        self.token = token
        self.file = file
        self.line = line
        super().__init__(self._format())

    def _format(self) -> str:
        where = ""
        if self.file is not None:
            where = f"{self.file}:{self.line}:" if self.line is not None else f"{self.file}:"
            if self.position is not None:
                where += f"{self.position + 1}:"
            where += " "
        elif self.position is not None:
            where = f"at character {self.position}: "
        text = f"{where}{self.reason}"
        if self.token is not None:
            text += f" (token {self.token!r})"
        if self.program:
            shown = self.program if len(self.program) <= 200 else self.program[:197] + "..."
            text += f" in program {shown!r}"
        return text

    def located(self, file: str, line: int) -> "ParseError":
        """The same error, attributed to ``file`` at 1-based ``line``."""
        return ParseError(self.reason, self.program, self.position, self.token, file, line)


@dataclass(frozen=True)
class Draw:
    """A primitive. ``kind`` is the vocabulary letter (``c s t`` in 2D, ``p u y`` in 3D)."""

    kind: str
    params: tuple[int, ...]

    def __post_init__(self):
        try:
            row = P.primitive(self.kind)
        except KeyError as e:
            raise ValueError(e.args[0]) from None
        if len(self.params) != len(row.params):
            raise ValueError(f"{row.name} takes {len(row.params)} parameters {row.params}, got {len(self.params)}")
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in self.params):
            raise ValueError(f"{row.name} parameters must be integers, got {self.params}")
        if any(abs(v) > MAX_PARAM for v in self.params):
            raise ValueError(f"{row.name} parameters must be within ±{MAX_PARAM}, got {self.params}")

    @property
    def dim(self) -> int:
        return P.primitive(self.kind).dim

    @property
    def name(self) -> str:
        return P.primitive(self.kind).name

    def text(self, long: bool = True) -> str:
        """``c(32,32,8)``; in 3D ``sp(...)`` (``long=True``) or the vocabulary form ``p(...)``."""
        return f"{P.primitive(self.kind).head(long)}({','.join(str(v) for v in self.params)})"


@dataclass(frozen=True)
class Op:
    """A boolean operator: ``+`` union, ``*`` intersection, ``-`` subtraction (earlier minus later)."""

    op: str

    def __post_init__(self):
        if self.op not in OPERATORS:
            raise ValueError(f"unknown operator {self.op!r}; expected one of {list(OPERATORS)}")

    def text(self, long: bool = True) -> str:
        return self.op


Token = Union[Draw, Op]


@dataclass(frozen=True)
class Node:
    """A CSG tree node: ``op`` applied to ``left`` (earlier operand) and ``right`` (later operand)."""

    op: str
    left: "Node | Draw"
    right: "Node | Draw"


@dataclass(frozen=True)
class Program:
    """A postfix CSG program.

    Attributes:
        tokens: the postfix tokens (no stop symbol).
        dim: 2 or 3.
    """

    tokens: tuple[Token, ...]
    dim: int = 2

    def __post_init__(self):
        if self.dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {self.dim}")
        for t in self.tokens:
            if isinstance(t, Draw) and t.dim != self.dim:
                raise ValueError(f"{t.name} is a {t.dim}D primitive in a {self.dim}D program")
            if not isinstance(t, (Draw, Op)):
                raise TypeError(f"program tokens must be Draw or Op, got {type(t).__name__}")
        if len(self.tokens) > MAX_TOKENS:
            raise ValueError(f"a program has at most {MAX_TOKENS} tokens, got {len(self.tokens)}")

    def __len__(self) -> int:
        return len(self.tokens)

    def __iter__(self) -> Iterator[Token]:
        return iter(self.tokens)

    @property
    def draws(self) -> tuple[Draw, ...]:
        return tuple(t for t in self.tokens if isinstance(t, Draw))

    def with_params(self, values) -> "Program":
        """The same structure with the draws' parameters replaced, in program order, by the integers of
        the flat sequence ``values`` (each draw takes as many as it has)."""
        values = [int(v) for v in values]
        need = sum(len(d.params) for d in self.draws)
        if len(values) != need:
            raise ValueError(f"{need} parameter values needed, got {len(values)}")
        toks, i = [], 0
        for t in self.tokens:
            if isinstance(t, Draw):
                toks.append(Draw(t.kind, tuple(values[i:i + len(t.params)])))
                i += len(t.params)
            else:
                toks.append(t)
        return Program(tuple(toks), self.dim)

    @property
    def is_valid(self) -> bool:
        """Every prefix has more draws than operators and the stack ends with one shape."""
        return is_valid(self)

    def text(self, long: bool = True) -> str:
        """The program text (no ``$``). In 3D, ``long=False`` gives the vocabulary form ``p(...)``."""
        return "".join(t.text(long) for t in self.tokens)

    def __str__(self) -> str:
        return self.text()

    def depth(self) -> int:
        """The maximum stack depth reached while executing (valid or not)."""
        d = best = 0
        for t in self.tokens:
            d = d + 1 if isinstance(t, Draw) else d - 1
            best = max(best, d)
        return best

    def tree(self) -> "Node | Draw":
        """The program as a CSG tree. Raises ``ValueError`` for an invalid program."""
        stack: list = []
        for i, t in enumerate(self.tokens):
            if isinstance(t, Draw):
                stack.append(t)
            else:
                if len(stack) < 2:
                    raise ValueError(f"stack underflow at token {i} ({t.op!r}) of {self.text()!r}")
                b = stack.pop()
                a = stack.pop()
                stack.append(Node(t.op, a, b))
        if len(stack) != 1:
            raise ValueError(f"program {self.text()!r} leaves {len(stack)} shapes on the stack")
        return stack[0]

    @staticmethod
    def from_tree(tree: "Node | Draw") -> "Program":
        """The postfix program of a CSG tree."""
        out: list[Token] = []

        def walk(n):
            if isinstance(n, Draw):
                out.append(n)
            else:
                walk(n.left)
                walk(n.right)
                out.append(Op(n.op))

        walk(tree)
        dim = out[0].dim if out else 2
        return Program(tuple(out), dim)


def to_text(program: Program, long: bool = True) -> str:
    """The text of ``program`` (see :meth:`Program.text`)."""
    return program.text(long)


# ---------------------------------------------------------------------------------------------
# validity

def _scan(tokens: Sequence[Token | str]) -> tuple[int | None, int, int]:
    """Run the validity automaton over ``tokens``.

    Returns:
        ``(underflow, draws, ops)``: the index of the first operator that lacks two operands (``None``
        if there is none; the scan stops there) and the draws and operators counted up to it.
    """
    draws = ops = 0
    for i, t in enumerate(tokens):
        if isinstance(t, Draw) or t == "d":
            draws += 1
        else:
            ops += 1
            if draws <= ops:
                return i, draws, ops
    return None, draws, ops


def prefix_status(tokens: Sequence[Token | str]) -> str:
    """Classify a token prefix: ``"invalid"`` (some operator lacks two operands), ``"complete"`` (one
    shape on the stack) or ``"open"`` (valid so far, more than one shape on the stack, or empty).

    Tokens may be :class:`Draw`/:class:`Op` or type letters (``"d"`` for a draw, an operator char).
    """
    underflow, draws, ops = _scan(tokens)
    if underflow is not None:
        return "invalid"
    return "complete" if draws > 0 and draws - 1 == ops else "open"


def completable(depth, remaining):
    """Which kinds of token keep a program completable within a length limit.

    With ``depth`` shapes on the stack and ``remaining`` tokens allowed (the next one included), a valid
    program can still be finished after a draw iff ``depth <= remaining - 1`` (the operators needed to
    reduce the stack must fit), after an operator iff ``depth >= 2``, and by ``$`` iff ``depth == 1``.
    This holds in every state reached by following the rule from the empty stack. Elementwise on ints,
    NumPy arrays and torch tensors (decoders and environments mask with it).

    Returns:
        ``(draw_ok, op_ok, stop_ok)``.
    """
    return depth <= remaining - 1, depth >= 2, depth == 1


def is_valid(program: Program | Sequence[Token]) -> bool:
    """The spec's whole-expression check: every prefix has D > O and D - 1 = O at the end.

    An empty program is invalid. Invalid programs render as an empty canvas.
    """
    tokens = program.tokens if isinstance(program, Program) else program
    return len(tokens) > 0 and prefix_status(tokens) == "complete"


# ---------------------------------------------------------------------------------------------
# parsing

_TOKEN_RE = re.compile(
    r"\s+"  # whitespace (ignored)
    r"|(?P<op>[+*\-])"
    r"|(?P<stop>\$)"
    r"|(?P<head>[A-Za-z_]+)\((?P<args>[^()]*)\)"
    r"|(?P<bad>[A-Za-z_]+\(?[^()+*$\-]*|.)"
)
_INT_RE = re.compile(r"[+-]?[0-9]+")  # ASCII digits only (\d would also take '٣')
# The fast path: a text (before its first ``$``) that is whitespace, draw tokens and operators only.
_WELL_FORMED = re.compile(r"(?:\s*(?:[A-Za-z_]+\([^()]*\)|[+*\-]))*\s*")
_PIECE = re.compile(r"[A-Za-z_]+\([^()]*\)|[+*\-]")
_OP_TOKENS = {o: Op(o) for o in OPERATORS}
_DRAWS: dict = {}  # (dim, token text) -> Draw, or None for a token the slow path must explain
_CACHE_MAX = 1 << 17


@P.on_change
def _clear_caches() -> None:
    _DRAWS.clear()


def split_tokens(text: str) -> list[str] | None:
    """The token texts of ``text`` up to its first ``$`` (``["c(32,32,8)", "s(8,8,8)", "+"]``), or None
    if that part holds anything else than whitespace, ``head(args)`` tokens and operators (then only
    :func:`parse` can say what is wrong). Heads and arguments are not checked here."""
    end = text.find(STOP)
    body = text if end < 0 else text[:end]
    if not _WELL_FORMED.fullmatch(body):
        return None
    return _PIECE.findall(body)


def draw_token(token: str, dim: int) -> Draw | None:
    """The :class:`Draw` of one well-formed token text of a ``dim``-D program (cached), or None if the
    token is not a valid ``dim``-D primitive (:func:`parse` then raises the located error)."""
    key = (dim, token)
    try:
        return _DRAWS[key]
    except KeyError:
        pass
    head, _, rest = token.partition("(")
    row = P.by_name(head)
    draw = None
    if row is not None and row.dim == dim:
        try:
            draw = Draw(row.kind, _parse_args(rest[:-1], head, row, "", 0))
        except ParseError:
            draw = None
    if len(_DRAWS) >= _CACHE_MAX:
        _DRAWS.clear()
    _DRAWS[key] = draw
    return draw


def _fast_tokens(text: str, dim: int) -> list[Token] | None:
    """The tokens of ``text`` from the cached per-token objects, or None where :func:`parse`'s full
    scan is needed (a malformed or unknown token)."""
    pieces = split_tokens(text)
    if pieces is None or len(pieces) > MAX_TOKENS:  # too long: the full scan stops at the limit and says where
        return None
    out = []
    for piece in pieces:
        t = _OP_TOKENS.get(piece) or _DRAWS.get((dim, piece)) or draw_token(piece, dim)
        if t is None:
            return None
        out.append(t)
    return out


def _known(dim: int) -> str:
    """The primitive names of ``dim`` for an error message: ``c, s, t``; ``sp, cu, cy (or p, u, y)``."""
    rows = P.primitives(dim)
    short = [r.kind for r in rows if r.long]
    return ", ".join(r.head() for r in rows) + (f" (or {', '.join(short)})" if short else "")


def _parse_args(args: str, head: str, row: P.Primitive, text: str, pos: int):
    parts = args.split(",")
    token = f"{head}({args})"
    name, names = row.name, row.params
    if len(parts) != len(names):
        raise ParseError(
            f"{name} takes {len(names)} parameters ({','.join(names)}), got {len(parts)}",
            text, pos, token)
    values = []
    for pname, part in zip(names, parts):
        s = part.strip()
        if not _INT_RE.fullmatch(s):
            what = "missing" if s == "" else f"non-integer {s!r}"
            raise ParseError(f"{name} parameter {pname} is {what}: parameters are integers", text, pos, token)
        v = int(s) if len(s) <= 12 else MAX_PARAM + 1  # never convert a huge digit string
        if abs(v) > MAX_PARAM:
            shown = s if len(s) <= 12 else s[:9] + "..."
            raise ParseError(f"{name} parameter {pname} is {shown}: parameters are within ±{MAX_PARAM}",
                             text, pos, token)
        if v < 0 and pname in row.sizes:
            raise ParseError(f"{name} parameter {pname} must be >= 0, got {v}", text, pos, token)
        values.append(v)
    return tuple(values)


_SHAPE_FILE = re.compile(r"\.(png|jpe?g|bmp|gif|tiff?|webp|npy|obj|ply|stl|off|glb|gltf)$", re.IGNORECASE)


def _refuse_file_name(text: str) -> None:
    """A shape file's name given as program text gets an error that says which call reads shapes."""
    if _SHAPE_FILE.search(text.strip()):
        raise ParseError(f"{text.strip()!r} is a shape file's name, not program text: csgnet.parse reads "
                         f"programs; csgnet.parse_shape({text.strip()!r}) infers a program for a shape file",
                         text)


def parse(text: str, dim: int = 2, strict: bool = True) -> Program:
    """Parse a program text.

    Args:
        text: e.g. ``"c(32,32,28)c(32,32,24)-"`` or ``"sp(32,32,32,8)cu(16,16,16,12)+"``. Text after the
            first ``$`` is ignored.
        dim: 2 or 3.
        strict: if true, the program must be valid (no stack underflow, one shape left at the end,
            not empty). If false, structurally invalid programs are returned (they render empty).

    Returns:
        The :class:`Program`.

    Raises:
        ParseError: naming the token and its position.
    """
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    if not isinstance(text, str):
        raise TypeError(f"program text must be a str, got {type(text).__name__}")
    fast = _fast_tokens(text, dim)
    if fast is not None and (
            not strict or (fast and prefix_status(fast) == "complete")):
        return Program(tuple(fast), dim)
    _refuse_file_name(text)
    # the full scan: locates the first error (or accepts what the fast path could not)
    tokens: list[Token] = []
    positions: list[int] = []
    pos = 0
    n = len(text)
    while pos < n:
        m = _TOKEN_RE.match(text, pos)
        # the last alternative of _TOKEN_RE matches any character, so m is never None
        kind = next((g for g in ("op", "stop", "head", "bad") if m.group(g) is not None), None)
        if kind == "stop":
            break
        if kind in ("op", "head") and len(tokens) == MAX_TOKENS:
            raise ParseError(f"program too long: more than {MAX_TOKENS} tokens", text, pos, m.group(0))
        if kind == "op":
            tokens.append(Op(m.group("op")))
            positions.append(pos)
        elif kind == "head":
            head = m.group("head")
            row = P.by_name(head)
            if row is None or row.dim != dim:
                raise ParseError(f"unknown {dim}D primitive {head!r}; expected one of {_known(dim)}",
                                 text, pos, m.group(0))
            params = _parse_args(m.group("args"), head, row, text, pos)
            tokens.append(Draw(row.kind, params))
            positions.append(pos)
        elif kind == "bad":
            raise ParseError("malformed token", text, pos, m.group(0))
        pos = m.end()
    if strict:
        if not tokens:
            raise ParseError("empty program", text, 0 if text else None)
        underflow, draws, ops = _scan(tokens)
        if underflow is not None:
            op = tokens[underflow].op
            raise ParseError(f"stack underflow: operator {op!r} needs two shapes on the stack",
                             text, positions[underflow], op)
        if draws - 1 != ops:
            raise ParseError(f"unfinished program: {draws - ops} shapes left on the stack "
                             f"({draws - ops - 1} more operators needed)", text, len(text))
    return Program(tuple(tokens), dim)


def parse_lines(lines: Iterable[str], dim: int = 2, file: str = "<string>", strict: bool = True,
                errors: str = "raise") -> list[Program] | tuple[list[Program], list[ParseError]]:
    """Parse a dataset: one program per line, blank lines skipped.

    Args:
        errors: ``"raise"`` raises the first :class:`ParseError` (naming ``file`` and the line);
            ``"collect"`` returns ``(programs, errors)``, with every good program kept.
    """
    programs, errs = [], []
    for i, line in enumerate(lines, start=1):
        line = line.strip()
        if not line:
            continue
        try:
            programs.append(parse(line, dim, strict))
        except ParseError as e:
            err = e.located(file, i)
            if errors == "raise":
                raise err from None
            errs.append(err)
    if errors == "collect":
        return programs, errs
    return programs
