"""Line vectors generic over a ShapeMOD macro library: hierarchical macro programs to trees and back.

ShapeMOD's Appendix C trains the ShapeAssembly VAE on macro programs: a line is a call of one of the
library's functions (the five base functions of the modified grammar and the macros), so the line vector
follows the library. :class:`LineLayout` computes it from the functions' typed parameters:

* a command one-hot over ``start``, ``stop`` and the |L| functions, in library order;
* ``k_cube`` cuboid-id one-hots of :data:`NUM_SLOTS` entries each (slot 0 = bbox, slot j = the j-th
  cuboid the block creates, in creation order);
* ``k_float`` floats, ``k_face`` face one-hots (6), ``k_axis`` axis one-hots (3), ``k_bool`` booleans;

each ``k`` the largest number of parameters of that type over the library's functions. A function's
parameters of one type fill that group's first slots in parameter order; :meth:`LineLayout.used` gives
the per-function mask of the slots it uses (the losses compare those only).

:func:`macro_program_to_tree` turns every block of a :class:`~shapeprog.macros.hierarchy.MacroHierarchy`
into a :class:`MacroNode`: its lines (the bbox line first, as a ``Cuboid`` call) and one child entry per
*created cuboid* (not per line: a macro call may create several cuboids, each of which may be a
``Program_k`` sub-program). :func:`tree_to_macro_program` writes a tree back: the cuboid of slot j is named
``Program_<m>`` when it has a child (blocks numbered breadth first), else ``cube<j-1>``.

Example:
    >>> from shapeprog.macros import Library
    >>> from shapeprog.macros.hierarchy import parse
    >>> lib = Library.from_text("def post(h: float, b: bool):\\n    c = Cuboid(0.1, h, 0.1, b)\\n"
    ...                         "    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> layout = LineLayout(lib)
    >>> layout.commands[:3], layout.width, layout.used("post")["float"]
    (('start', 'stop', 'Cuboid'), 46, (True, False, False, False, False, False))
    >>> h = parse("# Program_0\\nbbox = Cuboid(1.0, 1.0, 1.0, True)\\np = post(0.5, True)\\n\\n", library=lib)
    >>> tree = macro_program_to_tree(h, layout)
    >>> tuple(tree.lines.shape), tree.children
    ((2, 46), (None, None))
    >>> from shapeprog.macros.lang import to_text
    >>> print(to_text(tree_to_macro_program(tree, layout, decimals=3).programs[0]), end="")
    bbox = Cuboid(1.0, 1.0, 1.0, True)
    cube0 = post(0.5, True)
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import torch

from ..errors import ParseError
from ..lang import AXES, FACES
from ..macros.hierarchy import MacroHierarchy, block_line_offsets
from ..macros.lang import AXIS, BOOL, CUBE, FACE, FLOAT, TYPES, Call, Linear, Literal, MacroProgram, Name
from ..macros.library import Library
from .vectors import _LineTree

__all__ = ["GROUPS", "MAX_BLOCK_LINES", "NUM_SLOTS", "LineLayout", "MacroNode", "macro_program_to_tree",
           "tree_to_macro_program"]

#: Cuboid one-hot slots: 0 = bbox, j = the j-th cuboid a block creates (as the base layout's 11).
NUM_SLOTS = 11
#: Lines a block may have, its bbox line included (the refactored chair corpus has at most 22).
MAX_BLOCK_LINES = 32
#: The parameter groups of a line vector, in order, with the width of one slot of each.
GROUPS = {CUBE: NUM_SLOTS, FLOAT: 1, FACE: len(FACES), AXIS: len(AXES), BOOL: 1}
_PROGRAM = re.compile(r"Program_\d+")


class LineLayout:
    """The line vector of a library's programs (see the module docstring).

    Args:
        library: the functions; a call of a function not in it cannot be encoded.

    Attributes:
        library: the library.
        functions: the function names in library order (the five base functions first).
        commands: ``("start", "stop") + functions``: the command one-hot's entries.
        counts: per type of :data:`GROUPS`, the number of slots (the largest count over the functions).
        slices: per type, the slice of the line vector holding its slots; ``slices["cmd"]`` the command.
        width: the line vector's length.
        max_created: the most cuboids one call creates (1 at least: the bbox line's).
    """

    def __init__(self, library: Library):
        if not isinstance(library, Library):
            raise TypeError(f"`library` must be a shapeprog.macros.Library, got {type(library).__name__}")
        self.library = library
        self.functions = tuple(library)
        self.commands = ("start", "stop") + self.functions
        self.counts = {t: max(sum(p.type == t for p in library[f].params) for f in self.functions) for t in TYPES}
        self.slices: dict[str, slice] = {"cmd": slice(0, len(self.commands))}
        at = len(self.commands)
        for t in TYPES:
            n = self.counts[t] * GROUPS[t]
            self.slices[t] = slice(at, at + n)
            at += n
        self.width = at
        self.max_created = max(1, max(library[f].n_cuboids for f in self.functions))
        # per function: its parameters' (type, slot within the type's group) in parameter order
        self._slots: dict[str, tuple[tuple[str, int], ...]] = {}
        for f in self.functions:
            seen = {t: 0 for t in TYPES}
            out = []
            for p in library[f].params:
                out.append((p.type, seen[p.type]))
                seen[p.type] += 1
            self._slots[f] = tuple(out)
        # (commands, k) bool masks per type: row c marks the slots command c uses (start / stop: none)
        self.masks = {t: torch.zeros(len(self.commands), self.counts[t], dtype=torch.bool) for t in TYPES}
        for c, f in enumerate(self.functions, start=2):
            for t, k in self._slots[f]:
                self.masks[t][c, k] = True
        self.n_created = torch.tensor([0, 0] + [library[f].n_cuboids for f in self.functions], dtype=torch.long)

    START, STOP = 0, 1

    def __repr__(self) -> str:
        parts = ", ".join(f"{t}={self.counts[t]}" for t in TYPES)
        return f"LineLayout({len(self.functions)} functions, width {self.width}: {parts})"

    def command_index(self, func: str) -> int:
        """The command one-hot entry of function ``func``."""
        try:
            return 2 + self.functions.index(func)
        except ValueError:
            raise KeyError(f"no function {func!r} in the library") from None

    def used(self, func: str) -> dict[str, tuple[bool, ...]]:
        """Per type, which of the group's slots ``func`` uses."""
        c = self.command_index(func)
        return {t: tuple(self.masks[t][c].tolist()) for t in TYPES}

    def command_vector(self, command: str, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
        """The ``(width,)`` vector of a bare command (``"start"``, ``"stop"`` or a function name)."""
        v = torch.zeros(self.width, dtype=dtype, device=device)
        v[self.commands.index(command)] = 1.0
        return v

    def part(self, x: torch.Tensor, kind: str) -> torch.Tensor:
        """The ``kind`` group of line vectors ``(*, width)`` as ``(*, k, slot width)`` (``kind`` a type of
        :data:`GROUPS`) or ``(*, commands)`` for ``"cmd"``."""
        p = x[..., self.slices[kind]]
        return p if kind == "cmd" else p.reshape(*x.shape[:-1], self.counts[kind], GROUPS[kind])

    # -------------------------------------------------------------- one line
    def encode_call(self, call: Call, slot_of) -> list[float]:
        """The vector of a program line; ``slot_of(name)`` gives a cuboid argument's slot."""
        row = [0.0] * self.width
        row[self.command_index(call.func)] = 1.0
        for (t, k), a in zip(self._slots[call.func], call.args):
            at = self.slices[t].start + k * GROUPS[t]
            if t == FLOAT:
                row[at] = float(a.value)
            elif t == BOOL:
                row[at] = float(bool(a.value))
            elif t == FACE:
                row[at + FACES.index(a.value)] = 1.0
            elif t == AXIS:
                row[at + AXES.index(a.value)] = 1.0
            else:
                row[at + slot_of(a.name)] = 1.0
        return row

    def decode_call(self, row, name_of, rets: tuple[str, ...], decimals: int | None = None) -> Call:
        """The program line of a vector ``row`` (a list or a 1-d tensor: one-hots or logits); ``name_of(slot)``
        names a cuboid argument, ``rets`` the cuboids the line creates. The command is the argmax over the
        functions (start and stop excluded), booleans are ``entry > 0``."""
        r = row.tolist() if isinstance(row, torch.Tensor) else list(row)
        cs = self.slices["cmd"]
        c = max(range(cs.start + 2, cs.stop), key=lambda i: r[i])
        func = self.commands[c - cs.start]
        args = []
        for t, k in self._slots[func]:
            at = self.slices[t].start + k * GROUPS[t]
            if t == FLOAT:
                v = float(r[at])
                args.append(Linear.const(round(v, decimals) if decimals is not None else v))
            elif t == BOOL:
                args.append(Literal(r[at] > 0))
            else:
                best = max(range(GROUPS[t]), key=lambda i: r[at + i])
                args.append(Literal(FACES[best]) if t == FACE else Literal(AXES[best]) if t == AXIS
                            else Name(name_of(best)))
        return Call(func, tuple(args), rets)


@dataclass(frozen=True, eq=False)
class MacroNode(_LineTree):
    """One block of a hierarchical macro program as line vectors.

    Attributes:
        lines: (L, width) float, one row per program line, the bbox line (a ``Cuboid`` call) first.
        children: one entry per cuboid the block creates, in creation order, bbox first: the child
            :class:`MacroNode` of a ``Program_k`` cuboid, else None (always None for bbox).
        name: the block's name in the source (``Program_k``), for messages.
        float_start: where the layout's float group starts (``layout.slices["float"].start``), so that
            :attr:`bbox_dims` reads the bbox line's l, h, w without the layout.
    """

    lines: torch.Tensor
    children: tuple["MacroNode | None", ...]
    name: str = "Program_0"
    float_start: int | None = None

    @property
    def bbox_dims(self) -> torch.Tensor:
        """(3,) float: the block's bbox dims, the first three floats of its bbox line."""
        if self.float_start is None:
            raise ValueError(f"{self.name}: a MacroNode built without float_start has no known bbox dims")
        return self.lines[0, self.float_start: self.float_start + 3]

    def commands(self, layout: LineLayout) -> torch.Tensor:
        """(L,) int64: the command entry of every row."""
        return self.lines[:, layout.slices["cmd"]].argmax(dim=1)

    def creators(self, layout: LineLayout) -> list[tuple[int, int]]:
        """Per created cuboid (bbox first): ``(row, k)``, the row that creates it and its position among
        that row's created cuboids."""
        out = [(0, 0)]
        for i, c in enumerate(self.commands(layout).tolist()[1:], start=1):
            out += [(i, k) for k in range(int(layout.n_created[c]))]
        return out

    def input_seq(self, layout: LineLayout) -> torch.Tensor:
        """(L+1, width) float: ``[start, l1 .. lL]``, the decoder's teacher-forced input."""
        return self._framed(layout.command_vector, "start")

    def target_seq(self, layout: LineLayout) -> torch.Tensor:
        """(L+1, width) float: ``[l1 .. lL, stop]``, the decoder's target."""
        return self._framed(layout.command_vector, "stop")


def macro_program_to_tree(h: MacroHierarchy, layout: LineLayout, file: str = "<program>",
                          dtype: torch.dtype = torch.float32, device=None) -> MacroNode:
    """The line-vector tree of a hierarchical macro program, root first.

    Args:
        h: the program (e.g. one of :func:`shapeprog.macros.load_refactored`).
        layout: the layout of the library its blocks call.
        file: the program's name in error messages.

    Raises:
        ParseError: at ``file:line`` (lines of :func:`shapeprog.macros.hierarchy.to_text`) when the program
            cannot be encoded: a block defining a macro the library lacks (or defines differently), a call
            of a function not in the library, more than ``NUM_SLOTS - 1`` cuboids or ``MAX_BLOCK_LINES``
            lines in a block, an unknown cuboid.
    """
    offsets = block_line_offsets(h)
    blocks = dict(zip(h.names, h.programs))
    lib = layout.library

    def error(bi: int, index: int, reason: str, token: str) -> ParseError:
        p = h.programs[bi]
        defs = sum(len(d.body) + 2 for d in p.defs)  # header, body, blank line
        return ParseError(reason, file, offsets[bi] + defs + index + 1, 1, token)

    def build(bi: int, seen: tuple[str, ...]) -> MacroNode:
        p: MacroProgram = h.programs[bi]
        for d in p.defs:
            if d.name not in lib or lib[d.name].definition != d:
                raise ParseError(f"block {h.names[bi]} defines {d.name!r}, which the layout's library "
                                 f"{'lacks' if d.name not in lib else 'defines differently'}",
                                 file, offsets[bi] + 1, 5, d.name)
        if len(p.lines) > MAX_BLOCK_LINES:
            raise error(bi, MAX_BLOCK_LINES, f"more than {MAX_BLOCK_LINES} lines in block {h.names[bi]} "
                        f"(MAX_BLOCK_LINES)", p.lines[MAX_BLOCK_LINES].func)
        slots = {"bbox": 0}
        created = ["bbox"]
        rows = []
        for i, c in enumerate(p.lines):
            if c.func not in layout.functions:
                raise error(bi, i, f"function {c.func!r} is not in the layout's library", c.func)

            def slot_of(name: str, i=i) -> int:
                if name not in slots:
                    raise error(bi, i, f"unknown cuboid {name!r} in block {h.names[bi]}", name)
                return slots[name]
            rows.append(layout.encode_call(c, slot_of))
            for r in (c.rets if i else ()):
                if len(created) == NUM_SLOTS:
                    raise error(bi, i, f"more than {NUM_SLOTS - 1} cuboids in block {h.names[bi]} (the line "
                                f"vector has {NUM_SLOTS} cuboid slots, bbox included)", r)
                slots[r] = len(created)
                created.append(r)
        kids = []
        for name in created:
            if name != "bbox" and _PROGRAM.fullmatch(name) and name in blocks and name not in seen:
                kids.append(build(h.names.index(name), seen + (name,)))
            else:
                kids.append(None)
        lines = torch.tensor(rows, dtype=dtype, device=device)
        return MacroNode(lines, tuple(kids), h.names[bi], layout.slices[FLOAT].start)

    if not h.programs:
        raise ParseError("a hierarchical macro program without blocks", file, 1, 1, "")
    return build(0, (h.names[0],))


def tree_to_macro_program(tree: MacroNode, layout: LineLayout, decimals: int | None = None,
                          key_prefix: str = "") -> MacroHierarchy:
    """The hierarchical macro program a tree writes (targets or decoder predictions).

    Row 0 of a node is its bbox line (``bbox = Cuboid(...)``, aligned True); a later row is a call of the
    argmax function (start and stop excluded); a stop row ends a node. Cuboid slot j of a node is
    ``Program_<m>`` when ``children[j]`` is a node (blocks numbered breadth first), else ``cube<j-1>``.
    The programs carry no definitions (they call the layout's library); nothing is checked:
    :func:`shapeprog.macros.execute.compile_hierarchy` with the library checks and expands them.

    Args:
        decimals: round every float to this many places (3 gives the refactored corpus's text back from
            float32 vectors, up to its fitted values' extra places); None keeps the values.
        key_prefix: put before each block name in the headers (e.g. ``"chair/173/"``).
    """
    keys, programs = [], []
    queue = [(tree, "Program_0")]
    count = 1
    fs = layout.slices[FLOAT].start
    while queue:
        node, name = queue.pop(0)
        x = node.lines.detach().to("cpu", torch.float64)
        if x.dim() != 2 or x.shape[1] != layout.width or x.shape[0] == 0:
            raise ValueError(f"{name}: lines must be (L, {layout.width}) with L >= 1, got {tuple(x.shape)}")
        cmds = x[:, layout.slices["cmd"]].argmax(dim=1).tolist()
        n = cmds.index(LineLayout.STOP) if LineLayout.STOP in cmds else len(cmds)
        names = ["bbox"]
        calls = []
        dims = [float(v) for v in x[0, fs: fs + 3].tolist()]
        num = (lambda v: round(v, decimals)) if decimals is not None else (lambda v: v)  # noqa: E731
        calls.append(Call("Cuboid", tuple(Linear.const(num(v)) for v in dims) + (Literal(True),), ("bbox",)))
        for i in range(1, n):
            row = x[i]
            func = layout.commands[max(range(2, len(layout.commands)), key=lambda c: float(row[c]))]
            rets = []
            for _ in range(layout.library[func].n_cuboids):
                j = len(names)
                child = node.children[j] if j < len(node.children) else None
                if child is None:
                    names.append(f"cube{j - 1}")
                else:
                    names.append(f"Program_{count}")
                    queue.append((child, f"Program_{count}"))
                    count += 1
                rets.append(names[-1])
            name_of = lambda k: names[k] if k < len(names) else f"cube{k - 1}"  # noqa: E731
            calls.append(layout.decode_call(row, name_of, tuple(rets), decimals))
        keys.append(key_prefix + name)
        programs.append(MacroProgram((), tuple(calls)))
    return MacroHierarchy(tuple(keys), tuple(programs))

