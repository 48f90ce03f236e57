"""Public entry points of ShapeMOD: the shipped libraries, refactoring a program with a library, expansion
back to the base language, and the corpus collection discovery runs on.

Example:
    >>> from shapeprog import corpus, parse
    >>> from shapeprog.macros import Library, refactor
    >>> lib = Library.from_text("def slab(h: float):\\n    c = Cuboid(bb_x, h, bb_z, True)\\n"
    ...                         "    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> r = refactor(parse(corpus.read("chair", 173)), lib)
    >>> r.stats["blocks"], r.stats["f"] <= r.stats["f_base"]
    (2, True)
"""
from __future__ import annotations

import re
from concurrent.futures import Executor
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Sequence

import numpy as np

from shapeio.files import resolve_shipped

from ..lang import Program, parse
from ..limits import decode
from ..lang import parse as parse_program
from .data import convert_corpus, convert_program
from .subprogram import SubProgram
from .state import Nodes, nodes_from_subprograms
from .grammar import to_shapeassembly
from .lang import BASE, BOOL, CUBE, FLOAT, Call, MacroProgram, Name, to_text
from .hierarchy import as_hierarchy, is_hierarchy_text
from .hierarchy import parse as parse_hierarchy
from .library import Library, as_macro_program
from .objective import Result, best_program, templates, to_program
from .. import corpus
from .execute import compile_hierarchy

__all__ = ["BlockRefactor", "LIBRARIES", "LIBRARY_CATEGORIES", "Refactored", "collection", "expand", "header_split", "library_split", "library_text", "load_library", "read_library",
           "refactor", "program_stats"]

#: Categories with a shipped library (``shapeprog/macros/libs/<category>.txt``).
LIBRARY_CATEGORIES = ("chair", "table", "storage")
#: The shipped libraries: category -> file.
LIBRARIES = {c: Path(__file__).resolve().parent / "libs" / f"{c}.txt" for c in LIBRARY_CATEGORIES}


def load_library(name: str) -> Library:
    """A ShapeMOD library: the library file ``name`` when one exists at that path, else the shipped library of
    category ``name`` (:data:`LIBRARIES`; the rule of :func:`shapeio.files.resolve_shipped`: an existing file
    wins; see ``shapeprog/macros/libs/README.md`` for the shipped ones).

    Raises:
        NotShippedError: neither a file nor a shipped category (a ``ValueError``; the message names both).
        ParseError: the file is not a library (file, line and column).
    """
    return read_library(name)[0]


def read_library(name: str) -> tuple[Library, str]:
    """``(library, its file's text)`` of :func:`load_library` (the text with its header, as shipped).

    Raises:
        NotShippedError: neither a file nor a shipped category.
        ParseError: the file is not a library.
    """
    path = resolve_shipped(name, LIBRARIES, "ShapeMOD library")
    text = decode(path.read_bytes(), str(path))
    return Library.from_text(text, str(path)), text


def library_text(category: str) -> str:
    """The text of the shipped library file of ``category``, header included.

    Raises:
        ValueError: no library is shipped for ``category``.
    """
    if category not in LIBRARY_CATEGORIES:
        raise ValueError(f"no shipped ShapeMOD library for {category!r} (shipped: {', '.join(LIBRARY_CATEGORIES)})")
    return resources.files("shapeprog.macros").joinpath("libs", f"{category}.txt").read_text(encoding="utf-8")


def header_split(text: str) -> str | None:
    """The corpus split a library file was discovered on, read from the ``# shapes: N of split 'S'`` line of the
    header that ``python -m shapeprog macros discover`` writes; None when the text has no such line."""
    m = re.search(r"^# shapes: \d+ of split '([^']+)'", text, re.MULTILINE)
    return m.group(1) if m else None


def library_split(category: str) -> str | None:
    """The corpus split the shipped library of ``category`` was discovered on (``"train"`` or ``"all"``):
    :func:`header_split` of its file."""
    return header_split(library_text(category))


def program_stats(program: MacroProgram, library: Library) -> dict:
    """Counts of a macro program's calls after the bbox line: ``lines`` (calls), ``float``, ``cube``,
    ``categorical``, ``bool`` parameters; ``bbox_floats`` / ``bbox_bools`` of its bbox line. ``program`` may
    be its text."""
    program = as_macro_program(program, library, "shapeprog.macros.program_stats")
    lib = library.with_program(program)
    st = {"lines": 0, "float": 0, "cube": 0, "categorical": 0, "bool": 0, "bbox_floats": 3, "bbox_bools": 1}
    for c in program.lines[1:]:
        st["lines"] += 1
        for p in lib[c.func].params:
            key = {FLOAT: "float", CUBE: "cube", BOOL: "bool"}.get(p.type, "categorical")
            st[key] += 1
    return st


def _used(program: MacroProgram, library: Library) -> list:
    """Definitions of the macros ``program`` calls, with their dependencies, in library order."""
    need: set = set()
    todo = [c.func for c in program.lines if c.func not in BASE]
    while todo:
        f = todo.pop()
        if f in need:
            continue
        need.add(f)
        todo += [c.func for c in library[f].definition.body if c.func not in BASE]
    return [m for m in library.macros if m.name in need]


def _rename(call: Call, names: dict) -> Call:
    """``call`` with the cuboid names in ``names`` (old -> new) replaced, in its rets and arguments."""
    args = tuple(Name(names.get(a.name, a.name)) if isinstance(a, Name) else a for a in call.args)
    return Call(call.func, args, tuple(names.get(r, r) for r in call.rets))


@dataclass(frozen=True)
class BlockRefactor:
    """One sub-program refactored: its key, macro program (with the definitions it uses), text, f and
    the base program's f, :func:`program_stats`, and the base lines of the ordering it rewrites."""

    key: str
    program: MacroProgram
    text: str
    f: float
    f_base: float
    stats: dict
    lines: tuple = ()


@dataclass(frozen=True)
class Refactored:
    """A refactored program: one :class:`BlockRefactor` per sub-program (``Assembly`` block).

    Attributes:
        blocks: the blocks in program order.
        text: every block's text under a ``# <block>`` header line: a hierarchical macro program
            (:mod:`shapeprog.macros.hierarchy`; a sub-program's cuboid is named after its block).
        stats: summed :func:`program_stats` plus ``f`` and ``f_base`` (sums over blocks) and ``blocks``.
    """

    blocks: tuple[BlockRefactor, ...]
    text: str
    stats: dict

    @property
    def program(self) -> MacroProgram:
        """The root block's macro program."""
        return self.blocks[0].program


def refactor(program: Program | SubProgram | Sequence[SubProgram], library: Library, mode: str = "beam",
             max_orders: int = 1000, category: str = "", shape_id: int = 0) -> Refactored:
    """Rewrite a program with ``library``'s macros: per sub-program, the best program P* over its
    orderings (:func:`shapeprog.macros.objective.best_program`).

    Args:
        program: a ShapeAssembly program or its text (parsed with :func:`shapeprog.parse`; converted with
            :func:`~shapeprog.macros.data.convert_program`), or sub-programs.
        library: the macros.
        mode: ``'beam'`` (the reference's search) or ``'exact'``.
        max_orders: orderings searched per sub-program.
        category, shape_id: name the blocks of a parsed program (``'chair/173/Program_0'``).

    Raises:
        ValueError: a block of the program cannot be written in the modified grammar.
        TypeError: ``program`` is none of these (a macro program is already refactored: expand it with
            :func:`expand` first).
    """
    if not isinstance(library, Library):
        raise TypeError(f"shapeprog.macros.refactor takes a shapeprog.macros.Library as `library`, got "
                        f"{type(library).__name__}: load one with shapeprog.macros.load_library(category)")
    if isinstance(program, str):
        program = parse_program(program)
    if isinstance(program, Program):
        conv = convert_program(program, category, shape_id)
        if conv.failures:
            raise ValueError(f"cannot refactor: {conv.failures[0]}")
        subs = conv.subprograms
    elif isinstance(program, SubProgram):
        subs = [program]
    elif isinstance(program, (list, tuple)) and all(isinstance(s, SubProgram) for s in program):
        subs = list(program)
    else:
        name = type(program).__name__
        hint = (" (it is written with macros already: shapeprog.macros.expand(program, library) gives its base "
                "program)" if name in ("MacroProgram", "Refactored", "MacroHierarchy") else "")
        raise TypeError(f"shapeprog.macros.refactor takes a ShapeAssembly Program, its text or sub-programs, got "
                        f"{name}{hint}: make a program with shapeprog.parse(text)")
    tpls = templates(library)
    base = Library()
    btpls = templates(base)
    blocks = []
    for s in subs:
        orders = [s.lines(o) for o in s.orders[:max_orders]]
        r: Result = best_program(orders, library, tpls, mode)
        rb = best_program(orders, base, btpls, mode)
        mp = to_program(orders[r.order], r.calls, library)
        # the cuboid a sub-program fills takes that block's name, as in the corpus format
        perm = list(s.orders[r.order].cubes)
        kids = {f"cube{perm.index(c.parent[1])}": c.block for c in subs
                if c.parent is not None and c.parent[0] == s.block and c.shape_id == s.shape_id
                and c.category == s.category}
        mp = MacroProgram(tuple(_used(mp, library)), tuple(_rename(c, kids) for c in mp.lines))
        blocks.append(BlockRefactor(s.key, mp, to_text(mp), r.f, rb.f, program_stats(mp, library),
                                     tuple(orders[r.order])))
    stats = {k: sum(b.stats[k] for b in blocks) for k in blocks[0].stats} if blocks else {}
    stats.update(f=sum(b.f for b in blocks), f_base=sum(b.f_base for b in blocks), blocks=len(blocks))
    text = "".join(f"# {b.key}\n{b.text}\n" for b in blocks)
    return Refactored(tuple(blocks), text, stats)


def expand(program, library: Library | None = None) -> Program:
    """A macro program as a base ShapeAssembly program (its own definitions and ``library``'s).

    Args:
        program: a :class:`~shapeprog.macros.lang.MacroProgram` or its text: the result is one flat block; a
            refactored program (:func:`refactor`'s result), a :class:`~shapeprog.macros.hierarchy.MacroHierarchy`
            or its text: the whole hierarchical program (corpus format, a block per sub-program, cuboids named
            as the macro program binds them).
        library: the library its lines call (default: the base functions only).

    Raises:
        TypeError: ``program`` is none of these (a ShapeAssembly program is already in the base language).
    """
    lib = Library() if library is None else library
    h = as_hierarchy(program)
    if h is None and isinstance(program, str) and is_hierarchy_text(program):
        h = parse_hierarchy(program, library=lib)
    if h is not None:
        return compile_hierarchy(h, lib).program
    program = as_macro_program(program, lib, "shapeprog.macros.expand")
    return to_shapeassembly(lib.expand(program).lines)


def collection(category: str, split: str = "all", limit: int | None = None, seed: int = 0,
               executor: Executor | None = None, max_orders: int = 1000) -> tuple[Nodes, list[int]]:
    """The sub-programs of a corpus category as discovery :class:`~shapeprog.macros.state.Nodes`.

    Args:
        category, split: the corpus programs.
        limit: a random subset of this many shapes (drawn with ``seed``); None: all.
        executor: converts chunks of programs (optional).

    Returns:
        (nodes, the shape ids used, sorted).
    """
    ids = corpus.ids(category, split)
    if limit is not None and limit < len(ids):
        rng = np.random.default_rng(seed)
        ids = sorted(int(i) for i in rng.choice(ids, size=limit, replace=False))
        subs = []
        for i in ids:
            subs += convert_program(parse(corpus.read(category, i), f"{category}/{i}.txt"), category, i).subprograms
    else:
        subs = convert_corpus([category], split, executor=executor).by_category(category)
    return nodes_from_subprograms(subs, max_orders), list(ids)
