"""The lock-step schedule of compiled blocks as index tensors and constants.

The state of a batch of blocks is kept in flat rows (cuboid slot ``s`` of block row ``k`` is
row ``k * S + s``). :func:`plan_steps` turns the dependency levels of every block into steps
whose attach ops are grouped by rule (:class:`GroupPlan`); :func:`plan_levels` orders the
breadth-first placement of the block instances and the gather of the leaves. Nothing here
depends on the parameter values. See ``docs/shapeassembly.md``.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from .compile import GENERAL, SECOND, BlockCode, CompiledProgram

__all__ = ["GroupPlan", "LevelPlan", "StepPlan", "plan_levels", "plan_steps"]


@dataclass
class GroupPlan:
    """The attach ops of one rule at one step, over all blocks, as index tensors and constants.

    The state is kept in flat rows: cuboid slot ``s`` of block row ``k`` is row ``k * S + s`` of
    the pos / dims / axes tensors; attachment record ``j`` of block row ``k`` holds its src, tgt
    and global points in rows ``(k * J + j) * 3 + (0, 1, 2)`` of the record tensor."""

    mode: int
    n: int
    row_a: torch.Tensor  # (n,) state row of the moved cuboid
    row_b: torch.Tensor  # (n,) state row of the target cuboid
    c0: torch.Tensor  # (2n, 3) affine constants: the n src rows, then the n tgt rows
    c1: torch.Tensor  # (2n, 3) affine scales
    ix: torch.Tensor  # (2n, 3) parameter indices (-1: the trailing zero)
    macro: dict | None  # reflect / translate copies, see _macro_points
    prior: tuple | None  # SECOND: record rows of the earlier record's point on A and of its global point
    general: list | None  # GENERAL: per row, [(record row of the point on A, record row of the global point)]
    keep: torch.Tensor | None  # group rows whose record a later op reads (None: every row)
    rec_rows: torch.Tensor | None  # record rows written (None: no record of the group is read later)


@dataclass
class StepPlan:
    setdims: tuple | None  # (state rows, parameter indices (n, 3))
    copy: tuple | None  # (new state rows, source state rows)
    groups: list  # of GroupPlan


@dataclass
class LevelPlan:
    """Placement of the block instances at one depth of the sub-program trees."""

    rows: torch.Tensor  # (m,) block row of each instance
    parent: torch.Tensor | None  # (m,) row parent instance * S + parent slot in the previous level (None: roots)
    root_ix: torch.Tensor | None  # roots: (m, 3) parameter indices of the root bbox dims
    pos_sign: torch.Tensor | None  # (m, 1, 3) reflect flip of positions (None: no flip at this level)
    ax_sign: torch.Tensor | None  # (m, 1, 1, 3) reflect flip (180 deg turn) of the axes


def _shift(form, off):
    return (form[0], form[1], tuple(i + off if i >= 0 else -1 for i in form[2]))


def _plan_group(mode, items, offsets, S, J, dtype, device, read: set) -> GroupPlan:
    """Index tensors and constants of one attach group; ``items``: (block row, record index, op);
    ``read``: the (block row, record index) pairs that later ops read.

    The integers, the floats and the flags each go into one tensor, split into views (building
    the plan is part of every :func:`execute` call)."""
    rec_row = lambda blk, j, role: (blk * J + j) * 3 + role  # noqa: E731
    n = len(items)
    ints: list = []  # (name, values, shape)
    floats: list = []
    flags: list = []
    ints.append(("row_a", [blk * S + o.a for blk, _, o in items], (n,)))
    ints.append(("row_b", [blk * S + o.b for blk, _, o in items], (n,)))
    none = ((0.0,) * 3, (0.0,) * 3, (-1, -1, -1))
    src_forms, tgt_forms, macro_rows = [], [], []
    for r, (blk, _, o) in enumerate(items):
        if o.macro is None:
            src_forms.append(_shift(o.src, offsets[blk]))
            tgt_forms.append(_shift(o.tgt, offsets[blk]))
        else:  # computed at run time from the original record (_macro_points)
            src_forms.append(none)
            tgt_forms.append(none)
            macro_rows.append(r)
    forms = src_forms + tgt_forms
    floats.append(("c0", [x for f in forms for x in f[0]], (2 * n, 3)))
    floats.append(("c1", [x for f in forms for x in f[1]], (2 * n, 3)))
    ints.append(("ix", [x for f in forms for x in f[2]], (2 * n, 3)))
    if macro_rows:
        ms = [(items[r][0], items[r][2].macro) for r in macro_rows]
        m = len(ms)
        ints.append(("r_idx", macro_rows, (m,)))
        ints.append(("ap", [rec_row(blk, mc[0], 0) for blk, mc in ms], (m,)))  # the original record's point on A
        ints.append(("A", [blk * S + mc[1] for blk, mc in ms], (m,)))
        ints.append(("T", [blk * S + mc[2] for blk, mc in ms], (m,)))
        ints.append(("box", [blk * S for blk, _ in ms], (m,)))
        ints.append(("didx", [offsets[blk] + mc[7] if mc[7] >= 0 else -1 for blk, mc in ms], (m,)))
        e = [[1.0 if k == mc[4] else 0.0 for k in range(3)] for _, mc in ms]
        floats.append(("e", [x for row in e for x in row], (m, 3)))
        floats.append(("ii", [float(mc[5]) for _, mc in ms], (m,)))
        floats.append(("N", [float(mc[6]) for _, mc in ms], (m,)))
        is_ref = [mc[3] == "R" for _, mc in ms]
        flags.append(("is_ref", is_ref, (m,)))
        flags.append(("flip", [r and k == mc[4] for r, (_, mc) in zip(is_ref, ms) for k in range(3)], (m, 3)))
    if mode == SECOND:
        ints.append(("prior_ap", [rec_row(blk, *o.prior[0]) for blk, _, o in items], (n,)))
        ints.append(("prior_g", [rec_row(blk, o.prior[0][0], 2) for blk, _, o in items], (n,)))
    rows = [r for r, (blk, j, _) in enumerate(items) if (blk, j) in read]
    if rows and len(rows) < n:
        ints.append(("keep", rows, (len(rows),)))
    if rows:
        ints.append(("rec_rows", [rec_row(items[r][0], items[r][1], role) for r in rows for role in range(3)],
                     (3 * len(rows),)))

    def pack(entries, **kw):
        flat_vals = [x for _, vals, _ in entries for x in vals]
        t = torch.tensor(flat_vals, **kw)
        parts = t.split([len(vals) for _, vals, _ in entries])
        return {name: part.view(shape) for (name, _, shape), part in zip(entries, parts)}

    iv = pack(ints, dtype=torch.int64, device=device)
    fv = pack(floats, dtype=dtype, device=device)
    bv = pack(flags, dtype=torch.bool, device=device) if flags else {}
    macro = None
    if macro_rows:
        macro = dict(r_idx=iv["r_idx"], ap=iv["ap"], A=iv["A"], T=iv["T"], box=iv["box"], didx=iv["didx"],
                     ii=fv["ii"], N=fv["N"], e=fv["e"], is_ref=bv["is_ref"], flip=bv["flip"],
                     any_ref=any(is_ref), any_tr=not all(is_ref))
    prior = (iv["prior_ap"], iv["prior_g"]) if mode == SECOND else None
    general = None
    if mode == GENERAL:
        general = [[(rec_row(blk, j, role), rec_row(blk, j, 2)) for j, role in o.prior] for blk, _, o in items]
    return GroupPlan(mode, n, iv["row_a"], iv["row_b"], fv["c0"], fv["c1"], iv["ix"], macro, prior, general,
                      iv.get("keep"), iv.get("rec_rows"))


def plan_steps(codes: list[BlockCode], offsets: list[int], S: int, J: int, dtype, device) -> list[StepPlan]:
    """Lock-step schedule: step ``t`` runs the ``t``-th dependency level of every block."""
    read = set()  # attachment records that some op reads: second / general priors, macro sources
    for bi, c in enumerate(codes):
        for op in c.ops:
            if op[0] == "attach":
                o = op[1]
                if o.mode in (SECOND, GENERAL):
                    read.update((bi, j) for j, _ in o.prior)
                if o.macro is not None:
                    read.add((bi, o.macro[0]))
    steps = []
    for t in range(max(len(c.steps) for c in codes)):
        groups: dict = {}
        setd, copy = [], []
        for bi, c in enumerate(codes):
            if t >= len(c.steps):
                continue
            for op in c.steps[t]:
                if op[0] == "attach":
                    o = op[1]
                    groups.setdefault(o.mode, []).append((bi, o.j, o))
                elif op[0] == "setdims":
                    setd.append((bi * S + op[1],) + tuple(offsets[bi] + i for i in op[2]))
                else:
                    copy.append((bi * S + op[1], bi * S + op[2]))
        sd = cp = None
        if setd:
            t_ = torch.tensor(setd, device=device)
            sd = (t_[:, 0], t_[:, 1:])
        if copy:
            cp = torch.tensor(copy, device=device).unbind(1)
        plans = [_plan_group(m, it, offsets, S, J, dtype, device, read) for m, it in groups.items()]
        steps.append(StepPlan(sd, cp, plans))
    return steps


def plan_levels(comps: list[CompiledProgram], block_base: list[int], param_base: list[int], S: int, dtype, device):
    """Placement levels and the leaf gather of a batch of programs.

    Returns the levels, the row (instance * S + slot) of every leaf in output order (instances
    numbered level after level), and the leaf count, node and line tensors per program.
    """
    per_level: list[list] = []  # per depth: (program, local instance)
    where: list[dict] = []  # per program: local instance -> (depth, index in level)
    for pi, comp in enumerate(comps):
        depth = []
        loc = {}
        for li, (_, parent, _, _) in enumerate(comp.instances):
            d = 0 if parent < 0 else depth[parent] + 1
            depth.append(d)
            while len(per_level) <= d:
                per_level.append([])
            loc[li] = (d, len(per_level[d]))
            per_level[d].append((pi, li))
        where.append(loc)
    level_base = [0]
    for lv in per_level:
        level_base.append(level_base[-1] + len(lv))
    lt = lambda v: torch.tensor(v, dtype=torch.int64, device=device)  # noqa: E731
    levels = []
    for d, lv in enumerate(per_level):
        rows, parent, root_ix, pos_sign, ax_sign = [], [], [], [], []
        for pi, li in lv:
            bidx, par, ps, flip = comps[pi].instances[li]
            rows.append(block_base[pi] + bidx)
            if d == 0:
                root_ix.append([param_base[pi] + k for k in range(3)])
            else:
                parent.append(where[pi][par][1] * S + ps)
            sign = [1.0, 1.0, 1.0]
            if flip is not None:
                sign[flip] = -1.0
            pos_sign.append(sign)
            # a reflected copy's axes: -(axes * sign), a 180 degree turn
            ax_sign.append([-x for x in sign] if flip is not None else sign)
        flips = any(comps[pi].instances[li][3] is not None for pi, li in lv)
        levels.append(LevelPlan(
            rows=lt(rows),
            parent=lt(parent) if d else None,
            root_ix=lt(root_ix) if d == 0 else None,
            pos_sign=torch.tensor(pos_sign, dtype=dtype, device=device)[:, None] if flips else None,
            ax_sign=torch.tensor(ax_sign, dtype=dtype, device=device)[:, None, None] if flips else None,
        ))
    leaf_rows, counts, nodes, lines = [], [], [], []
    for pi, comp in enumerate(comps):
        node, line = [], []
        for li, (bidx, _, _, _) in enumerate(comp.instances):
            code = comp.blocks[bidx]
            keep = comp.leaf_slots[bidx]
            d, k = where[pi][li]
            leaf_rows.extend((level_base[d] + k) * S + s for s in keep)
            node.extend([int(code.name.split("_")[1]) if code.name.startswith("Program_") else bidx] * len(keep))
            line.extend(code.slot_line[s] for s in keep)
        counts.append(len(node))
        nodes.append(lt(node))
        lines.append(lt(line))
    return levels, lt(leaf_rows), counts, nodes, lines

