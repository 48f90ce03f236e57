"""Programs to and from the 63-dim line vectors of the ShapeAssembly generative model, both ways.

:func:`program_to_tree` turns every block of a program into one :class:`VectorNode` holding an
``(L, 63)`` tensor (one row per statement, the spec's code-order layout, its clamps, cuboids named by
slot) and the child node of each Cuboid line; :func:`tree_to_program` writes a tree (of targets or of
decoder predictions) back as a :class:`~shapeprog.lang.Program`. The layout, the clamps, the slot
renaming and the decisions: ``docs/shapeassembly_vae.md``.

Example:
    >>> from shapeprog.lang import parse, to_text
    >>> text = ("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.25, 0.5, False)\\n"
    ...         "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\nreflect(cube0, X)\\n")
    >>> tree = program_to_tree(parse(text))
    >>> tuple(tree.lines.shape), tree.lines[1, DIMS].tolist(), tree.lines[2, CUBE2].argmax().item()
    ((4, 63), [0.5, 0.25, 0.5], 0)
    >>> to_text(tree_to_program(tree, decimals=3)).splitlines()[3]
    '\\tattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)'
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Iterator

import torch

from ..errors import ParseError
from ..lang import (AXES, FACES, Attach, Block, Cuboid, Program, Reflect, Squeeze, Statement, Translate,
                    statement_lines, statement_text)

__all__ = [
    "ALIGNED",
    "ATTACH",
    "AXIS",
    "CMD",
    "COMMANDS",
    "COUNT",
    "CUBE1",
    "CUBE2",
    "CUBE3",
    "CUBES",
    "DIMS",
    "DIST",
    "FACE",
    "LINE_DIM",
    "MAX_CUBOID_LINES",
    "MIN_DIM",
    "NUM_SLOTS",
    "UV",
    "VectorNode",
    "command_vector",
    "l1_mask",
    "program_to_tree",
    "tree_to_program",
]

#: Length of a line vector.
LINE_DIM = 63
#: Command one-hot order (the reference code's, not the paper's).
COMMANDS = ("start", "Cuboid", "attach", "reflect", "translate", "squeeze", "stop")
#: Cuboid one-hot slots: 0 = bbox, j + 1 = ``cube<j>``.
NUM_SLOTS = 11
#: Cuboid lines a node may have, bbox included (the reference drops larger nodes).
MAX_CUBOID_LINES = 10

CMD = slice(0, 7)
CUBE1 = slice(7, 18)
CUBE2 = slice(18, 29)
CUBE3 = slice(29, 40)
CUBES = slice(7, 40)
DIMS = slice(40, 43)
ATTACH = slice(43, 49)
AXIS = slice(49, 52)
COUNT = 52
DIST = 53
FACE = slice(54, 60)
UV = slice(60, 62)
ALIGNED = 62

_START, _CUBOID, _ATTACH, _REFLECT, _TRANSLATE, _SQUEEZE, _STOP = range(7)
#: Entries of each command's continuous parameters (the L1 loss mask); reflect has none.
_L1 = {_CUBOID: DIMS, _ATTACH: ATTACH, _TRANSLATE: slice(COUNT, DIST + 1), _SQUEEZE: UV}
MIN_DIM = 0.01  #: the smallest Cuboid dim a line vector holds (the reference clamp)


def command_vector(command: str, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """The ``(63,)`` vector of a bare command, e.g. ``"start"`` or ``"stop"`` (a one-hot at its index)."""
    v = torch.zeros(LINE_DIM, dtype=dtype, device=device)
    v[COMMANDS.index(command)] = 1.0
    return v


class _LineTree:
    """What the trees of line vectors share (:class:`VectorNode`, :class:`~shapeprog.vae.layout.MacroNode`,
    frozen dataclasses with ``lines: (L, width) float`` and ``children``, one node or None each)."""

    def _framed(self, command_vector, command: str) -> torch.Tensor:
        """(L+1, width) float: the lines after ``command_vector("start")`` or before ``command_vector("stop")``."""
        row = command_vector(command, self.lines.dtype, self.lines.device)[None]
        return torch.cat([row, self.lines] if command == "start" else [self.lines, row])

    def nodes(self) -> Iterator[tuple]:
        """Every node of the tree with its depth (root 0), breadth first (the order of the blocks)."""
        queue = [(self, 0)]
        while queue:
            node, depth = queue.pop(0)
            yield node, depth
            queue += [(c, depth + 1) for c in node.children if c is not None]

    def to(self, device=None, dtype: torch.dtype | None = None):
        """A copy of the tree with every tensor moved to ``device`` / cast to ``dtype``."""
        kids = tuple(None if c is None else c.to(device, dtype) for c in self.children)
        return dataclasses.replace(self, lines=self.lines.to(device=device, dtype=dtype), children=kids)


@dataclass(frozen=True, eq=False)
class VectorNode(_LineTree):
    """One program block as line vectors, with the sub-program of each of its Cuboid lines.

    Attributes:
        lines: (L, 63) float, one row per statement in block order (no start or stop row).
        children: one entry per Cuboid line, bbox first: the child :class:`VectorNode` of a
            ``Program_`` part, or None for a leaf (always None for bbox).
        name: the block's name in the source program (``Program_k``), for messages.
    """

    lines: torch.Tensor
    children: tuple["VectorNode | None", ...]
    name: str = "Program_0"

    @property
    def commands(self) -> torch.Tensor:
        """(L,) int64: the command index of every row."""
        return self.lines[:, CMD].argmax(dim=1)

    @property
    def cuboid_rows(self) -> torch.Tensor:
        """(K,) int64: the rows that are Cuboid lines, bbox first."""
        return (self.commands == _CUBOID).nonzero().flatten()

    @property
    def bbox_dims(self) -> torch.Tensor:
        """(3,) float: the node's bbox dims (entries 40-42 of its first line)."""
        return self.lines[0, DIMS]

    def input_seq(self) -> torch.Tensor:
        """(L+1, 63) float: ``[start, l1 .. lL]``, the decoder's teacher-forced input."""
        return self._framed(command_vector, "start")

    def target_seq(self) -> torch.Tensor:
        """(L+1, 63) float: ``[l1 .. lL, stop]``, the decoder's target."""
        return self._framed(command_vector, "stop")


def l1_mask(target: torch.Tensor) -> torch.Tensor:
    """(T, 63) float: 1 at the continuous entries of each row of ``target`` (T, 63) that the L1 losses
    compare (Cuboid dims, attach coordinates, translate count and distance, squeeze u, v)."""
    mask = torch.zeros_like(target)
    cmds = target[:, CMD].argmax(dim=1).tolist()
    for row, c in enumerate(cmds):
        if c in _L1:
            mask[row, _L1[c]] = 1.0
    return mask


# ------------------------------------------------------------------------ program -> vectors


def _clamp(x: float, lo: float, hi: float) -> float:
    return min(max(float(x), lo), hi)


def _slot_table(block: Block, where) -> dict[str, int]:
    """Name -> slot of every cuboid of ``block``: bbox 0, Cuboid lines in order, then macro copies
    (named ``cube<number of cuboids - 1>`` as the executor names them)."""
    slots: dict[str, int] = {}
    for i, s in enumerate(block.statements):
        if isinstance(s, Cuboid):
            if s.name in slots:
                raise where(i, s.name, f"cuboid {s.name!r} is declared twice; every Cuboid line takes a new slot")
            if len(slots) == MAX_CUBOID_LINES:
                raise where(i, s.name, f"more than {MAX_CUBOID_LINES} Cuboid lines in block {block.name} "
                            f"(the line vector has {NUM_SLOTS} slots: bbox, cube0 .. cube{NUM_SLOTS - 2})")
            slots[s.name] = len(slots)
        elif isinstance(s, (Reflect, Translate)):
            for _ in range(1 if isinstance(s, Reflect) else int(s.n)):
                slots.setdefault(f"cube{len(slots) - 1}", len(slots))
    return slots


def _locator(program: Program, file: str):
    rows = statement_lines(program)
    index = {b.name: k for k, b in enumerate(program.blocks)}
    indent = 0 if program.flat else 1

    def error(block: Block, i: int, token: str, reason: str) -> ParseError:
        text = statement_text(block.statements[i])
        col = text.find(token) + 1 if token and token in text else 1
        return ParseError(reason, file, rows[index[block.name]][i] + 1, col + indent, token)

    return error


def _encode_block(block: Block, error) -> list[list[float]]:
    where = lambda i, token, reason: error(block, i, token, reason)  # noqa: E731
    slots = _slot_table(block, where)
    rows = [[0.0] * LINE_DIM for _ in block.statements]

    def slot(i: int, name: str) -> int:
        if name not in slots:
            raise where(i, name, f"unknown cuboid {name!r} in block {block.name}")
        k = slots[name]
        if k >= NUM_SLOTS:
            raise where(i, name, f"cuboid {name!r} is slot {k} of block {block.name}; the line vector has "
                        f"{NUM_SLOTS} slots (bbox, cube0 .. cube{NUM_SLOTS - 2})")
        return k

    for i, s in enumerate(block.statements):
        r = rows[i]
        if isinstance(s, Cuboid):
            r[_CUBOID] = 1.0
            r[DIMS] = [max(float(v), MIN_DIM) for v in (s.l, s.h, s.w)]
            r[ALIGNED] = float(bool(s.aligned))
        elif isinstance(s, Attach):
            r[_ATTACH] = 1.0
            r[CUBE1.start + slot(i, s.a)] = r[CUBE2.start + slot(i, s.b)] = 1.0
            r[ATTACH] = [_clamp(v, 0.0, 1.0) for v in (s.x1, s.y1, s.z1, s.x2, s.y2, s.z2)]
        elif isinstance(s, Squeeze):
            r[_SQUEEZE] = 1.0
            r[CUBE1.start + slot(i, s.a)] = r[CUBE2.start + slot(i, s.b)] = r[CUBE3.start + slot(i, s.c)] = 1.0
            r[FACE.start + FACES.index(s.face)] = 1.0
            r[UV] = [_clamp(s.u, 0.0, 1.0), _clamp(s.v, 0.0, 1.0)]
        elif isinstance(s, (Reflect, Translate)):
            r[_REFLECT if isinstance(s, Reflect) else _TRANSLATE] = 1.0
            r[CUBE1.start + slot(i, s.a)] = 1.0
            r[AXIS.start + AXES.index(s.axis)] = 1.0
            if isinstance(s, Translate):
                r[COUNT] = float(max(int(s.n), 1))
                r[DIST] = _clamp(s.d, 0.0, 1.0)
        else:
            raise TypeError(f"not a ShapeAssembly statement: {type(s).__name__}")
    return rows


def program_to_tree(program: Program, file: str = "<program>", dtype: torch.dtype = torch.float32,
                    device=None) -> VectorNode:
    """The line-vector tree of ``program``: one :class:`VectorNode` per block, root first.

    Args:
        program: a parsed program (corpus or flat format).
        file: the program's name, used in error messages (e.g. ``"chair/173.txt"``).
        dtype, device: of the ``(L, 63)`` line tensors.

    Returns:
        The root node; ``node.children[j]`` is the block of the node's j-th Cuboid line.

    Raises:
        ParseError: at the program's ``file:line:column`` when the model cannot encode it: more than
            10 Cuboid lines in a block, a cuboid whose slot is beyond the 11 of the vector (e.g. a
            macro copy ``cube10``), a cuboid declared twice, or an unknown cuboid name.
    """
    error = _locator(program, file)
    blocks = {b.name: b for b in program.blocks}

    def build(block: Block, seen: tuple[str, ...]) -> VectorNode:
        kids = []
        for j, c in enumerate(block.cuboids()):
            if j == 0 or not c.name.startswith("Program_") or c.name not in blocks or c.name in seen:
                kids.append(None)
            else:
                kids.append(build(blocks[c.name], seen + (c.name,)))
        lines = torch.tensor(_encode_block(block, error), dtype=dtype, device=device)
        return VectorNode(lines, tuple(kids), block.name)

    return build(program.root, (program.root.name,))


# ------------------------------------------------------------------------ vectors -> program


def _check_lines(node: VectorNode, path: str) -> None:
    x = node.lines
    if not isinstance(x, torch.Tensor) or x.dim() != 2 or x.shape[1] != LINE_DIM or x.shape[0] == 0:
        got = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
        raise ValueError(f"{path}: lines must be (L, {LINE_DIM}) with L >= 1, got {got}")


def _decode_block(node: VectorNode, path: str, name_of, decimals: int | None) -> list[Statement]:
    num = (lambda v: round(v, decimals)) if decimals is not None else (lambda v: v)  # noqa: E731
    rows = node.lines.detach().to("cpu", torch.float64).tolist()
    cmds = node.commands.tolist()
    out: list[Statement] = []
    ncub = 0
    for i, (r, c) in enumerate(zip(rows, cmds)):
        if c == _STOP:
            break
        if c == _START:
            raise ValueError(f"{path}: row {i} is a start command (only the decoder's input begins with one)")
        if i == 0 and c != _CUBOID:
            raise ValueError(f"{path}: row 0 is a {COMMANDS[c]} line; a block starts with its bbox Cuboid line")
        argmax = lambda s: max(range(s.start, s.stop), key=lambda k: r[k]) - s.start  # noqa: E731
        a = name_of(argmax(CUBE1))
        if c == _CUBOID:
            l, h, w = (num(max(v, MIN_DIM)) for v in r[DIMS])
            out.append(Cuboid(name_of(ncub), l, h, w, ncub == 0 or r[ALIGNED] > 0))
            ncub += 1
        elif c == _ATTACH:
            out.append(Attach(a, name_of(argmax(CUBE2)), *(num(_clamp(v, 0.0, 1.0)) for v in r[ATTACH])))
        elif c == _SQUEEZE:
            u, v = (num(_clamp(x, 0.0, 1.0)) for x in r[UV])
            out.append(Squeeze(a, name_of(argmax(CUBE2)), name_of(argmax(CUBE3)), FACES[argmax(FACE)], u, v))
        elif c == _REFLECT:
            out.append(Reflect(a, AXES[argmax(AXIS)]))
        else:
            out.append(Translate(a, AXES[argmax(AXIS)], max(int(round(r[COUNT])), 1), num(_clamp(r[DIST], 0.0, 1.0))))
    return out


def tree_to_program(tree: VectorNode, decimals: int | None = None) -> Program:
    """The program written by a line-vector tree (targets, or decoder predictions).

    Commands, slots, axes and faces are the argmax of their entries, so logits work as well as
    one-hots; aligned is ``entry 62 > 0`` (a 1/0 target or a logit; always True for bbox, whose flag
    the executor ignores and the model does not learn); the count is rounded. The
    preprocessing clamps are applied again (dims >= 0.01, coordinates, u, v, d in [0, 1], count >= 1).
    A stop row ends a node. The j-th Cuboid line is ``bbox`` (j = 0), ``Program_<m>`` when
    ``children[j]`` is a node, else ``cube<j-1>``; blocks are numbered breadth first. A slot with no
    Cuboid line is written ``cube<slot-1>`` (the executor's name of a macro copy).

    Args:
        tree: the root :class:`VectorNode`.
        decimals: round every continuous number to this many places (3 gives the corpus's text
            back from float32 vectors); None keeps the values.

    Returns:
        The :class:`~shapeprog.lang.Program` (corpus format), not checked: ``parse(to_text(p))``
        checks it.

    Raises:
        ValueError: a node whose lines are not (L, 63), that does not start with a Cuboid line, or
            that has a start row.
    """
    blocks: list[Block] = []
    queue = [(tree, "Program_0", "root")]
    count = 1
    while queue:
        node, name, path = queue.pop(0)
        _check_lines(node, path)
        cmds = node.commands.tolist()
        cmds = cmds[:cmds.index(_STOP)] if _STOP in cmds else cmds
        cub = [i for i, c in enumerate(cmds) if c == _CUBOID]
        names = ["bbox"]
        for j in range(1, len(cub)):
            child = node.children[j] if j < len(node.children) else None
            if child is None:
                names.append(f"cube{j - 1}")
            else:
                names.append(f"Program_{count}")
                queue.append((child, f"Program_{count}", f"{path}.children[{j}]"))
                count += 1
        name_of = lambda k: names[k] if k < len(names) else f"cube{k - 1}"  # noqa: E731
        blocks.append(Block(name, tuple(_decode_block(node, path, name_of, decimals))))
    return Program(tuple(blocks))
