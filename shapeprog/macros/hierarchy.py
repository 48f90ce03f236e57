"""Hierarchical macro programs: one macro program per sub-program (``Assembly`` block) of a ShapeAssembly
program, as :func:`shapeprog.macros.refactor` writes them. Standard library only (execution:
:func:`shapeprog.macros.execute.compile_hierarchy`).

The text is a sequence of blocks. A block starts with a header line ``# <key>`` whose last ``/``-separated
part is the block's name ``Program_k`` (``# chair/173/Program_1``, or just ``# Program_1``); the block's
macro program text follows (its own ``def`` s, then its lines, :func:`shapeprog.macros.lang.to_text`),
then a blank line::

    # chair/173/Program_0
    def nfunc_12(x0: float, ...):
        ...

    bbox = Cuboid(0.893, 1.558, 1.019, True)
    Program_1, cube1, cube2 = nfunc_12(0.528, 1.017, 0.5, 0.188, 0.018, 0.502, 0.848, 0.28)

    # chair/173/Program_1
    ...

The first block is ``Program_0``, the root. Every other block ``Program_k`` is the sub-program of the
cuboid that an earlier block binds to the name ``Program_k`` (the ShapeAssembly corpus convention): the
executor draws it inside that cuboid. Each block carries the definitions it calls, so a block reads on its
own; the same definition may appear in several blocks. :func:`to_text` prints the canonical form, and
``to_text(parse(t)) == t`` for printed texts.

Example:
    >>> t = ("# Program_0\\nbbox = Cuboid(1.0, 1.0, 1.0, True)\\nProgram_1 = Cuboid(0.5, 0.5, 0.5, True)\\n"
    ...      "attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n\\n# Program_1\\nbbox = Cuboid(0.5, 0.5, 0.5, True)\\n"
    ...      "c = Cuboid(0.1, 0.5, 0.1, True)\\nsqueeze(bbox, bbox, top, 0.1, 0.1)\\n\\n")
    >>> h = parse(t)
    >>> h.names, to_text(h) == t
    (('Program_0', 'Program_1'), True)
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

from .. import limits
from ..errors import ParseError
from ..lang import Attach, Block, Cuboid, Squeeze, block_rows
from .grammar import to_shapeassembly
from .lang import MacroProgram, to_text as program_text
from .library import Library, _parse_block

__all__ = [
    "HEADER",
    "MacroHierarchy",
    "is_hierarchy_text",
    "parse",
    "to_text",
]

#: A block's header line: ``# <key>``, the key ending in the block's name ``Program_k``.
HEADER = re.compile(r"#[ \t]*(?P<key>(?:\S*/)?(?P<name>Program_\d+))[ \t]*")


@dataclass(frozen=True)
class MacroHierarchy:
    """A hierarchical macro program.

    Attributes:
        keys: each block's header key (``'chair/173/Program_1'``), in text order.
        programs: each block's :class:`~shapeprog.macros.lang.MacroProgram`.
    """

    keys: tuple[str, ...]
    programs: tuple[MacroProgram, ...]

    @property
    def names(self) -> tuple[str, ...]:
        """The block names (``Program_k``)."""
        return tuple(k.rsplit("/", 1)[-1] for k in self.keys)

    def replace(self, programs) -> "MacroHierarchy":
        """The same blocks with new programs."""
        return MacroHierarchy(self.keys, tuple(programs))

    def __repr__(self) -> str:
        lines = sum(len(p.lines) for p in self.programs)
        return f"<MacroHierarchy: {len(self.keys)} blocks, {lines} lines; print with shapeprog.macros.hierarchy.to_text>"


def as_hierarchy(value) -> MacroHierarchy | None:
    """``value`` as a :class:`MacroHierarchy` when it is one or a :class:`~shapeprog.macros.api.Refactored` (its
    blocks); otherwise None (a hierarchy text is read with :func:`parse`)."""
    if isinstance(value, MacroHierarchy):
        return value
    if type(value).__name__ == "Refactored" and hasattr(value, "blocks"):
        return MacroHierarchy(tuple(b.key for b in value.blocks), tuple(b.program for b in value.blocks))
    return None


def is_hierarchy_text(text: str) -> bool:
    """Whether ``text`` holds block header lines (``# .../Program_k``)."""
    return any(HEADER.fullmatch(line) for line in text.split("\n"))


def block_line_offsets(h: MacroHierarchy) -> list[int]:
    """0-based line of each block's first program-text line (the line after its header) in :func:`to_text`."""
    out, n = [], 0
    for p in h.programs:
        out.append(n + 1)
        n += 1 + program_text(p).count("\n") + 1
    return out


def to_text(h: MacroHierarchy) -> str:
    """The canonical text: per block its header, its macro program's text and a blank line."""
    return "".join(f"# {k}\n{program_text(p)}\n" for k, p in zip(h.keys, h.programs))


def check(h: MacroHierarchy, file: str = "<string>", header_lines=None) -> None:
    """The block structure: ``Program_0`` first, names unique, each other block bound as a cuboid name by
    exactly one earlier block, and every ``Program_k`` cuboid name a later block (so the tree has no cycle).

    Raises:
        ParseError: at the offending block's header line.
    """
    offsets = block_line_offsets(h) if header_lines is None else list(header_lines)
    bound: dict = {}
    for bi, (name, p) in enumerate(zip(h.names, h.programs)):
        def bad(reason):
            return ParseError(reason, file, offsets[bi], 1, f"# {h.keys[bi]}")

        if bi == 0 and name != "Program_0":
            raise bad(f"the first block must be Program_0, got {name}")
        if name in h.names[:bi]:
            raise bad(f"block {name} appears twice")
        if bi > 0 and name not in bound:
            raise bad(f"no earlier block binds a cuboid named {name} (the cuboid this sub-program fills)")
        for c in p.lines[1:]:
            for r in c.rets:
                if re.fullmatch(r"Program_\d+", r):
                    if r in bound:
                        raise bad(f"cuboid {r} is bound twice")
                    if r not in h.names[bi + 1:]:
                        raise bad(f"cuboid {r} has no block after this one (a Program_k cuboid is a sub-program)")
                    bound[r] = bi


def rename_block(block, names, block_name: str):
    """A block's flat expansion with its cuboids named as the macro program binds them (``names``, per
    non-bbox Cuboid line), declarations first; and the expansion line of each statement of the result."""
    old = [s.name for s in block.statements if isinstance(s, Cuboid)][1:]
    m = dict(zip(old, names))
    m["bbox"] = "bbox"
    out = []
    for s in block.statements:
        if isinstance(s, Cuboid):
            out.append(dataclasses.replace(s, name=m[s.name]))
        elif isinstance(s, Attach):
            out.append(dataclasses.replace(s, a=m[s.a], b=m[s.b]))
        elif isinstance(s, Squeeze):
            out.append(dataclasses.replace(s, a=m[s.a], b=m[s.b], c=m[s.c]))
        else:
            out.append(dataclasses.replace(s, a=m[s.a]))
    # declarations first, as in the corpus format: in a flat text, a cuboid the program names ``cube1``
    # declared after ``reflect(cube0, X)`` loses its leaf to the copy (the executor's implicit copy slots);
    # declared before, it keeps it. Moves keep their order.
    order = [k for k, s in enumerate(out) if isinstance(s, Cuboid)] + [k for k, s in enumerate(out)
                                                                       if not isinstance(s, Cuboid)]
    return Block(block_name, tuple(out[k] for k in order)), order


def check_limits(h: MacroHierarchy, library=None, file: str = "<string>", header_lines=None,
                 expansions=None) -> None:
    """The ShapeAssembly limits of the program the hierarchy expands to (:func:`shapeprog.limits.check_tree`:
    sub-program depth, executed cuboids and attach operations), each error at its block's header line.
    ``expansions``: each block's :meth:`~shapeprog.macros.library.Library.expand` when the caller has them."""
    lib = Library() if library is None else library
    header_lines = block_line_offsets(h) if header_lines is None else header_lines
    blocks, parent = {}, {}
    for bi, (program, name) in enumerate(zip(h.programs, h.names)):
        loc = (header_lines[bi], 1, f"# {h.keys[bi]}")

        def fail(i, reason, k, loc=loc):
            raise ParseError(reason, file, *loc)

        exp = lib.expand(program) if expansions is None else expansions[bi]
        block, _ = rename_block(to_shapeassembly(exp.lines, check=False).blocks[0], exp.names, name)
        blocks[name] = (loc, [(loc, slots, n) for slots, n in block_rows(block.statements, fail, names=False)])
        parent.update((s.name, name) for s in block.statements
                      if isinstance(s, Cuboid) and re.fullmatch(r"Program_\d+", s.name))
    limits.check_tree(blocks, parent, file)


def parse(text: str, file: str = "<string>", library=None) -> MacroHierarchy:
    """Parse a hierarchical macro program; each block with ``library``
    (:meth:`shapeprog.macros.library.Library.parse`, which also checks that it expands).

    Raises:
        ParseError: with the line in the whole text (syntax, names, types, expansion, block structure).
    """
    lib = Library() if library is None else library
    lines = text.split("\n")
    starts = [i for i, ln in enumerate(lines) if HEADER.fullmatch(ln)]
    if not starts:
        raise ParseError("no block header line ('# Program_0')", file, 1, 1, lines[0] if lines else "")
    for i, ln in enumerate(lines[:starts[0]]):
        if ln.strip() and not ln.lstrip().startswith("#"):
            raise ParseError("text before the first block header ('# Program_0')", file, i + 1, 1, ln.strip())
    keys, programs, expansions = [], [], []
    for n, s in enumerate(starts):
        end = starts[n + 1] if n + 1 < len(starts) else len(lines)
        keys.append(HEADER.fullmatch(lines[s]).group("key"))
        body = "\n".join(lines[s + 1:end])
        try:
            program, exp = _parse_block(body, file, lib)
            programs.append(program), expansions.append(exp)
        except ParseError as e:
            raise ParseError(e.reason, e.file, e.line + s + 1, e.column, e.token) from None
    h = MacroHierarchy(tuple(keys), tuple(programs))
    check(h, file, [s + 1 for s in starts])
    check_limits(h, lib, file, [s + 1 for s in starts], expansions)
    return h
