"""Static compile of ShapeAssembly blocks into primitive ops (no tensors).

Which attach rule a statement uses depends only on the program's structure (how many
attachment records the moved cuboid has, including records where it was the target, and its
aligned flag), so it is decided here, as are macro names, the dependency levels of the ops
and the sub-program tree. The ops' continuous numbers are affine forms over the program's
parameter vector (:func:`shapeprog.execute.program_parameters`). See ``docs/shapeassembly.md``.

Example:
    >>> from shapeprog.lang import parse
    >>> p = parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\\n"
    ...           "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> c = compile_program(p)
    >>> c.n_params, c.blocks[0].slots, [op[0] for op in c.blocks[0].ops]
    (12, ['bbox', 'cube0'], ['attach'])
"""
from __future__ import annotations

from dataclasses import dataclass

from .lang import AXES, Attach, Cuboid, Program, Reflect, Squeeze, Translate, statement_lines

__all__ = ["FIRST", "SECOND", "GENERAL", "ALIGNED", "AttachOp", "BlockCode", "CompiledProgram", "compile_program"]

#: Attach rules, chosen per statement at compile time.
FIRST, SECOND, GENERAL, ALIGNED = 0, 1, 2, 3

# face -> (axis index k, "val"): val is 0 for the positive faces, 1 for the negative ones.
_FACE = {"right": (0, 0), "left": (0, 1), "top": (1, 0), "bot": (1, 1), "front": (2, 0), "back": (2, 1)}
_OPP = {"right": "left", "left": "right", "top": "bot", "bot": "top", "front": "back", "back": "front"}


@dataclass
class AttachOp:
    """One attach of cuboid slot ``a`` to slot ``b`` by rule ``mode`` (attach, squeeze or a macro copy)."""

    a: int
    b: int
    mode: int
    src: tuple  # affine form (c0 (3,), c1 (3,), idx (3,)), idx into the program's parameters (-1: none)
    tgt: tuple | None  # affine form, or None for a macro (computed at run time)
    prior: list  # list of (op index, role 0=subject 1=target) of a's earlier records
    macro: tuple | None = None  # (orig op j, src slot A, target slot T, kind 'R'|'T', k, i, N, d idx)
    j: int = 0  # index among the block's attach ops (its record row)


@dataclass
class BlockCode:
    """One block lowered to ops on cuboid slots (slot 0 is its ``bbox``)."""

    name: str
    slots: list[str]
    init_dims: list  # per slot: 3 param indices (or None -> zeros until copied)
    ops: list  # ('attach', AttachOp) | ('setdims', slot, idx3) | ('copy', new, src)
    steps: list  # ops grouped by dependency level (ops of one level are independent)
    slot_line: list[int]
    slot_source: list[int | None]  # macro copies: the source slot
    slot_reflect_axis: list[int | None]
    child_names: list[str | None]  # per Cuboid line (bbox first): sub-program name or None


def _aff(consts=(0.0, 0.0, 0.0), scales=(0.0, 0.0, 0.0), idx=(-1, -1, -1)):
    return (tuple(consts), tuple(scales), tuple(idx))


def _compile_block(block, offset: int, lines: list[int]) -> tuple[BlockCode, int]:
    """Static lowering of one block; ``offset`` is the index of its first parameter in the
    program's parameters. Returns the code and the index after its last parameter."""
    slots: dict[str, int] = {}
    names: list[str] = []
    init_dims: list = []
    aligned: list[bool] = []
    slot_line: list[int] = []
    slot_source: list = []
    slot_axis: list = []
    child_names: list = []
    ops: list = []
    records: list[list[tuple[int, int]]] = []  # per slot: (op index, role)
    move_atts: list[list[int]] = []  # per slot: op indices where it was the subject
    att_ops: list[AttachOp] = []  # attach op j is att_ops[j]
    p = offset
    levels: list[int] = []
    last_w: dict[int, int] = {}
    last_r: dict[int, int] = {}

    def schedule(write: int, reads: tuple) -> None:
        """Dependency level of the op just appended: after earlier writes and reads of the
        slot it writes and after earlier writes of the slots it reads."""
        lvl = 1 + max([last_w.get(write, -1), last_r.get(write, -1)] + [last_w.get(r, -1) for r in reads])
        last_w[write] = lvl
        for r in reads:
            last_r[r] = max(last_r.get(r, -1), lvl)
        levels.append(lvl)

    def new_slot(name, dims_idx, al, line, source=None, axis=None):
        slots[name] = len(names)
        names.append(name)
        init_dims.append(dims_idx)
        aligned.append(al)
        slot_line.append(line)
        slot_source.append(source)
        slot_axis.append(axis)
        records.append([])
        move_atts.append([])
        return slots[name]

    def attach(a, b, src, tgt, macro=None):
        j = len(att_ops)
        n = len(records[a])
        if aligned[a]:
            mode = FIRST if n == 0 else ALIGNED
        else:
            mode = FIRST if n == 0 else SECOND if n == 1 else GENERAL
        op = AttachOp(a, b, mode, src, tgt, list(records[a]), macro, j)
        ops.append(("attach", op))
        att_ops.append(op)
        schedule(a, (b,) if macro is None else (b, macro[1], 0))
        records[b].append((j, 1))
        records[a].append((j, 0))
        move_atts[a].append(j)

    new_slot("bbox", None, True, lines[0])
    for si, s in enumerate(block.statements):
        ln = lines[si]
        if isinstance(s, Cuboid):
            idx = (p, p + 1, p + 2)
            p += 3
            child_names.append(s.name if s.name.startswith("Program_") else None)
            if s.name in slots:
                k = slots[s.name]
                if si == 0 and k == 0:
                    init_dims[0] = idx
                else:
                    ops.append(("setdims", k, idx))
                    schedule(k, ())
            else:
                new_slot(s.name, idx, s.aligned, ln)
        elif isinstance(s, Attach):
            a, b = slots[s.a], slots[s.b]
            attach(a, b, _aff(scales=(1, 1, 1), idx=(p, p + 1, p + 2)),
                   _aff(scales=(1, 1, 1), idx=(p + 3, p + 4, p + 5)))
            p += 6
        elif isinstance(s, Squeeze):
            a, b, c = slots[s.a], slots[s.b], slots[s.c]
            iu, iv = p, p + 1
            p += 2
            for face, tgt_slot in ((s.face, b), (_OPP[s.face], c)):
                k, val = _FACE[face]
                src_c = [0.5, 0.5, 0.5]
                src_c[k] = 1.0 - val
                tc = [0.0, 0.0, 0.0]
                ts = [1.0, 1.0, 1.0]
                ti = [-1, -1, -1]
                tc[k] = float(1 - val) if tgt_slot == 0 else float(val)
                ts[k] = 0.0
                free = [d for d in range(3) if d != k]
                ti[free[0]], ti[free[1]] = iu, iv
                attach(a, tgt_slot, _aff(consts=src_c), _aff(tc, ts, ti))
        elif isinstance(s, (Reflect, Translate)):
            A = slots[s.a]
            k = AXES.index(s.axis)
            count = 1 if isinstance(s, Reflect) else s.n
            didx = -1
            if isinstance(s, Translate):
                didx = p
                p += 1
            for i in range(1, count + 1):
                name = f"cube{len(names) - 1}"
                if name in slots:  # a collision re-dimensions the existing cuboid (as the reference)
                    new = slots[name]
                    slot_source[new] = A
                    slot_axis[new] = k if isinstance(s, Reflect) else None
                else:
                    new = new_slot(name, None, aligned[A], ln, A, k if isinstance(s, Reflect) else None)
                ops.append(("copy", new, A))
                schedule(new, (A,))
                for j in list(move_atts[A]):
                    op = att_ops[j]
                    c0, c1, ix = op.src
                    if isinstance(s, Reflect):
                        c0 = tuple(1.0 - c0[d] if d == k else c0[d] for d in range(3))
                        c1 = tuple(-c1[d] if d == k else c1[d] for d in range(3))
                        kind = "R"
                    else:
                        kind = "T"
                    attach(new, op.b, (c0, c1, ix), None, (j, A, op.b, kind, k, i, count, didx))
        else:  # pragma: no cover - the parser only builds the five kinds
            raise TypeError(type(s).__name__)
    steps: list[list] = [[] for _ in range(max(levels, default=-1) + 1)]
    for op, lvl in zip(ops, levels):
        steps[lvl].append(op)
    return BlockCode(block.name, names, init_dims, ops, steps, slot_line, slot_source, slot_axis, child_names), p


@dataclass
class CompiledProgram:
    """Static structure of one program."""

    blocks: list[BlockCode]
    n_params: int
    instances: list  # BFS: (block idx, parent inst, parent slot, flip axis)
    leaf_slots: list  # per block: its slots that are leaves (no bbox, no sub-program)


def compile_program(program: Program) -> CompiledProgram:
    """Lower every block of ``program`` and lay out its breadth-first block instances.

    Args:
        program: a parsed :class:`~shapeprog.lang.Program`.

    Returns:
        The :class:`CompiledProgram`; its ``n_params`` equals ``len(program_parameters(program))``.
    """
    lines = statement_lines(program)
    blocks, off = [], 0
    for b, block_lines in zip(program.blocks, lines):
        code, off = _compile_block(b, off, block_lines)
        blocks.append(code)
    index = {b.name: i for i, b in enumerate(program.blocks)}
    # per block, per slot after the bbox: (sub-program block or None, flip axis)
    children = [[_child_of(c, s, index) for s in range(1, len(c.slots))] for c in blocks]
    leaf_slots = [[s for s, (child, _) in enumerate(ch, 1) if child is None] for ch in children]
    # breadth-first instances; an instance = one placement of a block
    queue = [(0, -1, -1, None)]
    qi = 0
    while qi < len(queue):
        bidx = queue[qi][0]
        queue.extend((child, qi, s, flip) for s, (child, flip) in enumerate(children[bidx], 1) if child is not None)
        qi += 1
    return CompiledProgram(blocks, off, queue, leaf_slots)


def _child_of(code: BlockCode, s: int, index: dict) -> tuple[int | None, int | None]:
    """Sub-program block of slot ``s`` (and flip axis for reflected copies)."""
    if s < len(code.child_names):
        name = code.child_names[s]
        return (index[name] if name is not None else None), None
    axis, k = code.slot_reflect_axis[s], s
    while k >= len(code.child_names):  # follow the copy chain to its source (a loop: chains can be long)
        k = code.slot_source[k]
        if k is None:
            return None, None
    name = code.child_names[k]
    return (None, None) if name is None else (index[name], axis)

