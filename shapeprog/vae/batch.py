"""The teacher-forced training pass over B program trees at once, level by level (plain PyTorch).

:class:`TreeBatch` flattens B :class:`~shapeprog.vae.vectors.VectorNode` trees into one table of line
rows and one plan per tree depth; :func:`batch_forward` runs the encoder bottom-up (all nodes of a depth
in one GRU call, child codes taking the place of their Cuboid lines) and the decoder top-down (all
nodes of a depth in one :meth:`~shapeprog.vae.model.Decoder.forward` call, each child starting from
the ``next`` output of its Cuboid line), and :func:`batch_loss` scores every shape with the terms and
weights of :func:`~shapeprog.vae.losses.program_loss`. Per shape the result equals
``program_loss(vae(tree), tree)`` (the same z), to float rounding; ``tests/shapeprog/vae/test_train.py``
checks losses and gradients against the per-tree pass.

Example:
    >>> from shapeprog.lang import parse
    >>> from shapeprog.vae.model import VAE
    >>> from shapeprog.vae.vectors import program_to_tree
    >>> box = "bbox = Cuboid(1.0, 1.0, 1.0, True)\\n"  # trees of any sizes share a batch
    >>> seat = box + "cube0 = Cuboid(0.5, 0.25, 0.5, True)\\nattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n"
    >>> batch = TreeBatch([program_to_tree(parse(text)) for text in (box, seat)])
    >>> total, terms = batch_loss(batch_forward(VAE(hidden_dim=32), batch, sample=False), batch)
    >>> tuple(total.shape), tuple(terms["kl"].shape), batch.size, batch.num_nodes, batch.targets.shape[0]
    ((2,), (2,), 2, 2, 6)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import torch
import torch.nn.functional as F

from .losses import _ALIGN_POS_WEIGHT, LOSS_WEIGHTS
from .model import VAE, Decoder, Encoder, NodeOutput, VAEOutput
from .vectors import ALIGNED, AXIS, CMD, CUBE1, CUBE2, CUBE3, DIMS, FACE, LINE_DIM, VectorNode, command_vector, l1_mask

__all__ = [
    "BatchOutput",
    "TreeBatch",
    "batch_forward",
    "batch_loss",
    "collate_trees",
    "decode_batch",
    "encode_batch",
]

_CUBOID, _ATTACH, _REFLECT, _TRANSLATE, _SQUEEZE = 1, 2, 3, 4, 5


@dataclass
class _Level:
    """The plan of the n nodes of one depth, with r line rows in all (T: the longest node's L + 1).

    ``seqs`` indices point into :attr:`TreeBatch.seqs` (S + 1 rows, the last one zero padding); ``row``
    indices into the level's r valid steps, node by node (the rows ``rows`` of :attr:`TreeBatch.targets`).
    """

    depth: int
    rows: slice  # the level's rows of TreeBatch.targets
    enc_index: torch.Tensor  # (n, T + 1) int64 -> seqs rows of [start, l1 .. lL, stop], padded
    enc_last: torch.Tensor  # (n,) int64, L + 1: the stop step, whose GRU output is the node's code
    child_rows: torch.Tensor  # (2, m) int64, (node, sequence position) of each child code, next level's order
    in_rows: torch.Tensor  # (r,) int64 -> seqs rows of the decoder inputs [start, l1 .. lL]
    row_node: torch.Tensor  # (r,) int64 -> the node (0 .. n-1) of each row
    gather: torch.Tensor  # (n, T) int64 -> the row at each step, r for padding
    steps: torch.Tensor  # (r,) int64 -> the place of each row in the flattened (n * T) steps
    bbox_index: torch.Tensor  # (n,) int64 -> the seqs row of each node's first line
    leaf_index: torch.Tensor  # (k,) int64 -> the rows that are Cuboid lines (leaf logits, child latents)
    next_index: torch.Tensor  # (m,) int64 -> the Cuboid lines (of the k) whose child starts a next-level node

    def to(self, device) -> "_Level":
        return _Level(self.depth, self.rows, *(getattr(self, f).to(device) for f in _LEVEL_TENSORS))


_LEVEL_TENSORS = ("enc_index", "enc_last", "child_rows", "in_rows", "row_node", "gather", "steps", "bbox_index",
                  "leaf_index", "next_index")


def _commands_by_node(trees: list, width: int, cmd: slice) -> dict[int, list[int]]:
    """Every node of the trees checked to hold (L >= 1, ``width``) lines of the first tree's dtype and device,
    and its commands read in one argmax over the whole batch: ``{id(node): [command per line]}``."""
    dtype, device = trees[0].lines.dtype, trees[0].lines.device
    flat, frontier = [], list(trees)
    while frontier:
        flat += frontier
        frontier = [c for n in frontier for c in n.children if c is not None]
    for i, n in enumerate(flat):
        x = n.lines
        if not isinstance(x, torch.Tensor) or x.dim() != 2 or x.shape[1] != width or x.shape[0] == 0:
            got = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
            raise ValueError(f"node {i} of the batch: lines must be (L, {width}) with L >= 1, got {got}")
        if x.dtype != dtype or x.device != device:
            raise ValueError(f"node {i} of the batch is {x.dtype} on {x.device}; the batch is {dtype} on {device}")
    cmds_all = torch.cat([n.lines for n in flat])[:, cmd].argmax(dim=1).tolist()
    out, pos = {}, 0
    for n in flat:
        out[id(n)] = cmds_all[pos:pos + n.lines.shape[0]]
        pos += n.lines.shape[0]
    return out


class _LevelRows:
    """The sequence bookkeeping shared by the level plans of :class:`TreeBatch` and :class:`MacroPlan`: per node
    of a depth (n nodes, T steps at most), its ``[start, l1 .. lL, stop]`` block of ``seqs`` rows for the encoder
    and its L + 1 decoder rows; the level's target rows start at the plan's row ``R0``."""

    def __init__(self, n: int, T: int, R0: int):
        self.T, self.R0 = T, R0
        self.enc_index = torch.full((n, T + 1), -1, dtype=torch.int64)
        self.gather = torch.full((n, T), -1, dtype=torch.int64)
        self.enc_last, self.in_rows, self.row_node, self.steps, self.bbox_index = [], [], [], [], []

    def add(self, k: int, L: int, o: int, q0: int) -> None:
        """Node ``k`` of L lines whose sequence starts at ``seqs`` row ``o`` and whose first target row is the
        level's row ``q0``."""
        self.enc_index[k, : L + 2] = torch.arange(o, o + L + 2)
        self.gather[k, : L + 1] = torch.arange(q0, q0 + L + 1)
        self.enc_last.append(L + 1)
        self.bbox_index.append(o + 1)
        self.in_rows += range(o, o + L + 1)
        self.row_node += [k] * (L + 1)
        self.steps += range(k * self.T, k * self.T + L + 1)

    def tensors(self, r: int) -> dict[str, torch.Tensor]:
        """The level's index tensors, padding steps pointing at row ``r`` (one past its rows)."""
        self.gather[self.gather < 0] = r
        t = lambda v: torch.tensor(v, dtype=torch.int64)  # noqa: E731
        return {"enc_index": self.enc_index, "enc_last": t(self.enc_last), "in_rows": t(self.in_rows),
                "row_node": t(self.row_node), "gather": self.gather, "steps": t(self.steps),
                "bbox_index": t(self.bbox_index)}


class _PlanRows:
    """The rows of a plan (:class:`TreeBatch`, :class:`MacroPlan`) as its nodes come, level by level: every
    node's ``[start, l1 .. lL, stop]`` block of ``seqs``, its L + 1 target rows ``[l1 .. lL, stop]`` and the
    leaf terms of the cuboids it creates.

    Args:
        start, stop: (1, width) float, the start and stop rows (their dtype and device are the plan's).
    """

    def __init__(self, start: torch.Tensor, stop: torch.Tensor):
        self.start, self.stop = start, stop
        self.seq_parts: list[torch.Tensor] = []
        self.target_rows: list[int] = []
        self.offset = 0  # the next node's first seqs row
        self.leaf_target: list[float] = []
        self.leaf_weight: list[float] = []
        self.leaf_shape: list[int] = []

    def level(self, current: list, cmds_of: dict[int, list[int]]) -> _LevelRows:
        """The bookkeeping of a new level of nodes ``current`` (``(tree, node)`` pairs)."""
        T = max(len(cmds_of[id(node)]) for _, node in current) + 1
        return _LevelRows(len(current), T, len(self.target_rows))

    def add(self, seq: _LevelRows, k: int, lines: torch.Tensor) -> tuple[int, int]:
        """Node ``k`` of ``seq``'s level with ``lines`` (L, width); returns its first target row in the plan and
        in the level."""
        L, o = len(lines), self.offset
        self.seq_parts += [self.start, lines, self.stop]
        self.offset += L + 2
        r0 = len(self.target_rows)
        seq.add(k, L, o, r0 - seq.R0)
        self.target_rows += range(o + 1, o + L + 2)
        return r0, r0 - seq.R0

    def leaves(self, b: int, children: tuple, count: int) -> tuple[int, list]:
        """The leaf terms of the ``count`` cuboids a node of tree ``b`` creates (a leaf: no child program; each
        weighs 1 / ``count``); returns the first one's index and each one's child node (None for a leaf)."""
        kids = [children[j] if j < len(children) else None for j in range(count)]
        l0 = len(self.leaf_target)
        self.leaf_target += [float(child is None) for child in kids]
        self.leaf_weight += [1.0 / count] * count if count else []
        self.leaf_shape += [b] * count
        return l0, kids

    def span(self, seq: _LevelRows) -> slice:
        """The plan's target rows of ``seq``'s level (once its nodes are added)."""
        return slice(seq.R0, len(self.target_rows))

    def finish(self, plan, levels: list, width: int) -> None:
        """Set the plan's ``seqs`` (every block and a final zero row, (S + 1, width)), ``targets`` (their target
        rows, (R, width)) and ``leaf_target``, ``leaf_weight`` (K,) float, ``leaf_shape`` (K,) int64; the
        padding of the levels' ``enc_index`` is pointed at the zero row."""
        for lv in levels:
            lv.enc_index[lv.enc_index < 0] = self.offset
        dtype, device = self.start.dtype, self.start.device
        plan.seqs = torch.cat(self.seq_parts + [torch.zeros(1, width, dtype=dtype, device=device)])
        plan.targets = plan.seqs[torch.tensor(self.target_rows, dtype=torch.int64, device=device)]
        plan.leaf_target = torch.tensor(self.leaf_target, dtype=dtype, device=device)
        plan.leaf_weight = torch.tensor(self.leaf_weight, dtype=dtype, device=device)
        plan.leaf_shape = torch.tensor(self.leaf_shape, dtype=torch.int64, device=device)


class TreeBatch:
    """B program trees flattened for :func:`batch_forward` and :func:`batch_loss`.

    Every node's sequence ``[start, l1 .. lL, stop]`` is a block of rows of :attr:`seqs`; nodes are
    grouped by depth, and within a depth ordered by their parent's place and then by Cuboid line, so
    each tree's nodes keep their breadth-first order (that of :meth:`VectorNode.nodes`). The predicted
    rows of all nodes, depth by depth, are the rows of :attr:`targets`. Building the plan reads the trees
    once on their device (CPU in training: the collate builds it, :meth:`to` then moves a few tensors).

    Args:
        trees: B >= 1 root nodes, all of one dtype (and device).

    Attributes:
        trees: the trees given (not moved by :meth:`to`).
        size: B.
        num_nodes: N, the nodes of all trees.
        seqs: (S + 1, 63) float, every node's ``[start, l1 .. lL, stop]`` and a final zero row.
        targets: (R, 63) float, the target rows ``[l1 .. lL, stop]`` of every node, depth by depth.
        row_shape: (R,) int64, the tree of each target row.
        l1_mask: (R, 63) float, :func:`~shapeprog.vae.vectors.l1_mask` of the targets.
        kind_rows: target rows by command (``"Cuboid"``, ``"attach"``, ``"reflect"``, ``"translate"``,
            ``"squeeze"``), and ``"align"``, the Cuboid rows but the first of each node; (r_k,) int64 each.
        leaf_target: (K,) float, 1 where a Cuboid line is a leaf (bbox included), per node depth by depth.
        leaf_weight: (K,) float, 1 / (the Cuboid lines of the line's node): the leaf term is a mean per node.
        leaf_shape: (K,) int64, the tree of each Cuboid line.
        root_bbox: (B, 3) float, each root's bbox dims.
        levels: the per-depth plans, root depth first.
    """

    def __init__(self, trees: list[VectorNode]):
        trees = list(trees)
        if not trees:
            raise ValueError("a TreeBatch needs at least one tree, got none")
        for b, t in enumerate(trees):
            if not isinstance(t, VectorNode):
                raise TypeError(f"trees[{b}] is a {type(t).__name__}, not a VectorNode")
        self.trees = trees
        self.size = len(trees)
        ref = trees[0].lines
        dtype, device = ref.dtype, ref.device

        cmds_of = _commands_by_node(trees, LINE_DIM, CMD)

        flat = _PlanRows(command_vector("start", dtype, device)[None], command_vector("stop", dtype, device)[None])
        row_shape: list[int] = []
        kinds: dict[str, list[int]] = {k: [] for k in ("Cuboid", "attach", "reflect", "translate", "squeeze", "align")}
        kind_of = {_CUBOID: "Cuboid", _ATTACH: "attach", _REFLECT: "reflect", _TRANSLATE: "translate",
                   _SQUEEZE: "squeeze"}
        self.levels: list[_Level] = []
        self._node_slices: list[tuple[int, int, int, int, int]] = []  # (tree, row0, rows, leaf0, leaves)
        current: list[tuple[int, VectorNode]] = list(enumerate(trees))
        depth = 0
        while current:
            seq = flat.level(current, cmds_of)
            next_index, leaf_index, child_nodes, child_pos = [], [], [], []
            nxt: list[tuple[int, VectorNode]] = []
            for k, (b, node) in enumerate(current):
                cmds = cmds_of[id(node)]
                L = len(cmds)
                r0, q0 = flat.add(seq, k, node.lines)  # the node's first row in targets and in the level
                row_shape += [b] * (L + 1)
                rows = [i for i, c in enumerate(cmds) if c == _CUBOID]
                for i, c in enumerate(cmds):
                    if c in kind_of:
                        kinds[kind_of[c]].append(r0 + i)
                kinds["align"] += [r0 + i for i in rows[1:]]
                l0, kids = flat.leaves(b, node.children, len(rows))
                for i, child in zip(rows, kids):
                    leaf_index.append(q0 + i)
                    if child is not None:
                        child_nodes.append(k)
                        child_pos.append(i + 1)  # the Cuboid line's place in [start, l1 .. lL, stop]
                        next_index.append(len(leaf_index) - 1)
                        nxt.append((b, child))
                self._node_slices.append((b, r0, L + 1, l0, len(rows)))
            span = flat.span(seq)
            as_tensor = lambda v: torch.tensor(v, dtype=torch.int64)  # noqa: E731
            self.levels.append(_Level(
                depth, span, child_rows=as_tensor([child_nodes, child_pos]),
                leaf_index=as_tensor(leaf_index), next_index=as_tensor(next_index),
                **seq.tensors(span.stop - span.start)))
            current = nxt
            depth += 1
        self.num_nodes = len(self._node_slices)
        flat.finish(self, self.levels, LINE_DIM)
        self.root_bbox = self.seqs[self.levels[0].bbox_index.to(device)][:, DIMS]
        self.l1_mask = l1_mask(self.targets)
        self.row_shape = torch.tensor(row_shape, dtype=torch.int64, device=device)
        self.kind_rows = {k: torch.tensor(v, dtype=torch.int64, device=device) for k, v in kinds.items()}
        self.levels = [lv.to(device) for lv in self.levels]

    @property
    def device(self) -> torch.device:
        """The device of the batch's tensors."""
        return self.seqs.device

    @property
    def dtype(self) -> torch.dtype:
        """The dtype of the line rows."""
        return self.seqs.dtype

    def to(self, device=None, dtype: torch.dtype | None = None, **kwargs) -> "TreeBatch":
        """A copy whose tensors are on ``device`` and whose float rows are ``dtype``; :attr:`trees` stays
        as given (Lightning moves a batch through this method; ``kwargs`` such as ``non_blocking`` are
        passed on)."""
        out = object.__new__(TreeBatch)
        out.__dict__.update(self.__dict__)
        cast = {} if dtype is None else {"dtype": dtype}
        for name in ("seqs", "targets", "l1_mask", "root_bbox", "leaf_target", "leaf_weight"):
            setattr(out, name, getattr(self, name).to(device, **cast, **kwargs))
        out.row_shape = self.row_shape.to(device, **kwargs)
        out.kind_rows = {k: v.to(device, **kwargs) for k, v in self.kind_rows.items()}
        out.leaf_shape = self.leaf_shape.to(device, **kwargs)
        out.levels = [lv.to(device) for lv in self.levels]
        return out

    def __len__(self) -> int:
        return self.size

    def __repr__(self) -> str:
        return (f"TreeBatch(size={self.size}, nodes={self.num_nodes}, rows={self.targets.shape[0]}, "
                f"depths={len(self.levels)}, {self.dtype}, {self.device})")

    def split(self, output: "BatchOutput") -> list[VAEOutput]:
        """The per-tree :class:`~shapeprog.vae.model.VAEOutput` of a batched output (views of its
        tensors), as :meth:`VAE.forward <shapeprog.vae.model.VAE.forward>` lays them out: what
        :func:`~shapeprog.vae.losses.program_loss` and :func:`~shapeprog.vae.model.prediction_tree` take."""
        nodes: list[list[NodeOutput]] = [[] for _ in range(self.size)]
        for b, r0, rows, l0, leaves in self._node_slices:
            nodes[b].append(NodeOutput(output.lines[r0:r0 + rows], output.leaf[l0:l0 + leaves]))
        return [VAEOutput(nodes[b], output.bbox_dims[b], output.mu[b], output.logvar[b], output.z[b])
                for b in range(self.size)]


def collate_trees(trees: list[VectorNode]) -> TreeBatch:
    """The DataLoader collate of program trees: the list kept as :attr:`TreeBatch.trees`, with its plan."""
    return TreeBatch(trees)


@dataclass
class BatchOutput:
    """What :func:`batch_forward` returns for a :class:`TreeBatch` of B trees.

    Attributes:
        lines: (R, 63) float, the predictions for the rows of :attr:`TreeBatch.targets`.
        leaf: (K,) float, the leaf logit of every Cuboid line, in the order of :attr:`TreeBatch.leaf_target`.
        bbox_dims: (B, 3) float, the predicted root bbox dims.
        mu, logvar: (B, H) float, the bottleneck's outputs.
        z: (B, H) float, the latents decoded.
    """

    lines: torch.Tensor
    leaf: torch.Tensor
    bbox_dims: torch.Tensor
    mu: torch.Tensor
    logvar: torch.Tensor
    z: torch.Tensor


def encode_batch(encoder: Encoder, batch: TreeBatch) -> torch.Tensor:
    """The root codes of a batch, bottom-up, one GRU call per depth: (B, H) float.

    Per tree equal to ``encoder.encode_node(tree)``: padding follows each sequence's stop row, and the
    code is the GRU output at the stop step.
    """
    emb = encoder.inp_net(batch.seqs)  # (S + 1, H); the padding row's embedding is never read
    codes = None
    H = encoder.hidden_dim
    for lv in reversed(batch.levels):
        x = emb[lv.enc_index]  # (n, T + 1, H)
        if lv.child_rows.shape[1]:
            x = x.index_put((lv.child_rows[0], lv.child_rows[1]), codes)
        n = x.shape[0]
        out, _ = encoder.gru(x, encoder.h_start.expand(1, n, H).contiguous())
        codes = out[torch.arange(n, device=out.device), lv.enc_last]
    return codes


def decode_batch(decoder: Decoder, batch: TreeBatch, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Teacher-forced decoding of a batch from latents ``z`` (B, H), top-down, one GRU call per depth.

    Per node equal to ``decoder(node.input_seq()[None], ...)`` with the target as teacher: the input
    embedding and the line heads (:meth:`Decoder.embed`, :meth:`Decoder.heads`) run on the valid steps only,
    the child and leaf heads (:meth:`Decoder.child_heads`) on the Cuboid lines only, and the GRU on the
    nodes of a depth padded to the longest.

    Returns:
        ``(lines (R, 63), leaf (K,))``: the predictions for the rows of :attr:`TreeBatch.targets` and the
        leaf logits of the Cuboid lines (:attr:`TreeBatch.leaf_target` order).
    """
    latent = z
    lines, leaves = [], []
    for lv in batch.levels:
        n, T = lv.gather.shape
        bbox = batch.seqs[lv.bbox_index][:, DIMS][lv.row_node]  # (r, 3)
        emb = decoder.embed(batch.seqs[lv.in_rows], bbox, lv.depth)  # (r, H)
        x = torch.cat([emb, emb.new_zeros(1, emb.shape[1])])[lv.gather]  # (n, T, H), zero padding
        out, _ = decoder.gru(x, latent[None].contiguous())
        out = out.reshape(n * T, -1)[lv.steps]  # (r, H)
        lines.append(decoder.heads(out, bbox, batch.targets[lv.rows]))
        cub = lv.leaf_index
        nxt, leaf = decoder.child_heads(out[cub], latent[lv.row_node[cub]])
        leaves.append(leaf)
        latent = nxt[lv.next_index]
    return torch.cat(lines), torch.cat(leaves)


def _latents(mu: torch.Tensor, logvar: torch.Tensor, sample: bool, generator: torch.Generator | None,
             eps: torch.Tensor | None) -> torch.Tensor:
    """The latents (B, H) of a batched pass: ``mu``, or ``mu + eps * exp(logvar / 2)`` when ``sample`` (``eps``
    drawn by ``generator`` unless given)."""
    if not sample:
        return mu
    if eps is None:
        eps = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=mu.device)
    elif eps.shape != mu.shape:
        raise ValueError(f"eps must be (B, H) = {tuple(mu.shape)}, got {tuple(eps.shape)}")
    return mu + eps * torch.exp(0.5 * logvar)


def batch_forward(vae: VAE, batch: TreeBatch, sample: bool = True, generator: torch.Generator | None = None,
                  eps: torch.Tensor | None = None) -> BatchOutput:
    """Encode and decode a batch teacher-forced: :meth:`VAE.forward <shapeprog.vae.model.VAE.forward>` for B
    trees at once.

    Args:
        vae: the model (on the batch's device and dtype).
        batch: the trees.
        sample: ``z = mu + eps * exp(logvar / 2)``; False decodes ``z = mu``.
        generator: draws ``eps`` (B, H) when ``sample`` and no ``eps`` is given.
        eps: (B, H) float, the noise to use (so that a per-tree pass can be given the same).

    Returns:
        A :class:`BatchOutput`.
    """
    mu, logvar = vae.encoder.sampler(encode_batch(vae.encoder, batch))
    z = _latents(mu, logvar, sample, generator, eps)
    lines, leaf = decode_batch(vae.decoder, batch, z)
    return BatchOutput(lines, leaf, vae.decoder.bbox(z), mu, logvar, z)


def batch_loss(output: BatchOutput, batch: TreeBatch, weights: Mapping[str, float] | None = None,
               kl: bool = True) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The weighted loss of every shape of a batch: :func:`~shapeprog.vae.losses.program_loss` per tree.

    Args:
        output: :func:`batch_forward` of ``batch``.
        batch: the target trees.
        weights: per-term weights; default :data:`~shapeprog.vae.losses.LOSS_WEIGHTS` (a missing term weighs 0).
        kl: include the KL term (False reports it as 0).

    Returns:
        ``(total, terms)``: (B,) float, the weighted sum per shape, and each unweighted term per shape,
        (B,) float each, named as in ``program_loss``.
    """
    weights = LOSS_WEIGHTS if weights is None else weights
    pred, tgt, B = output.lines, batch.targets, batch.size
    if pred.shape != tgt.shape:
        raise ValueError(f"output.lines must be {tuple(tgt.shape)} for this batch, got {tuple(pred.shape)}")
    zeros = pred.new_zeros(B)

    def per_shape(values: torch.Tensor, rows: torch.Tensor | None = None) -> torch.Tensor:
        shape = batch.row_shape if rows is None else batch.row_shape[rows]
        return zeros.index_add(0, shape, values)

    def ce(rows: torch.Tensor, part: slice) -> torch.Tensor:
        if rows.numel() == 0:
            return zeros
        return per_shape(F.cross_entropy(pred[rows, part], tgt[rows, part].argmax(dim=1), reduction="none"), rows)

    rows = batch.kind_rows
    sym = torch.cat([rows["reflect"], rows["translate"]])
    l1 = (batch.l1_mask * (pred - tgt).abs()).sum(dim=1)
    terms = {
        "cmd": per_shape(F.cross_entropy(pred[:, CMD], tgt[:, CMD].argmax(dim=1), reduction="none")),
        "cub_prm": per_shape(l1[rows["Cuboid"]], rows["Cuboid"]),
        "xyz_prm": per_shape(l1[rows["attach"]], rows["attach"]),
        "uv_prm": per_shape(l1[rows["squeeze"]], rows["squeeze"]),
        "sym_prm": per_shape(l1[rows["translate"]], rows["translate"]),
        "cub": ce(rows["attach"], CUBE1) + ce(rows["attach"], CUBE2),
        "sym_cub": ce(sym, CUBE1),
        "sq_cub": ce(rows["squeeze"], CUBE1) + ce(rows["squeeze"], CUBE2) + ce(rows["squeeze"], CUBE3),
        "axis": ce(sym, AXIS),
        "face": ce(rows["squeeze"], FACE),
    }
    later = rows["align"]
    if later.numel():
        pw = torch.tensor(_ALIGN_POS_WEIGHT, dtype=pred.dtype, device=pred.device)
        terms["align"] = per_shape(F.binary_cross_entropy_with_logits(
            pred[later, ALIGNED], tgt[later, ALIGNED], reduction="none", pos_weight=pw), later)
    else:
        terms["align"] = zeros
    leaf = F.binary_cross_entropy_with_logits(output.leaf, batch.leaf_target, reduction="none")
    terms["leaf"] = zeros.index_add(0, batch.leaf_shape, leaf * batch.leaf_weight)
    terms["bb"] = (output.bbox_dims - batch.root_bbox).abs().sum(dim=1)
    terms["kl"] = -(1 + output.logvar - output.mu.pow(2) - output.logvar.exp()).sum(dim=1) if kl else zeros
    total = sum((weights.get(k, 0.0) * v for k, v in terms.items()), zeros)
    return total, terms
