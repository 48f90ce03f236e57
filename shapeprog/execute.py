"""Differentiable ShapeAssembly executor (one code path, batched over blocks).

Reproduces the reference's hierarchical execution (spec section (b)); the same code computes
values and, through autograd, gradients with respect to every continuous number of the
program text. A program is compiled (:mod:`shapeprog.compile`), scheduled in lock step
(:mod:`shapeprog.schedule`), run with the attach rules of :mod:`shapeprog.attach`, then
placed breadth first. How it works and the decisions taken: ``docs/shapeassembly.md``.

Example:
    >>> from shapeprog.lang import parse
    >>> p = parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\\n"
    ...           "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> s = execute(p)
    >>> s.centers.tolist()
    [[0.0, -0.4000000059604645, 0.0]]
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from .attach import point, rule_aligned, rule_first, rule_general, rule_second, to_local
from .compile import ALIGNED, FIRST, SECOND, compile_program
from .errors import ExecutionError
from .geometry import cuboid_corners, mesh_arrays
from .lang import NUM_FIELDS, Program, as_program, numbers
from .schedule import GroupPlan, plan_levels, plan_steps

__all__ = ["ExecutedShape", "ExecutionPlan", "execute", "execute_batch", "program_parameters", "parameter_names"]


# ----------------------------------------------------------------------------- result


@dataclass
class ExecutedShape:
    """Leaf cuboids of an executed program (bbox cuboids excluded), in the spec's order:
    breadth-first over program nodes, declared order then macro copies within a node.

    Attributes:
        centers: (L, 3) float, cuboid centres.
        dims: (L, 3) float, extents along the cuboid's right/up/front axes.
        axes: (L, 3, 3) float, rows are the unit right/up/front vectors.
        corners: (L, 8, 3) float, corners in the spec's order.
        node: (L,) int64, index of the program block (``Program_k`` -> k) of each leaf.
        line: (L,) int64, 0-based file line of the statement that created each leaf
            (its Cuboid line, or the reflect/translate line for macro copies).
        root_dims: (3,) float, the root bbox dims.
    """

    centers: torch.Tensor
    dims: torch.Tensor
    axes: torch.Tensor
    corners: torch.Tensor
    node: torch.Tensor
    line: torch.Tensor
    root_dims: torch.Tensor

    def __len__(self) -> int:
        return self.centers.shape[0]

    def mesh(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(vertices (8L, 3) float, faces (12L, 3) int64), the reference's OBJ layout."""
        return mesh_arrays(self.corners)

    def to_trimesh(self):
        """The leaf cuboids as one ``trimesh.Trimesh`` (float64 vertices in :meth:`mesh`'s order, no merging);
        ``face_attributes['part']`` holds each triangle's leaf index and ``metadata['lines']`` each leaf's
        0-based program line."""
        import trimesh  # lazy: trimesh only for a mesh

        verts, faces = mesh_arrays(self.corners.detach().cpu().double())
        part = torch.arange(len(self)).repeat_interleave(faces.shape[0] // max(len(self), 1))
        return trimesh.Trimesh(vertices=verts.numpy(), faces=faces.numpy(), process=False,
                               face_attributes={"part": part.numpy()},
                               metadata={"lines": self.line.tolist()})



# ----------------------------------------------------------------------------- params


def program_parameters(program: Program, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """The continuous numbers of ``program`` as a flat (P,) tensor, in text order.

    Order: per block, per statement: Cuboid (l, h, w), attach (x1, y1, z1, x2, y2, z2),
    squeeze (u, v), translate (d). Write values back with
    :func:`shapeprog.lang.replace_numbers`.
    """
    return torch.tensor(numbers(as_program(program, "program_parameters")), dtype=dtype, device=device)


def parameter_names(program: Program) -> list[str]:
    """A readable name per entry of :func:`program_parameters`, e.g. ``'Program_1:3:attach.y2'``
    (block name, 0-based statement index in the block, statement and field)."""
    out = []
    for b in as_program(program, "parameter_names").blocks:
        for i, s in enumerate(b.statements):
            for f in NUM_FIELDS[type(s)]:
                out.append(f"{b.name}:{i}:{type(s).__name__.lower()}.{f}")
    return out



# ----------------------------------------------------------------------------- plan


class ExecutionPlan:
    """Programs compiled for execution, reusable: static structure, index tensors and constants.

    Building a plan does everything that does not depend on the parameter values (the rule of
    every attach, macro expansion, the lock-step schedule, the sub-program tree, the leaf order);
    :meth:`run` then only does tensor arithmetic. :func:`execute` and :func:`execute_batch` build
    a plan per call; a caller that executes the same programs many times (fitting, a training
    loop with fixed structure) builds it once.

    Example:
        >>> from shapeprog.lang import parse
        >>> p = parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\\n"
        ...           "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
        >>> plan = ExecutionPlan([p])
        >>> x = program_parameters(p).requires_grad_(True)
        >>> plan.run([x])[0].centers.tolist()
        [[0.0, -0.4000000059604645, 0.0]]
    """

    def __init__(self, programs: list[Program], dtype: torch.dtype = torch.float32, device=None):
        if isinstance(programs, (Program, str)):
            raise TypeError("`programs` must be a list of programs; use ExecutionPlan([program])")
        self.programs = [as_program(p, "ExecutionPlan") for p in programs]
        self.dtype = dtype
        self.device = torch.device("cpu") if device is None else torch.device(device)
        comps = [compile_program(p) for p in self.programs]
        self.n_params = [c.n_params for c in comps]
        codes, offsets, block_base, param_base = [], [], [], []
        poff = 0
        for c in comps:
            block_base.append(len(codes))
            param_base.append(poff)
            codes.extend(c.blocks)
            offsets.extend([poff] * len(c.blocks))
            poff += c.n_params
        self._param_base = param_base
        if not codes:
            return
        dev = self.device
        S = max(len(c.slots) for c in codes)
        init = []
        for c, off in zip(codes, offsets):
            rows = [(-1, -1, -1) if d is None else tuple(off + i for i in d) for d in c.init_dims]
            init.append(rows + [(-1, -1, -1)] * (S - len(rows)))
        self._nb, self._S = len(codes), S
        self._init_ix = torch.tensor(init, dtype=torch.int64, device=dev).reshape(-1, 3)  # (nb * S, 3)
        self._n_rec = max([sum(1 for o in c.ops if o[0] == "attach") for c in codes] + [1])
        self._steps = plan_steps(codes, offsets, S, self._n_rec, dtype, dev)
        self._levels, self._leaves, self._counts, self._nodes, self._lines = plan_levels(
            comps, block_base, param_base, S, dtype, dev)

    def __len__(self) -> int:
        return len(self.programs)

    def parameters(self) -> list[torch.Tensor]:
        """The programs' own numbers, one (P_i,) tensor each (see :func:`program_parameters`)."""
        return [program_parameters(p, self.dtype, self.device) for p in self.programs]

    def run(self, params: list[torch.Tensor | None] | None = None) -> list[ExecutedShape]:
        """Execute the programs, with their own numbers or with ``params`` (one (P_i,) tensor or
        None per program); the result is differentiable in the given tensors."""
        if not self.programs:
            return []
        if params is not None and len(params) != len(self.programs):
            raise ValueError(f"`params` must hold {len(self.programs)} tensors, got {len(params)}")
        flats = []
        for i, p in enumerate(self.programs):
            t = None if params is None else params[i]
            if t is None:
                t = program_parameters(p, self.dtype, self.device)
            else:
                if t.dim() != 1 or t.shape[0] != self.n_params[i]:
                    raise ValueError(
                        f"`params` for program {i} must have shape ({self.n_params[i]},), got {tuple(t.shape)}")
                t = t.to(dtype=self.dtype, device=self.device)
            flats.append(t)
        flat = torch.cat(flats + [torch.zeros(1, dtype=self.dtype, device=self.device)])  # index -1 -> 0
        pos, dims, ax = self._run_steps(flat)
        return self._place(flat, pos, dims, ax)

    def _run_steps(self, flat: torch.Tensor):
        """Local programs of all blocks in lock step. State in flat rows (block row * S + slot):
        pos (R, 3), dims (R, 3), axes (R, 3, 3)."""
        dtype, device = self.dtype, self.device
        dims = flat[self._init_ix]  # dims from the declaring lines
        R = dims.shape[0]
        pos = torch.zeros(R, 3, dtype=dtype, device=device)
        ax = torch.eye(3, dtype=dtype, device=device).repeat(R, 1, 1)
        rec = torch.zeros(self._nb * self._n_rec * 3, 3, dtype=dtype, device=device)  # src, tgt, g per attach
        for step in self._steps:
            if step.setdims is not None:
                rows, ix = step.setdims
                dims.index_copy_(0, rows, flat[ix])
            if step.copy is not None:
                new, src = step.copy
                n = new.shape[0]
                dims.index_copy_(0, new, dims[src])
                pos.index_fill_(0, new, 0.0)
                ax.index_copy_(0, new, torch.eye(3, dtype=dtype, device=device).expand(n, 3, 3))
            for grp in step.groups:
                _run_attach_group(grp, flat, pos, dims, ax, rec)
        return pos, dims, ax

    def _place(self, flat, pos, dims, ax) -> list[ExecutedShape]:
        """Breadth-first placement, one batched pass per depth (apply_delta and reflect flips)."""
        S = self._S
        pos, dims, ax = pos.view(-1, S, 3), dims.view(-1, S, 3), ax.view(-1, S, 3, 3)
        wps, wds, was = [], [], []
        prev = None
        for lv in self._levels:
            lp, ld, la = pos[lv.rows], dims[lv.rows], ax[lv.rows]
            if lv.pos_sign is not None:
                lp = lp * lv.pos_sign
                la = la * lv.ax_sign
            rdims = ld[:, 0]
            if prev is None:  # roots: the identity frame at the origin, dims from the root bbox line
                wd = ld * (flat[lv.root_ix] / rdims)[:, None]
                wp, wa = lp, la
            else:
                pp, pd, pa = prev
                apos = pp.reshape(-1, 3)[lv.parent]
                adims = pd.reshape(-1, 3)[lv.parent]
                aax = pa.reshape(-1, 3, 3)[lv.parent]
                # apply_delta: scale dims per local axis index, rotate positions (not scaled)
                wd = ld * (adims / rdims)[:, None]
                wp = torch.bmm(lp, aax) + apos[:, None]
                wa = torch.matmul(la, aax[:, None])
            prev = (wp, wd, wa)
            wps.append(wp)
            wds.append(wd)
            was.append(wa)
        if len(wps) == 1:
            wp, wd, wa = wps[0], wds[0], was[0]
        else:
            wp, wd, wa = torch.cat(wps), torch.cat(wds), torch.cat(was)
        rows = self._leaves
        centers = wp.reshape(-1, 3)[rows]
        dd = wd.reshape(-1, 3)[rows]
        aa = wa.reshape(-1, 3, 3)[rows]
        corners = cuboid_corners(centers, dd, aa)
        self._check_finite(centers, dd, aa, corners)
        out = []
        parts = [x.split(self._counts) for x in (centers, dd, aa, corners)]
        for i, (c, d, a, k) in enumerate(zip(*parts)):
            base = self._param_base[i]
            out.append(ExecutedShape(centers=c, dims=d, axes=a, corners=k, node=self._nodes[i],
                                     line=self._lines[i], root_dims=flat[base:base + 3].clone()))
        return out


    def _check_finite(self, centers, dims, axes, corners) -> None:
        """Raise :class:`ExecutionError` at the first leaf (L rows) with a non-finite value."""
        with torch.no_grad():
            ok = torch.cat([centers, dims, axes.flatten(1), corners.flatten(1)], 1).isfinite().all(1)
            if bool(ok.all()):
                return
            row = int((~ok).nonzero()[0])
        for i, n in enumerate(self._counts):
            if row < n:
                line = int(self._lines[i][row]) + 1
                raise ExecutionError("execution gives a non-finite cuboid (created by this line)", line,
                                     None if len(self.programs) == 1 else i)
            row -= n


# ----------------------------------------------------------------------------- run


def _run_attach_group(grp: GroupPlan, flat, pos, dims, ax, rec) -> None:
    """One attach group: move the subjects (state updated in place) and keep the records."""
    n = grp.n
    vals = grp.c0 + grp.c1 * flat[grp.ix]
    src, tgt = vals[:n], vals[n:]
    if grp.macro is not None:
        src, tgt = _macro_points(grp.macro, flat, pos, dims, ax, rec, src, tgt)
    rb, ra = grp.row_b, grp.row_a
    posB, dimsB, axB = pos[rb], dims[rb], ax[rb]
    g = point(posB, dimsB, axB, tgt)
    posA, dimsA, axA = pos[ra], dims[ra], ax[ra]
    mode = grp.mode
    if mode == FIRST:
        posA, dimsA, axA = rule_first(posA, dimsA, axA, src, g)
    elif mode == SECOND:
        r_ap, r_g = grp.prior
        posA, dimsA, axA = rule_second(posA, dimsA, axA, src, g, rec[r_ap], rec[r_g])
    elif mode == ALIGNED:
        posA, dimsA, axA = rule_aligned(posA, dimsA, axA, posB, dimsB, axB)
    else:
        outs = []
        for r, prior in enumerate(grp.general):
            prev = [(rec[r_ap], rec[r_g]) for r_ap, r_g in prior]
            outs.append(rule_general(posA[r:r + 1], dimsA[r:r + 1], axA[r:r + 1], src[r:r + 1], g[r:r + 1], prev))
        posA = torch.cat([o[0] for o in outs])
        dimsA = torch.cat([o[1] for o in outs])
        axA = torch.cat([o[2] for o in outs])
    pos.index_copy_(0, ra, posA)
    if mode != FIRST:  # the first rule only translates
        dims.index_copy_(0, ra, dimsA)
        if mode != ALIGNED:  # the aligned rule never turns a cuboid
            ax.index_copy_(0, ra, axA)
    if grp.rec_rows is not None:  # only records that a later op reads
        recs = torch.stack([src, tgt, g], 1)
        if grp.keep is not None:
            recs = recs[grp.keep]
        rec.index_copy_(0, grp.rec_rows, recs.reshape(-1, 3))


def _macro_points(m: dict, flat, pos, dims, ax, rec, src, tgt):
    """Source/target local points of reflect/translate copies (spec: reflect, translate)."""
    A, T, e = m["A"], m["T"], m["e"]
    ap = rec[m["ap"]]  # the original record's source point on A
    src_m = torch.where(m["flip"], 1 - ap, ap)
    p = point(pos[A], dims[A], ax[A], ap)
    pg = None
    if m["any_ref"]:
        # reflect through the plane through the bbox centre (origin) normal to world axis k
        pg = p - 2 * e * p
    if m["any_tr"]:
        # translate: p + i * (L * d / N) * e, L = local bbox extent along k
        L = (dims[m["box"]] * e).sum(-1)
        step = L * flat[m["didx"]] / m["N"]
        p_tr = p + (m["ii"] * step)[:, None] * e
        pg = p_tr if pg is None else torch.where(m["is_ref"][:, None], pg, p_tr)
    loc = to_local(pos[T], dims[T], ax[T], pg[:, None, :])[:, 0]
    tgt_m = loc.clamp(0.0, 1.0)
    src = src.index_copy(0, m["r_idx"], src_m)
    tgt = tgt.index_copy(0, m["r_idx"], tgt_m)
    return src, tgt


# ----------------------------------------------------------------------------- public API


def execute_batch(programs: list[Program], dtype: torch.dtype = torch.float32, device=None,
                  params: list[torch.Tensor] | None = None) -> list[ExecutedShape]:
    """Execute several programs together (their blocks run in lock step).

    Args:
        programs: parsed programs.
        dtype: float32 (the reference precision) or float64.
        device: torch device (default: that of the first given ``params`` tensor, else CPU).
        params: optional list of (P_i,) tensors (or None), one per program (see
            :func:`program_parameters`); gradients flow to them.

    Returns:
        One :class:`ExecutedShape` per program; equal to calling :func:`execute` on each.
    """
    if isinstance(programs, (Program, str)):
        raise TypeError("execute_batch takes a list of programs; execute(program) runs one")
    programs = [as_program(p, "shapeprog.execute_batch") for p in programs]
    if not programs:
        return []
    if device is None and params is not None:
        device = next((t.device for t in params if t is not None), None)
    return ExecutionPlan(programs, dtype, device).run(params)


def execute(program: Program, dtype: torch.dtype = torch.float32, device=None,
            params: torch.Tensor | None = None) -> ExecutedShape:
    """Execute a ShapeAssembly program (the reference's hierarchical execution).

    Args:
        program: a :class:`~shapeprog.lang.Program` or its text (parsed with :func:`shapeprog.parse`).
        dtype: float32 (the reference precision, default) or float64.
        device: torch device (default: that of ``params``, else CPU).
        params: optional (P,) tensor replacing the program's continuous numbers (text order,
            see :func:`program_parameters`); the result is differentiable in it.

    Returns:
        The :class:`ExecutedShape` of the leaf cuboids.

    Raises:
        ExecutionError: a cuboid comes out with a non-finite value (e.g. a zero bbox extent, or
            ``params`` out of range); it names the line that created the first such cuboid.
    """
    program = as_program(program, "shapeprog.execute")
    return execute_batch([program], dtype, device, None if params is None else [params])[0]
