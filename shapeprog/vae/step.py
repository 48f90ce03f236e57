"""The VAE's decoder run one step at a time for one sequence (``_Net``: NumPy on CPU, torch elsewhere),
the network that the validity-checked decoding loop of :mod:`shapeprog.vae.decode` talks to.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from .model import Decoder
from .vectors import LINE_DIM, NUM_SLOTS


# ----------------------------------------------------------------------------- the network, one step


class _Head:
    """A 3-layer MLP whose input is ``[x (main), extra]``: the extra part's first-layer contribution is
    added by the caller (one-hot rows, or a term fixed for the whole node)."""

    def __init__(self, mlp, main: int, conv, lrelu):
        W1 = conv(mlp.l1.weight.detach())  # views, no copies: BLAS reads the strided blocks as they are
        self.W1 = W1[:, :main]
        self.X = W1[:, main:].T  # (extra, out): row i = column main + i
        self.b1 = conv(mlp.l1.bias.detach())
        self.W2, self.b2 = conv(mlp.l2.weight.detach()), conv(mlp.l2.bias.detach())
        self.W3, self.b3 = conv(mlp.l3.weight.detach()), conv(mlp.l3.bias.detach())
        self.lrelu = lrelu

    def const(self, extra=None, rows: slice | None = None):
        """The first-layer bias plus the contribution of an extra input fixed for a node (at ``rows``
        of the extra part)."""
        if extra is None:
            return self.b1
        return self.b1 + extra @ (self.X if rows is None else self.X[rows])

    def __call__(self, x, pre, rows: Sequence[int] = ()):
        y = self.W1 @ x + pre
        for r in rows:
            y = y + self.X[r]
        y = self.lrelu(y)
        y = self.lrelu(self.W2 @ y + self.b2)
        return self.W3 @ y + self.b3


class _Net:
    """The decoder run one step at a time for one sequence (NumPy on CPU, torch elsewhere).

    The same arithmetic as :meth:`Decoder.forward` (tested), without the batch and time dimensions, and
    with each head run only when the line needs it. The decoding loop talks to the network through
    these methods only (:class:`~shapeprog.vae.replay.Replay` is a stand-in with the same methods).
    """

    def __init__(self, decoder: Decoder, backend: str | None = None):
        p = next(decoder.parameters())
        self.device, self.dtype = p.device, p.dtype
        self.numpy = p.device.type == "cpu" if backend is None else backend == "numpy"
        conv = (lambda t: t.numpy()) if self.numpy else (lambda t: t)
        if self.numpy:
            lrelu = lambda x: np.maximum(x, 0.2 * x)  # noqa: E731
            self.sigmoid = lambda x: 0.5 * (1.0 + np.tanh(0.5 * x))
            self.tanh = np.tanh
            np_dtype = p.detach().numpy().dtype
            self.vec = lambda v: np.asarray(v, dtype=np_dtype)
        else:
            lrelu = lambda x: torch.maximum(x, 0.2 * x)  # noqa: E731
            self.sigmoid, self.tanh = torch.sigmoid, torch.tanh
            self.vec = lambda v: torch.tensor(v, dtype=self.dtype, device=self.device)
        H = self.H = decoder.hidden_dim
        self.decoder = decoder
        self.inp_net = _Head(decoder.inp_net, LINE_DIM, conv, lrelu)
        g = decoder.gru
        self.Wih, self.Whh = conv(g.weight_ih_l0.detach()), conv(g.weight_hh_l0.detach())
        self.bih, self.bhh = conv(g.bias_ih_l0.detach()), conv(g.bias_hh_l0.detach())
        heads = ("cmd_net", "cube_net", "dim_net", "align_net", "att_net", "sym_net", "squeeze_net", "next_net",
                 "leaf_net")
        for name in heads:
            setattr(self, name, _Head(getattr(decoder, name), H, conv, lrelu))

    def latent(self, z: torch.Tensor):
        """A latent (H,) tensor as the GRU's state in this backend."""
        z = z.detach().to(device=self.device, dtype=self.dtype)
        return z.cpu().numpy() if self.numpy else z

    def root_bbox(self, z: torch.Tensor) -> list[float]:
        """``bbdimNet(z)``: the root's bbox dims."""
        return self.decoder.bbox(z.detach().to(device=self.device, dtype=self.dtype)).tolist()

    def begin(self, h_start, bbox_dims: Sequence[float], depth: int) -> dict:
        """A node's context: the first-layer terms fixed by its bbox dims, depth and start latent."""
        hier = [0.0, 0.0, 0.0]
        hier[min(int(depth), 2)] = 1.0
        bb = self.vec(list(bbox_dims))
        return {
            "inp": self.inp_net.const(self.vec(list(bbox_dims) + hier)),
            "dim": self.dim_net.const(bb), "align": self.align_net.const(bb),
            "sym": self.sym_net.const(bb, slice(NUM_SLOTS, NUM_SLOTS + 3)),
            "next": self.next_net.const(h_start), "leaf": self.leaf_net.const(h_start),
        }

    def step(self, line: Sequence[float], h, ctx: dict):
        """One GRU step on the input ``line`` (63 floats); returns the new state (= the GRU output)."""
        H = self.H
        x = self.inp_net(self.vec(line), ctx["inp"])
        gi = self.Wih @ x + self.bih
        gh = self.Whh @ h + self.bhh
        r = self.sigmoid(gi[:H] + gh[:H])
        u = self.sigmoid(gi[H:2 * H] + gh[H:2 * H])
        n = self.tanh(gi[2 * H:] + r * gh[2 * H:])
        return n + u * (h - n)

    def command(self, h, ctx) -> list[float]:
        """The 7 command logits."""
        return self.cmd_net(h, self.cmd_net.b1).tolist()

    def cubes(self, h, ctx, cmd: int) -> list[float]:
        """The 33 cube logits given the command."""
        return self.cube_net(h, self.cube_net.b1, (cmd,)).tolist()

    def cuboid(self, h, ctx) -> tuple[list[float], float]:
        """A Cuboid line's dims (3) and aligned logit."""
        return self.dim_net(h, ctx["dim"]).tolist(), float(self.align_net(h, ctx["align"])[0])

    def attach(self, h, ctx, a: int, b: int) -> list[float]:
        """The 6 attach coordinates given the two slots."""
        return self.att_net(h, self.att_net.b1, (a, NUM_SLOTS + b)).tolist()

    def sym(self, h, ctx, a: int) -> list[float]:
        """The 3 axis logits, the count and the distance of a reflect/translate line given its slot."""
        return self.sym_net(h, ctx["sym"], (a,)).tolist()

    def squeeze(self, h, ctx, a: int, b: int, c: int) -> list[float]:
        """The 6 face logits and (u, v) of a squeeze line given its slots."""
        return self.squeeze_net(h, self.squeeze_net.b1, (a, NUM_SLOTS + b, 2 * NUM_SLOTS + c)).tolist()

    def leaf(self, h, ctx) -> float:
        """The leaf logit (< 0: the cuboid gets a sub-program)."""
        return float(self.leaf_net(h, ctx["leaf"])[0])

    def child(self, h, ctx):
        """The latent of the sub-program started at this step."""
        return self.next_net(h, ctx["next"])
