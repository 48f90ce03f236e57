"""ShapeAssembly: the language (AST, parser, printer). Standard library only.

:func:`parse` reads the corpus format (``Assembly Program_<m> { ... }`` blocks) or the flat single-block
format into a :class:`Program`, whose :class:`Block` objects hold the statements (:class:`Cuboid`,
:class:`Attach`, :class:`Squeeze`, :class:`Reflect`, :class:`Translate`); errors are :class:`ParseError`
naming ``file:line:col``. :func:`to_text` prints the format that was parsed, numbers with ``repr``, so
``to_text(parse(text)) == text`` byte for byte for every corpus file.

See docs/shapeassembly.md ("Language") for the formats, the statements and the parsing rules.

Example:
    >>> p = parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.1, 0.5, True)\\n"
    ...           "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> p.flat, len(p.root.statements), p.root.statements[2].b
    (True, 3, 'bbox')
    >>> to_text(p) == "bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.1, 0.5, True)\\n" \\
    ...     "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n"
    True
"""
from __future__ import annotations

import dataclasses
import re
import warnings
from typing import Iterator, Sequence

from . import limits
from .errors import ParseError, ParseWarning
from .syntax import (  # noqa: F401 - the names of syntax are this module's too (__all__)
    AXES, Attach, Block, CORPUS_DECIMALS, Cuboid, FACES, NUM_FIELDS, Program, Reflect, Squeeze, Statement,
    Translate,
)
from .syntax import __all__ as _LOWER_NAMES

__all__ = [*_LOWER_NAMES, "ParseError", "ParseWarning", "as_program", "parse", "statement_lines", "to_text"]


def as_program(program, call: str = "this function") -> Program:
    """``program`` as a :class:`Program`: a Program as it is, a ``str`` parsed with :func:`parse`.

    Raises:
        TypeError: anything else, naming ``call`` and the call that makes a program.
        ParseError: text that is not a ShapeAssembly program.
    """
    if isinstance(program, Program):
        return program
    if isinstance(program, str):
        return parse(program)
    hint = ""
    name = type(program).__name__
    if name in ("MacroProgram", "Refactored", "MacroHierarchy"):
        hint = "; a macro program becomes a ShapeAssembly program with shapeprog.macros.expand(program, library)"
    elif hasattr(program, "read_text"):
        hint = "; read the file first (shapeprog.parse(path.read_text(), str(path)))"
    elif isinstance(program, (bytes, bytearray)):
        hint = "; decode the bytes first (text.decode('utf-8'))"
    raise TypeError(f"{call} takes a shapeprog Program or its text, got {name}: make one with "
                    f"shapeprog.parse(text){hint}")


# --------------------------------------------------------------------------- printer


def _num(x: float, decimals: int | None) -> str:
    if decimals is not None:
        x = round(float(x), decimals)
    x = float(x)
    if x == 0.0:
        x = 0.0  # no "-0.0"
    return repr(x)


def statement_text(s: Statement, decimals: int | None = None) -> str:
    """One statement as text, without indentation or newline."""
    f = lambda x: _num(x, decimals)  # noqa: E731
    if isinstance(s, Cuboid):
        return f"{s.name} = Cuboid({f(s.l)}, {f(s.h)}, {f(s.w)}, {s.aligned})"
    if isinstance(s, Attach):
        nums = ", ".join(f(v) for v in (s.x1, s.y1, s.z1, s.x2, s.y2, s.z2))
        return f"attach({s.a}, {s.b}, {nums})"
    if isinstance(s, Squeeze):
        return f"squeeze({s.a}, {s.b}, {s.c}, {s.face}, {f(s.u)}, {f(s.v)})"
    if isinstance(s, Reflect):
        return f"reflect({s.a}, {s.axis})"
    if isinstance(s, Translate):
        return f"translate({s.a}, {s.axis}, {int(s.n)}, {f(s.d)})"
    raise TypeError(f"not a ShapeAssembly statement: {type(s).__name__}")


def to_text(program: Program, decimals: int | None = None) -> str:
    """Print ``program`` in its format (corpus or flat); ``decimals`` rounds every number.

    Numbers are written as ``repr(float)``, so parsed corpus files come back byte for byte.
    """
    program = as_program(program, "shapeprog.to_text")
    out = []
    if program.flat:
        for s in program.root.statements:
            out.append(statement_text(s, decimals) + "\n")
        return "".join(out)
    for b in program.blocks:
        out.append(f"Assembly {b.name} {{\n")
        for s in b.statements:
            out.append("\t" + statement_text(s, decimals) + "\n")
        out.append("}\n")
    return "".join(out)


def statement_lines(program: Program) -> list[list[int]]:
    """0-based file line index of every statement, per block (as printed by :func:`to_text`)."""
    res, line = [], 0
    for b in program.blocks:
        if not program.flat:
            line += 1  # "Assembly ... {"
        res.append(list(range(line, line + len(b.statements))))
        line += len(b.statements) + (0 if program.flat else 1)
    return res


# ---------------------------------------------------------------------------- parser

_TOKEN = re.compile(
    r"\s*(?:(?P<num>[+-]?(?:[0-9]+\.[0-9]*|\.[0-9]+|[0-9]+)(?:[eE][+-]?[0-9]+)?)|(?P<name>[A-Za-z_][A-Za-z_0-9]*)"
    r"|(?P<punct>[(),={}])|(?P<bad>\S))"
)
_HEADER = re.compile(r"^Assembly\s+(Program_\d+)\s*\{\s*$")
_ARGS = {
    "Cuboid": ("num", "num", "num", "bool"),
    "attach": ("name", "name") + ("num",) * 6,
    "squeeze": ("name", "name", "name", "face", "num", "num"),
    "reflect": ("name", "axis"),
    "translate": ("name", "axis", "int", "num"),
}


class _Line:
    def __init__(self, text: str, file: str, lineno: int):
        self.text, self.file, self.lineno = text, file, lineno
        self.toks: list[tuple[str, str, int]] = []  # (kind, text, col)
        for m in _TOKEN.finditer(text):
            kind = m.lastgroup
            if kind is None:
                break
            self.toks.append((kind, m.group(kind), m.start(kind) + 1))
        self.i = 0

    def error(self, reason: str, tok: tuple[str, str, int] | None = None) -> ParseError:
        if tok is None:
            tok = self.toks[self.i] if self.i < len(self.toks) else ("end", "", len(self.text) + 1)
        return ParseError(reason, self.file, self.lineno, tok[2], tok[1])

    def peek(self):
        return self.toks[self.i] if self.i < len(self.toks) else None

    def take(self, kind: str | None = None, text: str | None = None, what: str = ""):
        t = self.peek()
        if t is None:
            raise self.error(f"expected {what or text or kind} at end of line")
        if (kind and t[0] != kind) or (text and t[1] != text):
            raise self.error(f"expected {what or repr(text) if text else what or kind}, got {t[1]!r}")
        self.i += 1
        return t


def _parse_statement(ln: _Line) -> tuple[Statement, list[tuple[str, str, int]]]:
    """Syntax of one statement line; returns the statement and its name tokens."""
    first = ln.peek()
    if first is None:
        raise ln.error("empty line")
    if first[0] != "name":
        raise ln.error(f"expected a statement, got {first[1]!r}")
    decl = None
    t2 = ln.toks[1] if len(ln.toks) > 1 else None
    if t2 is not None and t2[1] == "=":
        decl = ln.take("name")
        ln.take("punct", "=")
        cmd = ln.take("name", what="'Cuboid'")
        if cmd[1] != "Cuboid":
            raise ln.error(f"unknown command {cmd[1]!r}", cmd)
    else:
        cmd = ln.take("name")
        if cmd[1] == "Cuboid":
            raise ln.error("Cuboid needs a name: 'NAME = Cuboid(...)'", cmd)
        if cmd[1] not in _ARGS:
            raise ln.error(f"unknown command {cmd[1]!r}", cmd)
    ln.take("punct", "(")
    args: list[tuple[str, str, int]] = []
    if ln.peek() is not None and ln.peek()[1] == ")":
        ln.i += 1
    else:
        while True:
            t = ln.peek()
            if t is None:
                raise ln.error("missing ')'")
            if t[0] == "punct" or t[0] == "bad":
                raise ln.error(f"expected an argument, got {t[1]!r}")
            args.append(t)
            ln.i += 1
            t = ln.take(what="',' or ')'")
            if t[1] == ")":
                break
            if t[1] != ",":
                raise ln.error(f"expected ',' or ')', got {t[1]!r}", t)
    rest = ln.toks[ln.i:]
    if rest:
        if len(rest) == 1 and rest[0][1] == ",":
            warnings.warn(
                f"{ln.file}:{ln.lineno}: ignoring a stray ',' after the statement", ParseWarning, stacklevel=4
            )
        else:
            raise ln.error(f"unexpected {rest[0][1]!r} after the statement", rest[0])
    spec = _ARGS[cmd[1]]
    if len(args) != len(spec):
        raise ln.error(f"{cmd[1]} expects {len(spec)} arguments, got {len(args)}", cmd)
    vals: list = []
    names = []
    for (kind, text, col), want in zip(args, spec):
        tok = (kind, text, col)
        if want == "num":
            if kind != "num":
                raise ln.error(f"expected a number, got {text!r}", tok)
            vals.append(limits.number(text, ln.file, ln.lineno, col))
        elif want == "int":
            if kind != "num":
                raise ln.error(f"expected a positive integer count, got {text!r}", tok)
            vals.append(limits.count(text, ln.file, ln.lineno, col))
        elif want == "bool":
            if text not in ("True", "False"):
                raise ln.error(f"expected True or False, got {text!r}", tok)
            vals.append(text == "True")
        elif want == "face":
            if text not in FACES:
                raise ln.error(f"unknown face {text!r} (expected one of {', '.join(FACES)})", tok)
            vals.append(text)
        elif want == "axis":
            if text not in AXES:
                raise ln.error(f"unknown axis {text!r} (expected X, Y or Z)", tok)
            vals.append(text)
        else:
            if kind != "name":
                raise ln.error(f"expected a cuboid name, got {text!r}", tok)
            vals.append(text)
            names.append(tok)
    if decl is not None:
        return Cuboid(decl[1], *vals), [decl]
    cls = {"attach": Attach, "squeeze": Squeeze, "reflect": Reflect, "translate": Translate}[cmd[1]]
    return cls(*vals), names


def _cuboid_names(s: Statement) -> tuple[str, ...]:
    """The cuboids a move statement names, in text order."""
    return (s.a, s.b) if isinstance(s, Attach) else (s.a, s.b, s.c) if isinstance(s, Squeeze) else (s.a,)


def block_rows(stmts: Sequence[Statement], fail, names: bool = True) -> list[tuple[list, int]]:
    """The executor's cuboid slots and attach operations of one block, with its semantic checks.

    Checks: bbox first, cuboid names well formed and known, bbox never moved, nothing attached or
    squeezed against itself. Slots, macro copy names and operations follow the executor's compile step
    (:mod:`shapeprog.compile`).

    Args:
        stmts: the block's statements (not empty).
        fail: ``fail(i, reason, k)`` raises the error of statement ``i`` at its ``k``-th cuboid name
            (the declared name for a Cuboid line).
        names: check the form of declared names (bbox, cube<k>, Program_<k>); False for programs whose
            cuboids carry other names (expanded macro programs), which execute the same way.

    Returns:
        Per statement: for each cuboid slot it creates (bbox excluded) the sub-program block placed
        there (None: a leaf), and the number of attach operations it executes to.
    """
    s0 = stmts[0]
    if not (isinstance(s0, Cuboid) and s0.name == "bbox"):
        fail(0, "a block must start with 'bbox = Cuboid(...)'", None)
    known = {"bbox": 0}  # name -> slot (macro names are cube<number of slots - 1>)
    source: list[int | None] = [None]  # per slot: the slot it is a macro copy of
    maker = [0]  # per slot: the statement that created it
    moves = [0]  # per slot: attach operations that move it (a macro copy repeats its source's)
    ops = [0] * len(stmts)  # per statement: attach operations
    lines: list[str | None] = []  # per Cuboid line: its sub-program name or None
    for si, s in enumerate(stmts):
        if isinstance(s, Cuboid):
            if names and not re.fullmatch(r"bbox|cube\d+|Program_\d+", s.name):
                fail(si, f"bad cuboid name {s.name!r} (expected bbox, cube<k> or Program_<k>)", 0)
            lines.append(s.name if s.name.startswith("Program_") else None)
            if s.name not in known:
                known[s.name] = len(source)
                source.append(None)
                maker.append(si)
                moves.append(0)
            continue
        named = _cuboid_names(s)
        for k, name in enumerate(named):
            if name not in known:
                fail(si, f"unknown cuboid {name!r}", k)
        if named[0] == "bbox":
            fail(si, f"bbox cannot be moved ({type(s).__name__.lower()} of bbox)", 0)
        if isinstance(s, Squeeze) and s.a in (s.b, s.c):
            fail(si, f"{s.a!r} cannot be squeezed against itself", 0)
        if isinstance(s, Attach) and s.a == s.b:
            fail(si, f"{s.a!r} cannot be attached to itself", 1)
        if isinstance(s, (Attach, Squeeze)):
            ops[si] = 1 if isinstance(s, Attach) else 2
            moves[known[s.a]] += ops[si]
        new = 1 if isinstance(s, Reflect) else s.n if isinstance(s, Translate) else 0
        for _ in range(new):
            name = f"cube{len(source) - 1}"
            if name in known:  # a collision re-uses the cuboid (as the executor does)
                source[known[name]] = known[s.a]
            else:
                known[name] = len(source)
                source.append(known[s.a])
                maker.append(si)
                moves.append(0)
            copied = moves[known[s.a]]
            moves[known[name]] += copied
            ops[si] += copied

    def child(k: int) -> str | None:  # as shapeprog.compile._child_of (a loop: copy chains can be long)
        while k >= len(lines):
            if source[k] is None:
                return None
            k = source[k]
        return lines[k]

    rows: list[tuple[list, int]] = [([], n) for n in ops]
    for k in range(1, len(source)):
        rows[maker[k]][0].append(child(k))
    return rows


def _check_block(stmts: list[tuple[Statement, _Line, list]], header: _Line | None, file: str) -> list:
    """Semantic checks of one block (:func:`block_rows`), errors at the offending token.

    Returns:
        One row per statement for :func:`shapeprog.limits.check_tree`: its location, and the
        statement's :func:`block_rows` row (slots, attach operations).
    """
    if not stmts:
        where = header or _Line("", file, 1)
        raise where.error("empty block")

    def fail(si: int, reason: str, k: int | None):
        _, ln, names = stmts[si]
        raise ln.error(reason, ln.toks[0] if k is None else names[k])

    rows = block_rows([s for s, _, _ in stmts], fail)
    return [((ln.lineno, ln.toks[0][2], ln.toks[0][1]), slots, n) for (_, ln, _), (slots, n) in zip(stmts, rows)]


def parse(text: str, file: str = "<string>") -> Program:
    """Parse a ShapeAssembly program (corpus or flat format).

    Args:
        text: the program text.
        file: a name used in error messages.

    Returns:
        The :class:`Program`.

    Raises:
        ParseError: with ``file:line:column: reason``; e.g. an unknown command, a wrong
            argument count, an unknown cuboid, face or axis, a missing sub-program block,
            a statement that moves bbox, or a text beyond one of the limits of
            :mod:`shapeprog.limits`.
    """
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    lines = [ln[:-1] if ln.endswith("\r") else ln for ln in lines]
    limits.check_lines(lines, file)
    first = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if first is None:
        raise ParseError("empty program", file, 1, 1, "")
    flat = not lines[first].lstrip().startswith("Assembly")
    blocks: list[tuple[_Line | None, str, list]] = []
    rows: dict = {}  # per block: (header location, rows of _check_block) for limits.check_tree
    cur = None
    for i, raw in enumerate(lines):
        lineno = i + 1
        if not raw.strip():
            continue  # blank lines are tolerated (none in the corpus)
        ln = _Line(raw, file, lineno)
        if flat:
            if cur is None:
                cur = (None, "Program_0", [])
                blocks.append(cur)
            if ln.toks and ln.toks[0][1] == "Assembly":
                raise ln.error("'Assembly' block in a flat program", ln.toks[0])
            s, names = _parse_statement(ln)
            cur[2].append((s, ln, names))
            continue
        if cur is None:
            m = _HEADER.match(raw)
            if not m:
                raise ln.error("expected 'Assembly Program_<k> {'", ln.toks[0] if ln.toks else None)
            if any(b[1] == m.group(1) for b in blocks):
                raise ln.error(f"duplicate block {m.group(1)!r}", ln.toks[1])
            if len(blocks) == limits.MAX_BLOCKS:
                raise ln.error(f"more than {limits.MAX_BLOCKS} blocks (MAX_BLOCKS)", ln.toks[1])
            cur = (ln, m.group(1), [])
            blocks.append(cur)
            continue
        if raw.strip() == "}":
            rows[cur[1]] = ((cur[0].lineno, cur[0].toks[1][2], cur[1]), _check_block(cur[2], cur[0], file))
            cur = None
            continue
        if ln.toks and ln.toks[0][1] == "Assembly":
            raise ln.error("missing '}' before the next block", ln.toks[0])
        s, names = _parse_statement(ln)
        cur[2].append((s, ln, names))
    if flat:
        rows["Program_0"] = ((first + 1, 1, ""), _check_block(cur[2], None, file))
    elif cur is not None:
        raise ParseError("missing '}' at end of file", file, len(lines), len(lines[-1]) + 1, "")
    # hierarchy: every Program_m Cuboid must have a block; every non-root block one parent.
    by_name = {b[1]: b for b in blocks}
    if not flat and blocks[0][1] != "Program_0":
        hl = blocks[0][0]
        raise hl.error("the first block must be 'Assembly Program_0'", hl.toks[1])
    parent: dict[str, str] = {}
    for hl, name, stmts in blocks:
        for s, ln, names in stmts:
            if isinstance(s, Cuboid) and s.name.startswith("Program_"):
                if s.name not in by_name:
                    raise ln.error(f"missing sub-program block 'Assembly {s.name}'", names[0])
                if s.name in parent or s.name == "Program_0" or s.name == name:
                    raise ln.error(f"sub-program {s.name!r} is declared more than once", names[0])
                parent[s.name] = name
    for hl, name, _ in blocks[1:]:
        if name not in parent:
            raise hl.error(f"block {name!r} is not used by any parent", hl.toks[1])
    # reject cycles: walk each block up to the root
    for hl, name, _ in blocks[1:]:
        seen, n = set(), name
        while n in parent:
            if n in seen:
                raise hl.error(f"block {name!r} is part of a cycle", hl.toks[1])
            seen.add(n)
            n = parent[n]
    limits.check_tree(rows, parent, file)
    return Program(tuple(Block(name, tuple(s for s, _, _ in stmts)) for _, name, stmts in blocks), flat)


def replace_numbers(program: Program, values: Iterator[float]) -> Program:
    """A copy of ``program`` whose continuous numbers are taken in order from ``values``.

    The order is the text order: per block, per statement, the numbers as they appear
    (Cuboid l,h,w; attach 6 coordinates; squeeze u,v; translate d).
    """
    it = iter(values)
    blocks = []
    for b in program.blocks:
        stmts = []
        for s in b.statements:
            fields = NUM_FIELDS[type(s)]
            if fields:
                s = dataclasses.replace(s, **{f: next(it) for f in fields})
            stmts.append(s)
        blocks.append(Block(b.name, tuple(stmts)))
    return Program(tuple(blocks), program.flat)


def round_numbers(program: Program, decimals: int = CORPUS_DECIMALS) -> Program:
    """A copy of ``program`` with every continuous number rounded to ``decimals`` (``-0.0`` becomes ``0.0``),
    so that its text is written as the corpus writes numbers and parses back to the same program."""
    return replace_numbers(program, (round(v, decimals) + 0.0 for v in numbers(program)))


def numbers(program: Program) -> list[float]:
    """The continuous numbers of ``program`` in the order used by :func:`replace_numbers`."""
    program = as_program(program, "shapeprog.lang.numbers")
    return [getattr(s, f) for b in program.blocks for s in b.statements for f in NUM_FIELDS[type(s)]]
