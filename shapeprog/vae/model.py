"""The encoder, decoder and VAE of the ShapeAssembly generative model (plain PyTorch).

:class:`Encoder` (the reference's ``ENCGRU``) codes a :class:`~shapeprog.vae.vectors.VectorNode` tree
bottom-up, a child's code replacing its Cuboid line's embedding; :class:`Decoder` (``FDGRU``) predicts
line vectors, child latents and leaf logits, one GRU step per line; :class:`VAE` joins them with the
teacher-forced pass that training uses. Sizes, heads and decisions: ``docs/shapeassembly_vae.md``.
The attribute names follow the reference modules, so their ``state_dict`` keys match.

Example:
    >>> from shapeprog.lang import parse
    >>> from shapeprog.vae.vectors import program_to_tree
    >>> tree = program_to_tree(parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\n"
    ...     "cube0 = Cuboid(0.5, 0.25, 0.5, True)\\nattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n"))
    >>> vae = VAE(hidden_dim=32)
    >>> out = vae(tree, sample=False)
    >>> tuple(out.nodes[0].lines.shape), tuple(out.nodes[0].leaf.shape), tuple(out.bbox_dims.shape)
    ((4, 63), (2,), (3,))
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .vectors import CMD, CUBE1, CUBES, LINE_DIM, NUM_SLOTS, VectorNode, command_vector

__all__ = ["MLP", "Decoder", "DecoderStep", "Encoder", "NodeOutput", "Sampler", "VAE", "VAEOutput", "one_hot_argmax",
           "prediction_tree"]


def check_dropout(p: float) -> float:
    """``p`` as a float in [0, 1).

    Raises:
        ValueError: outside [0, 1).
    """
    if not 0.0 <= float(p) < 1.0:
        raise ValueError(f"dropout must be in [0, 1), got {p!r}")
    return float(p)


class MLP(nn.Module):
    """Three Linear layers with leaky-ReLU(0.2) after the first two: ``(*, in) -> (*, out)``."""

    def __init__(self, in_dim: int, hidden1: int, hidden2: int, out_dim: int):
        super().__init__()
        self.l1 = nn.Linear(in_dim, hidden1)
        self.l2 = nn.Linear(hidden1, hidden2)
        self.l3 = nn.Linear(hidden2, out_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.leaky_relu(self.l1(x), 0.2)
        x = F.leaky_relu(self.l2(x), 0.2)
        return self.l3(x)


class Sampler(nn.Module):
    """The VAE bottleneck: ``h (*, H) -> (mu (*, H), logvar (*, H))`` through Linear + ReLU."""

    def __init__(self, hidden_dim: int):
        super().__init__()
        self.mlp1 = nn.Linear(hidden_dim, hidden_dim)
        self.mlp2mu = nn.Linear(hidden_dim, hidden_dim)
        self.mlp2var = nn.Linear(hidden_dim, hidden_dim)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        e = torch.relu(self.mlp1(x))
        return self.mlp2mu(e), self.mlp2var(e)


class Encoder(nn.Module):
    """``ENCGRU``: a program tree -> a code, bottom-up.

    Each node's sequence ``[start, l1 .. lL, stop]`` is embedded by an MLP 63 -> H -> H -> H; at each
    Cuboid line with a child the embedding is replaced by the child's code; a GRU from a learned
    start state reads the sequence and its final hidden state is the node's code.

    Args:
        hidden_dim: H (256 in the reference: 740,352 parameters).
    """

    def __init__(self, hidden_dim: int = 256):
        super().__init__()
        self.hidden_dim = hidden_dim
        self.gru = nn.GRU(hidden_dim, hidden_dim, batch_first=True)
        self.inp_net = MLP(LINE_DIM, hidden_dim, hidden_dim, hidden_dim)
        self.sampler = Sampler(hidden_dim)
        self.h_start = nn.Parameter(torch.randn(1, 1, hidden_dim))

    def encode_node(self, node: VectorNode) -> torch.Tensor:
        """The code of ``node`` and its sub-tree: (H,) float."""
        x = node.lines
        seq = torch.cat([command_vector("start", x.dtype, x.device)[None], x,
                         command_vector("stop", x.dtype, x.device)[None]])
        emb = self.inp_net(seq)
        rows = node.cuboid_rows.tolist()
        kids = [(rows[j] + 1, c) for j, c in enumerate(node.children[: len(rows)]) if c is not None]
        if kids:
            pos = torch.tensor([p for p, _ in kids], device=x.device)
            codes = torch.stack([self.encode_node(c) for _, c in kids])
            emb = emb.index_copy(0, pos, codes)
        _, h = self.gru(emb[None], self.h_start)
        return h[0, 0]

    def forward(self, tree: VectorNode) -> tuple[torch.Tensor, torch.Tensor]:
        """``(mu (H,), logvar (H,))`` of the root's code through the bottleneck."""
        return self.sampler(self.encode_node(tree))


def one_hot_argmax(x: torch.Tensor, groups: int = 1) -> torch.Tensor:
    """One-hot of the argmax of each of ``groups`` equal parts of the last dim: (*, N) -> (*, N)."""
    parts = x.reshape(*x.shape[:-1], groups, -1)
    out = F.one_hot(parts.argmax(-1), parts.shape[-1]).to(x.dtype)
    return out.reshape(x.shape)


@dataclass
class DecoderStep:
    """What :meth:`Decoder.forward` returns for B sequences of T steps.

    Attributes:
        lines: (B, T, 63) float, the predicted line vectors (logits for one-hots and aligned).
        next: (B, T, H) float, the child latent proposed at each step.
        leaf: (B, T) float, the leaf logit at each step (>= 0: leaf).
        h: (1, B, H) float, the GRU state after the last step.
    """

    lines: torch.Tensor
    next: torch.Tensor
    leaf: torch.Tensor
    h: torch.Tensor


class Decoder(nn.Module):
    """``FDGRU``: a latent -> line vectors, one GRU step per line, with a head per field.

    Args:
        hidden_dim: H (256 in the reference: 1,406,403 parameters).
        dropout: dropout on the GRU's input embeddings in training (0, the reference: none; ours, a
            regulariser; it has no weights, so it does not change the state dict).
    """

    def __init__(self, hidden_dim: int = 256, dropout: float = 0.0):
        super().__init__()
        h = hidden_dim
        self.hidden_dim = h
        self.input_dropout = nn.Dropout(check_dropout(dropout))
        self.bbdimNet = MLP(h, h, h, 3)  # noqa: N815 - the reference's state_dict key
        self.gru = nn.GRU(h, h, batch_first=True)
        self.inp_net = MLP(LINE_DIM + 3 + 3, h, h, h)
        self.cmd_net = MLP(h, h // 2, h // 4, 7)
        self.cube_net = MLP(h + 7, h // 2, h // 4, 3 * NUM_SLOTS)
        self.dim_net = MLP(h + 3, h // 2, h // 4, 3)
        self.align_net = MLP(h + 3, h // 2, h // 4, 1)
        self.att_net = MLP(h + 2 * NUM_SLOTS, h, h, 6)
        self.squeeze_net = MLP(h + 3 * NUM_SLOTS, h // 2, h // 4, 8)
        self.sym_net = MLP(h + 3 + NUM_SLOTS, h // 2, h // 4, 5)
        self.next_net = MLP(2 * h, h, h, h)
        self.leaf_net = MLP(2 * h, h // 2, h // 8, 1)

    def forward(self, inp: torch.Tensor, h: torch.Tensor, h_start: torch.Tensor, bbox_dims: torch.Tensor,
                depth: int, teacher: torch.Tensor | None = None) -> DecoderStep:
        """Run B sequences of T input lines.

        Args:
            inp: (B, T, 63) float, the input line vectors (``[start, l1 ..]`` when teacher forcing).
            h: (1, B, H) float, the GRU state (the latent at a node's start).
            h_start: (1, B, H) float, the latent the node started from (for the child and leaf heads).
            bbox_dims: (B, 3) float, the node's bbox dims.
            depth: the node's depth (root 0); the network sees ``min(depth, 2)`` one-hot.
            teacher: (B, T, >= 40) float, the target lines whose command and cube one-hots feed the
                heads; None uses the argmax of this step's own predictions.

        Returns:
            A :class:`DecoderStep`.
        """
        if inp.dim() != 3 or inp.shape[2] != LINE_DIM:
            raise ValueError(f"inp must be (B, T, {LINE_DIM}), got {tuple(inp.shape)}")
        B, T, _ = inp.shape
        bb = bbox_dims[:, None, :].expand(B, T, 3)
        out, h = self.gru(self.embed(inp, bb, depth), h)
        nxt, leaf = self.child_heads(out, h_start.transpose(0, 1).expand(B, T, -1))
        return DecoderStep(self.heads(out, bb, teacher), nxt, leaf, h)

    def embed(self, inp: torch.Tensor, bbox_dims: torch.Tensor, depth: int) -> torch.Tensor:
        """The GRU's input: ``inp_net`` of the line, the bbox dims and the depth one-hot.

        Args:
            inp: (*, 63) float, input line vectors.
            bbox_dims: (*, 3) float, the bbox dims of each line's node.
            depth: the nodes' depth (the network sees ``min(depth, 2)`` one-hot).

        Returns:
            (*, H) float.
        """
        hier = inp.new_zeros(*inp.shape[:-1], 3)
        hier[..., min(int(depth), 2)] = 1.0
        return self.input_dropout(self.inp_net(torch.cat([inp, bbox_dims, hier], dim=-1)))

    def heads(self, out: torch.Tensor, bbox_dims: torch.Tensor, teacher: torch.Tensor | None = None) -> torch.Tensor:
        """The line vector predicted from GRU outputs, one head per field (no recurrence: any leading shape).

        Args:
            out: (*, H) float, GRU outputs.
            bbox_dims: (*, 3) float, the bbox dims of each step's node.
            teacher: (*, >= 40) float, target lines whose command and cube one-hots feed the heads; None
                uses the argmax of the step's own predictions.

        Returns:
            (*, 63) float, as :attr:`DecoderStep.lines`.
        """
        cmd = self.cmd_net(out)
        cmd_oh = teacher[..., CMD] if teacher is not None else one_hot_argmax(cmd)
        cube = self.cube_net(torch.cat([out, cmd_oh], dim=-1))
        cube_oh = teacher[..., CUBES] if teacher is not None else one_hot_argmax(cube, 3)
        return torch.cat([
            cmd,
            cube,
            self.dim_net(torch.cat([out, bbox_dims], dim=-1)),
            self.att_net(torch.cat([out, cube_oh[..., : 2 * NUM_SLOTS]], dim=-1)),
            self.sym_net(torch.cat([out, cube_oh[..., : CUBE1.stop - CUBE1.start], bbox_dims], dim=-1)),
            self.squeeze_net(torch.cat([out, cube_oh], dim=-1)),
            self.align_net(torch.cat([out, bbox_dims], dim=-1)),
        ], dim=-1)

    def child_heads(self, out: torch.Tensor, h_start: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The child latent and leaf logit of steps: ``out`` (*, H) GRU outputs and ``h_start`` (*, H), the
        latent each step's node started from -> ``(next (*, H), leaf (*,))``, as in :class:`DecoderStep`."""
        ctx = torch.cat([out, h_start], dim=-1)
        return self.next_net(ctx), self.leaf_net(ctx)[..., 0]

    def bbox(self, z: torch.Tensor) -> torch.Tensor:
        """The root bbox dims predicted from latents: (*, H) -> (*, 3)."""
        return self.bbdimNet(z)

    def teacher_forced(self, tree: VectorNode, z: torch.Tensor) -> list["NodeOutput"]:
        """Decode ``tree`` from latent ``z`` (H,) with every input and one-hot taken from the target.

        Nodes run breadth first (the order of :meth:`VectorNode.nodes`): the root from ``z``, each
        child from the ``next`` output at the step that predicts its Cuboid line.

        Returns:
            One :class:`NodeOutput` per node, breadth first.
        """
        outs: list[NodeOutput] = []
        queue = [(tree, z, 0)]
        while queue:
            node, latent, depth = queue.pop(0)
            h0 = latent.reshape(1, 1, -1)
            step = self(node.input_seq()[None], h0, h0, node.bbox_dims[None], depth, node.target_seq()[None])
            rows = node.cuboid_rows
            outs.append(NodeOutput(step.lines[0], step.leaf[0, rows]))
            for j, child in enumerate(node.children[: len(rows)]):
                if child is not None:
                    queue.append((child, step.next[0, rows[j]], depth + 1))
        return outs


@dataclass
class NodeOutput:
    """The teacher-forced predictions for one node of L lines and K Cuboid lines.

    Attributes:
        lines: (L+1, 63) float, predictions for ``[l1 .. lL, stop]``.
        leaf: (K,) float, the leaf logit of each Cuboid line, bbox first.
    """

    lines: torch.Tensor
    leaf: torch.Tensor


@dataclass
class VAEOutput:
    """What :meth:`VAE.forward` returns.

    Attributes:
        nodes: one :class:`NodeOutput` per node, breadth first.
        bbox_dims: (3,) float, the predicted root bbox dims.
        mu, logvar: (H,) float, the bottleneck's outputs.
        z: (H,) float, the latent decoded.
    """

    nodes: list[NodeOutput]
    bbox_dims: torch.Tensor
    mu: torch.Tensor
    logvar: torch.Tensor
    z: torch.Tensor


def reparameterize(mu: torch.Tensor, logvar: torch.Tensor, sample: bool,
                   generator: torch.Generator | None = None) -> torch.Tensor:
    """``mu + eps * exp(logvar / 2)`` with ``eps ~ N(0, 1)`` drawn by ``generator`` when ``sample``, else ``mu``."""
    if not sample:
        return mu
    eps = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=mu.device)
    return mu + eps * torch.exp(0.5 * logvar)


class VAE(nn.Module):
    """The encoder and decoder together.

    Args:
        hidden_dim: H, the code, latent and GRU size (256 in the reference).
        dropout: the decoder's input dropout in training (:class:`Decoder`; 0 in the reference).
    """

    def __init__(self, hidden_dim: int = 256, dropout: float = 0.0):
        super().__init__()
        self.encoder = Encoder(hidden_dim)
        self.decoder = Decoder(hidden_dim, dropout)

    def encode(self, tree: VectorNode, sample: bool = False,
               generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(z, mu, logvar)``, each (H,): ``z = mu + eps * exp(logvar / 2)`` when ``sample``, else ``mu``.

        ``generator`` (on the model's device) draws ``eps``.
        """
        mu, logvar = self.encoder(tree)
        return reparameterize(mu, logvar, sample, generator), mu, logvar

    def forward(self, tree: VectorNode, sample: bool = True, generator: torch.Generator | None = None) -> VAEOutput:
        """Encode ``tree`` and decode it teacher-forced: the training pass, scored by
        :func:`~shapeprog.vae.losses.program_loss`."""
        z, mu, logvar = self.encode(tree, sample, generator)
        return VAEOutput(self.decoder.teacher_forced(tree, z), self.decoder.bbox(z), mu, logvar, z)


def prediction_tree(output: VAEOutput, tree: VectorNode) -> VectorNode:
    """The teacher-forced predictions of ``output`` as a tree shaped like the target ``tree``.

    Node k's lines are its predicted rows ``[l1 .. lL, stop]``; a Cuboid line keeps the target's child
    when its leaf logit is negative (the prediction says "sub-program") and becomes a leaf otherwise.
    :func:`~shapeprog.vae.vectors.tree_to_program` writes the result as a program.
    """
    nodes = [n for n, _ in tree.nodes()]
    if len(nodes) != len(output.nodes):
        raise ValueError(f"the output has {len(output.nodes)} nodes, the tree {len(nodes)}")
    preds = {id(n): o for n, o in zip(nodes, output.nodes)}

    def build(node: VectorNode) -> VectorNode:
        out = preds[id(node)]
        leaf = out.leaf.tolist()
        kids = tuple(None if c is None or leaf[j] >= 0 else build(c) for j, c in enumerate(node.children[: len(leaf)]))
        return VectorNode(out.lines.detach(), kids, node.name)

    return build(tree)
