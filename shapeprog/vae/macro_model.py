"""The hierarchical sequence VAE over macro programs (ShapeMOD, Appendix C), sized by a :class:`LineLayout`.

The same architecture as :mod:`shapeprog.vae.model` (a GRU encoder bottom-up over the blocks, a GRU decoder
one step per line, breadth first over the blocks), with the line vector and the heads following the
library (:class:`~shapeprog.vae.layout.LineLayout`):

* the command head predicts ``start``, ``stop`` and the |L| functions;
* one typed head per parameter group, each conditioned on the command one-hot (the target's when teacher
  forcing, the argmax otherwise): cuboid ids, floats (also given the cuboid one-hots and the block's bbox
  dims), faces and axes (given the cuboid one-hots), booleans; the losses compare only the slots the
  command's function uses (:meth:`LineLayout.used`);
* the child heads (``next_net`` the child latent, ``leaf_net`` the leaf logit) run once per *created
  cuboid* of a line, given its position among the line's created cuboids; in the encoder a child's code is
  added to the embedding of the line that creates its cuboid, through ``kid_net`` with the same position.

The shipped base-language models keep :class:`shapeprog.vae.model.VAE` and its fixed 63-wide statement
layout (both cuboids of an attach named); a macro model is a :class:`MacroVAE` and its weights file holds
the library's text (:mod:`shapeprog.vae.pretrained`).

Example:
    >>> from shapeprog.macros import Library
    >>> from shapeprog.macros.hierarchy import parse
    >>> from shapeprog.vae.layout import LineLayout, macro_program_to_tree
    >>> layout = LineLayout(Library())
    >>> tree = macro_program_to_tree(parse("# Program_0\\nbbox = Cuboid(1.0, 1.0, 1.0, True)\\n"
    ...     "c = Cuboid(0.5, 0.25, 0.5, True)\\nattach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n\\n"), layout)
    >>> out = MacroVAE(layout, hidden_dim=32)(tree, sample=False)
    >>> tuple(out.nodes[0].lines.shape), tuple(out.nodes[0].leaf.shape)
    ((4, 45), (2,))
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..macros.lang import AXIS, BOOL, CUBE, FACE, FLOAT, TYPES
from .layout import GROUPS, LineLayout, MacroNode
from .model import MLP, NodeOutput, Sampler, VAEOutput, check_dropout, one_hot_argmax, reparameterize

__all__ = ["MacroDecoder", "MacroEncoder", "MacroVAE"]


def _position(k: torch.Tensor, n: int, like: torch.Tensor) -> torch.Tensor:
    return F.one_hot(k, n).to(like.dtype)


class MacroEncoder(nn.Module):
    """A macro-program tree -> a code, bottom-up (the twin of :class:`shapeprog.vae.model.Encoder`).

    Args:
        layout: the line layout.
        hidden_dim: H.
    """

    def __init__(self, layout: LineLayout, hidden_dim: int = 256):
        super().__init__()
        self.layout, self.hidden_dim = layout, hidden_dim
        self.gru = nn.GRU(hidden_dim, hidden_dim, batch_first=True)
        self.inp_net = MLP(layout.width, hidden_dim, hidden_dim, hidden_dim)
        self.kid_net = nn.Linear(hidden_dim + layout.max_created, hidden_dim)
        self.sampler = Sampler(hidden_dim)
        self.h_start = nn.Parameter(torch.randn(1, 1, hidden_dim))

    def encode_node(self, node: MacroNode) -> torch.Tensor:
        """The code of ``node`` and its sub-tree: (H,) float."""
        lay, x = self.layout, node.lines
        seq = torch.cat([lay.command_vector("start", x.dtype, x.device)[None], x,
                         lay.command_vector("stop", x.dtype, x.device)[None]])
        emb = self.inp_net(seq)
        creators = node.creators(lay)
        kids = [(creators[j], c) for j, c in enumerate(node.children[: len(creators)]) if c is not None]
        if kids:
            rows = torch.tensor([r + 1 for (r, _), _ in kids], device=x.device)
            pos = torch.tensor([k for (_, k), _ in kids], device=x.device)
            codes = torch.stack([self.encode_node(c) for _, c in kids])
            add = self.kid_net(torch.cat([codes, _position(pos, lay.max_created, codes)], dim=-1))
            emb = emb.index_add(0, rows, add)
        _, h = self.gru(emb[None], self.h_start)
        return h[0, 0]

    def forward(self, tree: MacroNode) -> tuple[torch.Tensor, torch.Tensor]:
        """``(mu (H,), logvar (H,))`` of the root's code through the bottleneck."""
        return self.sampler(self.encode_node(tree))


class MacroDecoder(nn.Module):
    """A latent -> macro line vectors, one GRU step per line, a typed head per parameter group.

    Args:
        layout: the line layout.
        hidden_dim: H.
        dropout: dropout on the GRU's input embeddings in training (as the base decoder's; 0: none).
    """

    def __init__(self, layout: LineLayout, hidden_dim: int = 256, dropout: float = 0.0):
        super().__init__()
        h, lay = hidden_dim, layout
        self.layout, self.hidden_dim = layout, h
        self.input_dropout = nn.Dropout(check_dropout(dropout))
        n_cmd, n_cube = len(lay.commands), lay.counts[CUBE] * GROUPS[CUBE]
        self.bbdimNet = MLP(h, h, h, 3)  # noqa: N815 - the base decoder's name
        self.gru = nn.GRU(h, h, batch_first=True)
        self.inp_net = MLP(lay.width + 3 + 3, h, h, h)
        self.cmd_net = MLP(h, h // 2, h // 4, n_cmd)
        inputs = {CUBE: h + n_cmd, FLOAT: h + n_cmd + n_cube + 3, FACE: h + n_cmd + n_cube, AXIS: h + n_cmd + n_cube,
                  BOOL: h + n_cmd}
        self.type_nets = nn.ModuleDict({f"{t}_net": MLP(inputs[t], h, h // 2, lay.counts[t] * GROUPS[t])
                                        for t in TYPES if lay.counts[t]})
        self.next_net = MLP(2 * h + lay.max_created, h, h, h)
        self.leaf_net = MLP(2 * h + lay.max_created, h // 2, h // 8, 1)

    def embed(self, inp: torch.Tensor, bbox_dims: torch.Tensor, depth: int) -> torch.Tensor:
        """The GRU's input: ``inp_net`` of the line (*, width), the bbox dims (*, 3) and the depth one-hot."""
        hier = inp.new_zeros(*inp.shape[:-1], 3)
        hier[..., min(int(depth), 2)] = 1.0
        return self.input_dropout(self.inp_net(torch.cat([inp, bbox_dims, hier], dim=-1)))

    def heads(self, out: torch.Tensor, bbox_dims: torch.Tensor, teacher: torch.Tensor | None = None) -> torch.Tensor:
        """The line vectors (*, width) predicted from GRU outputs (*, H); ``teacher`` (*, width) gives the
        command and cuboid one-hots the heads are conditioned on (None: the argmax of the predictions)."""
        lay = self.layout
        cmd = self.cmd_net(out)
        cmd_oh = teacher[..., lay.slices["cmd"]] if teacher is not None else one_hot_argmax(cmd)
        parts = {}
        if lay.counts[CUBE]:
            parts[CUBE] = self.type_nets["cube_net"](torch.cat([out, cmd_oh], dim=-1))
            cube_oh = (teacher[..., lay.slices[CUBE]] if teacher is not None
                       else one_hot_argmax(parts[CUBE], lay.counts[CUBE]))
        else:
            cube_oh = out.new_zeros(*out.shape[:-1], 0)
        for t in (FLOAT, FACE, AXIS, BOOL):
            if not lay.counts[t]:
                continue
            extra = [out, cmd_oh] + ([cube_oh] if t != BOOL else []) + ([bbox_dims] if t == FLOAT else [])
            parts[t] = self.type_nets[f"{t}_net"](torch.cat(extra, dim=-1))
        return torch.cat([cmd] + [parts.get(t, out.new_zeros(*out.shape[:-1], 0)) for t in TYPES], dim=-1)

    def child_heads(self, out: torch.Tensor, h_start: torch.Tensor, position: torch.Tensor):
        """Child latents (*, H) and leaf logits (*,) of created cuboids: GRU outputs ``out`` (*, H) of their
        lines, the node's start latent ``h_start`` (*, H), their ``position`` (*,) int64 among the line's."""
        ctx = torch.cat([out, h_start, _position(position, self.layout.max_created, out)], dim=-1)
        return self.next_net(ctx), self.leaf_net(ctx)[..., 0]

    def bbox(self, z: torch.Tensor) -> torch.Tensor:
        """The root bbox dims predicted from latents: (*, H) -> (*, 3)."""
        return self.bbdimNet(z)

    def run(self, inp: torch.Tensor, h: torch.Tensor, bbox_dims: torch.Tensor, depth: int):
        """GRU over ``inp`` (T, width) from state ``h`` (1, 1, H): ``(out (T, H), h (1, 1, H))``."""
        bb = bbox_dims[None].expand(inp.shape[0], 3)
        out, h = self.gru(self.embed(inp, bb, depth)[None], h)
        return out[0], h

    def teacher_forced(self, tree: MacroNode, z: torch.Tensor) -> list[NodeOutput]:
        """Decode ``tree`` from ``z`` (H,) with every input and one-hot taken from the target, breadth first
        (the order of :meth:`MacroNode.nodes`); each child from the ``next`` output of its created cuboid.

        Returns:
            One :class:`~shapeprog.vae.model.NodeOutput` per node: ``lines`` (L+1, width) and ``leaf`` (K,),
            one logit per created cuboid, bbox first.
        """
        lay = self.layout
        outs: list[NodeOutput] = []
        queue = [(tree, z, 0)]
        while queue:
            node, latent, depth = queue.pop(0)
            h0 = latent.reshape(1, 1, -1)
            out, _ = self.run(node.input_seq(lay), h0, node.bbox_dims, depth)
            lines = self.heads(out, node.bbox_dims[None].expand(out.shape[0], 3), node.target_seq(lay))
            creators = node.creators(lay)
            rows = torch.tensor([r for r, _ in creators], device=out.device)
            pos = torch.tensor([k for _, k in creators], device=out.device)
            nxt, leaf = self.child_heads(out[rows], latent[None].expand(len(creators), -1), pos)
            outs.append(NodeOutput(lines, leaf))
            for j, child in enumerate(node.children[: len(creators)]):
                if child is not None:
                    queue.append((child, nxt[j], depth + 1))
        return outs


class MacroVAE(nn.Module):
    """The encoder and decoder of macro programs together (the twin of :class:`shapeprog.vae.model.VAE`).

    Args:
        layout: the library's :class:`~shapeprog.vae.layout.LineLayout`.
        hidden_dim: H.
        dropout: the decoder's input dropout in training (:class:`MacroDecoder`).
    """

    def __init__(self, layout: LineLayout, hidden_dim: int = 256, dropout: float = 0.0):
        super().__init__()
        self.layout = layout
        self.encoder = MacroEncoder(layout, hidden_dim)
        self.decoder = MacroDecoder(layout, hidden_dim, dropout)

    @property
    def library(self):
        return self.layout.library

    def encode(self, tree: MacroNode, sample: bool = False, generator: torch.Generator | None = None):
        """``(z, mu, logvar)``, each (H,): ``z = mu + eps * exp(logvar / 2)`` when ``sample``, else ``mu``."""
        mu, logvar = self.encoder(tree)
        return reparameterize(mu, logvar, sample, generator), mu, logvar

    def forward(self, tree: MacroNode, sample: bool = True, generator: torch.Generator | None = None) -> VAEOutput:
        """Encode ``tree`` and decode it teacher-forced (scored by :func:`~shapeprog.vae.losses.macro_program_loss`)."""
        z, mu, logvar = self.encode(tree, sample, generator)
        return VAEOutput(self.decoder.teacher_forced(tree, z), self.decoder.bbox(z), mu, logvar, z)
