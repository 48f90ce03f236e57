"""The teacher-forced training pass over B macro-program trees (ShapeMOD's Appendix C) at once, level by
level (plain PyTorch): :class:`MacroTreeBatch` and its per-depth :class:`MacroPlan`,
:func:`macro_batch_forward` and :func:`macro_batch_loss`, the macro counterparts of
:mod:`shapeprog.vae.batch`, scored with the terms of :func:`~shapeprog.vae.losses.macro_program_loss`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import torch
import torch.nn.functional as F

from .model import NodeOutput, VAEOutput
from .batch import BatchOutput, _PlanRows, _commands_by_node, _latents
from .losses import MACRO_LOSS_WEIGHTS

__all__ = [
    "MacroPlan",
    "MacroTreeBatch",
    "collate_macro_trees",
    "macro_batch_forward",
    "macro_batch_loss",
]


# ------------------------------------------------------------------------ macro programs (ShapeMOD)


@dataclass
class _MacroLevel:
    """The plan of the n nodes of one depth of a :class:`MacroTreeBatch` (r line rows; T: the longest L + 1).

    Indices as in :class:`_Level`: ``seqs`` rows, level rows (of the level's r target rows), and the
    created cuboids (``creator_*``, k of them) whose child latents and leaf logits the decoder predicts.
    """

    depth: int
    rows: slice  # the level's rows of the plan's targets
    enc_index: torch.Tensor  # (n, T + 1) int64 -> seqs rows of [start, l1 .. lL, stop], padded
    enc_last: torch.Tensor  # (n,) int64, L + 1: the stop step, whose GRU output is the node's code
    kid_at: torch.Tensor  # (2, m) int64, (node, sequence position) of the line creating each child
    kid_pos: torch.Tensor  # (m,) int64, the child's cuboid's place among its line's created cuboids
    in_rows: torch.Tensor  # (r,) int64 -> seqs rows of the decoder inputs [start, l1 .. lL]
    row_node: torch.Tensor  # (r,) int64 -> the node of each row
    gather: torch.Tensor  # (n, T) int64 -> the level row at each step, r for padding
    steps: torch.Tensor  # (r,) int64 -> the place of each row in the flattened (n * T) steps
    bbox_index: torch.Tensor  # (n,) int64 -> the seqs row of each node's bbox line
    creator_row: torch.Tensor  # (k,) int64 -> the level row of the line creating each cuboid
    creator_pos: torch.Tensor  # (k,) int64, its place among the line's created cuboids
    creator_node: torch.Tensor  # (k,) int64 -> its node
    next_index: torch.Tensor  # (m,) int64 -> the created cuboids (of the k) whose child is a next-level node

    def to(self, device) -> "_MacroLevel":
        return _MacroLevel(self.depth, self.rows, *(getattr(self, f).to(device) for f in _MACRO_LEVEL_TENSORS))


_MACRO_LEVEL_TENSORS = ("enc_index", "enc_last", "kid_at", "kid_pos", "in_rows", "row_node", "gather", "steps",
                        "bbox_index", "creator_row", "creator_pos", "creator_node", "next_index")


class MacroPlan:
    """B macro-program trees of one layout flattened for :func:`macro_batch_forward` and
    :func:`macro_batch_loss`, depth by depth, as :class:`TreeBatch` flattens base-language trees.

    Within a depth the nodes are ordered by their parent's place and then by created cuboid, so every
    tree's nodes keep the breadth-first order of :meth:`~shapeprog.vae.layout.MacroNode.nodes`.

    Attributes:
        layout: the :class:`~shapeprog.vae.layout.LineLayout`.
        size: B.
        seqs: (S + 1, width) float, every node's ``[start, l1 .. lL, stop]`` and a final zero row.
        targets: (R, width) float, every node's ``[l1 .. lL, stop]``, depth by depth.
        commands: (R,) int64, the command of each target row.
        row_shape: (R,) int64, the tree of each target row.
        first_row: (R,) bool, True on each node's first target row (its bbox line, whose flag is not learnt).
        leaf_target, leaf_weight, leaf_shape: (K,) per created cuboid: 1 when it has no child program, 1 / (its
            node's created cuboids), its tree.
        root_bbox: (B, 3) float, each root's bbox dims.
        levels: the per-depth plans, root depth first.
    """

    def __init__(self, trees: list, layout):
        self.layout, self.size = layout, len(trees)
        ref = trees[0].lines
        dtype, device = ref.dtype, ref.device
        cmds_of = _commands_by_node(trees, layout.width, layout.slices["cmd"])
        n_created = layout.n_created.tolist()
        flat = _PlanRows(layout.command_vector("start", dtype, device)[None],
                         layout.command_vector("stop", dtype, device)[None])
        commands, row_shape, first_row = [], [], []
        self.levels: list[_MacroLevel] = []
        self._node_slices: list[tuple[int, int, int, int, int]] = []  # (tree, row0, rows, leaf0, leaves)
        depth = 0
        current = list(enumerate(trees))
        as_tensor = lambda v: torch.tensor(v, dtype=torch.int64)  # noqa: E731
        while current:
            seq = flat.level(current, cmds_of)
            kid_node, kid_row, kid_pos = [], [], []
            creator_row, creator_pos, creator_node, next_index = [], [], [], []
            nxt = []
            for k, (b, node) in enumerate(current):
                cmds = cmds_of[id(node)]
                L = len(cmds)
                r0, q0 = flat.add(seq, k, node.lines)
                commands += cmds + [layout.STOP]
                row_shape += [b] * (L + 1)
                first_row += [True] + [False] * L
                creators = [(0, 0)] + [(i, j) for i, c in enumerate(cmds[1:], start=1) for j in range(n_created[c])]
                l0, kids = flat.leaves(b, node.children, len(creators))
                for (row, p), child in zip(creators, kids):
                    creator_row.append(q0 + row)
                    creator_pos.append(p)
                    creator_node.append(k)
                    if child is not None:
                        kid_node.append(k)
                        kid_row.append(row + 1)  # the creating line's place in [start, l1 .. lL, stop]
                        kid_pos.append(p)
                        next_index.append(len(creator_row) - 1)
                        nxt.append((b, child))
                self._node_slices.append((b, r0, L + 1, l0, len(creators)))
            span = flat.span(seq)
            self.levels.append(_MacroLevel(
                depth, span, kid_at=as_tensor([kid_node, kid_row]), kid_pos=as_tensor(kid_pos),
                creator_row=as_tensor(creator_row), creator_pos=as_tensor(creator_pos),
                creator_node=as_tensor(creator_node), next_index=as_tensor(next_index),
                **seq.tensors(span.stop - span.start)))
            current = nxt
            depth += 1
        flat.finish(self, self.levels, layout.width)
        self.commands = torch.tensor(commands, dtype=torch.int64, device=device)
        self.row_shape = torch.tensor(row_shape, dtype=torch.int64, device=device)
        self.first_row = torch.tensor(first_row, dtype=torch.bool, device=device)
        self.levels = [lv.to(device) for lv in self.levels]
        f0 = layout.slices["float"].start
        self.bbox_rows = {lv.depth: self.seqs[lv.bbox_index][:, f0:f0 + 3] for lv in self.levels}
        self.root_bbox = self.bbox_rows[0]

    def split(self, output: "BatchOutput") -> list[VAEOutput]:
        """The per-tree :class:`~shapeprog.vae.model.VAEOutput` of a batched output, laid out as
        :meth:`MacroVAE.forward <shapeprog.vae.macro_model.MacroVAE.forward>` lays it out."""
        nodes: list[list[NodeOutput]] = [[] for _ in range(self.size)]
        for b, r0, rows, l0, leaves in self._node_slices:
            nodes[b].append(NodeOutput(output.lines[r0:r0 + rows], output.leaf[l0:l0 + leaves]))
        return [VAEOutput(nodes[b], output.bbox_dims[b], output.mu[b], output.logvar[b], output.z[b])
                for b in range(self.size)]



class MacroTreeBatch:
    """B macro-program trees (:class:`~shapeprog.vae.layout.MacroNode`) of one layout, for
    :func:`macro_batch_forward` and :func:`macro_batch_loss`; the level-by-level plan (:class:`MacroPlan`) is
    built for the model's layout at the first pass and kept.

    Attributes:
        trees: the trees, on the batch's device.
        size: B.
    """

    def __init__(self, trees: list):
        self.trees = list(trees)
        if not self.trees:
            raise ValueError("a batch needs at least one tree")
        self.size = len(self.trees)
        self._plans: dict[int, MacroPlan] = {}

    @property
    def device(self) -> torch.device:
        return self.trees[0].lines.device

    @property
    def dtype(self) -> torch.dtype:
        return self.trees[0].lines.dtype

    def plan(self, layout) -> MacroPlan:
        """The :class:`MacroPlan` of the trees for ``layout`` (built once per layout)."""
        key = id(layout)
        if key not in self._plans:
            self._plans[key] = MacroPlan(self.trees, layout)
        return self._plans[key]

    def to(self, device=None, dtype: torch.dtype | None = None, **kwargs) -> "MacroTreeBatch":
        return MacroTreeBatch([t.to(device, dtype) for t in self.trees])

    def __len__(self) -> int:
        return self.size

    def __repr__(self) -> str:
        return f"MacroTreeBatch({self.size} trees)"


def collate_macro_trees(trees: list) -> MacroTreeBatch:
    """The DataLoader collate of macro-program trees."""
    return MacroTreeBatch(trees)


def macro_batch_forward(vae, batch: MacroTreeBatch, sample: bool = True, generator: torch.Generator | None = None,
                        eps: torch.Tensor | None = None, codes: torch.Tensor | None = None) -> BatchOutput:
    """Encode and decode a batch of macro programs teacher-forced, one GRU call per depth each way:
    :meth:`MacroVAE.forward <shapeprog.vae.macro_model.MacroVAE.forward>` for B trees at once (per tree equal
    to it to float rounding, given the same noise).

    Args:
        vae: a :class:`~shapeprog.vae.macro_model.MacroVAE` (on the batch's device and dtype).
        batch: the trees.
        sample: ``z = mu + eps * exp(logvar / 2)``; False decodes ``z = mu``.
        generator: draws ``eps`` (B, H) when ``sample`` and no ``eps`` is given.
        eps: (B, H) float, the noise to use.
        codes: (B, H) float, latents to decode instead of the trees' encodings (``mu`` = ``z`` = ``codes`` and
            ``logvar`` = 0 then).

    Returns:
        A :class:`BatchOutput`: ``lines`` (R, width) for the plan's target rows, ``leaf`` (K,) per created cuboid.
    """
    plan = batch.plan(vae.layout)
    enc, dec = vae.encoder, vae.decoder
    if codes is None:
        emb = enc.inp_net(plan.seqs)
        H, lay = enc.hidden_dim, vae.layout
        kids = None
        for lv in reversed(plan.levels):
            x = emb[lv.enc_index]  # (n, T + 1, H)
            if lv.kid_pos.numel():
                pos = F.one_hot(lv.kid_pos, lay.max_created).to(kids.dtype)
                add = enc.kid_net(torch.cat([kids, pos], dim=-1))
                x = x.index_put((lv.kid_at[0], lv.kid_at[1]), add, accumulate=True)
            n = x.shape[0]
            out, _ = enc.gru(x, enc.h_start.expand(1, n, H).contiguous())
            kids = out[torch.arange(n, device=out.device), lv.enc_last]
        mu, logvar = enc.sampler(kids)
        z = _latents(mu, logvar, sample, generator, eps)
    else:
        if codes.dim() != 2 or codes.shape[0] != batch.size:
            raise ValueError(f"codes must be (B, H) with B = {batch.size}, got {tuple(codes.shape)}")
        z = mu = codes
        logvar = torch.zeros_like(codes)
    latent, lines, leaves = z, [], []
    for lv in plan.levels:
        n, T = lv.gather.shape
        bbox = plan.bbox_rows[lv.depth][lv.row_node]  # (r, 3)
        emb = dec.embed(plan.seqs[lv.in_rows], bbox, lv.depth)
        x = torch.cat([emb, emb.new_zeros(1, emb.shape[1])])[lv.gather]
        out, _ = dec.gru(x, latent[None].contiguous())
        out = out.reshape(n * T, -1)[lv.steps]
        lines.append(dec.heads(out, bbox, plan.targets[lv.rows]))
        nxt, leaf = dec.child_heads(out[lv.creator_row], latent[lv.creator_node], lv.creator_pos)
        leaves.append(leaf)
        latent = nxt[lv.next_index]
    return BatchOutput(torch.cat(lines), torch.cat(leaves), dec.bbox(z), mu, logvar, z)


def macro_batch_loss(vae, batch: MacroTreeBatch, sample: bool = True, weights: Mapping[str, float] | None = None,
                     kl: bool = True, generator: torch.Generator | None = None, codes: torch.Tensor | None = None,
                     eps: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """``(total (B,), terms {name: (B,)})``: :func:`~shapeprog.vae.losses.macro_program_loss` of each tree of
    the batch under ``vae`` (a :class:`~shapeprog.vae.macro_model.MacroVAE`), z sampled when ``sample``,
    computed by :func:`macro_batch_forward` (equal per tree to the tree-by-tree pass, to float rounding).

    With ``codes`` (B, H) each tree is decoded teacher-forced from its row instead of its own encoding (a
    point-cloud encoder's codes, :mod:`shapeprog.pointcloud.train`); there is no posterior then, so ``kl``
    must be False.
    """
    if codes is not None and kl:
        raise ValueError("codes given: there is no posterior to take a KL term of; pass kl=False")
    out = macro_batch_forward(vae, batch, sample=sample, generator=generator, eps=eps, codes=codes)
    plan, lay = batch.plan(vae.layout), vae.layout
    weights = MACRO_LOSS_WEIGHTS if weights is None else weights
    pred, tgt, cmds = out.lines, plan.targets, plan.commands
    zeros = pred.new_zeros(batch.size)
    shape_of = plan.row_shape

    def per_shape(values: torch.Tensor, shapes: torch.Tensor) -> torch.Tensor:
        return zeros.index_add(0, shapes, values)

    terms = {"cmd": per_shape(F.cross_entropy(pred[:, lay.slices["cmd"]], cmds, reduction="none"), shape_of)}
    for t in ("cube", "face", "axis"):
        if not lay.counts[t]:
            terms[t] = zeros
            continue
        used = lay.masks[t].to(pred.device)[cmds]  # (R, k)
        logits, want = lay.part(pred, t)[used], lay.part(tgt, t)[used]
        terms[t] = per_shape(F.cross_entropy(logits, want.argmax(-1), reduction="none"),
                             shape_of[:, None].expand_as(used)[used])
    if lay.counts["float"]:
        used = lay.masks["float"].to(pred.device)[cmds]
        fs = lay.slices["float"]
        terms["float"] = per_shape((pred[:, fs][used] - tgt[:, fs][used]).abs(), shape_of[:, None].expand_as(used)[used])
    else:
        terms["float"] = zeros
    if lay.counts["bool"]:
        used = lay.masks["bool"].to(pred.device)[cmds] & ~plan.first_row[:, None]
        bs = lay.slices["bool"]
        terms["bool"] = per_shape(F.binary_cross_entropy_with_logits(pred[:, bs][used], tgt[:, bs][used],
                                                                     reduction="none"),
                                  shape_of[:, None].expand_as(used)[used])
    else:
        terms["bool"] = zeros
    leaf = F.binary_cross_entropy_with_logits(out.leaf, plan.leaf_target, reduction="none")
    terms["leaf"] = per_shape(leaf * plan.leaf_weight, plan.leaf_shape)
    terms["bb"] = (out.bbox_dims - plan.root_bbox).abs().sum(dim=1)
    terms["kl"] = -(1 + out.logvar - out.mu.pow(2) - out.logvar.exp()).sum(dim=1) if kl else zeros
    total = sum((weights.get(k, 0.0) * v for k, v in terms.items()), zeros)
    return total, terms
