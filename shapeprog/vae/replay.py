"""A stand-in for the decoder network that replays a program, for checking the validity rules on real programs.

``bench/bench_vae_sampling.py --replay N`` and the tests decode corpus programs through it: a program that
the rules of :mod:`shapeprog.vae.validity` leave unchanged comes back byte for byte.
"""
from __future__ import annotations

from .validity import STOP
from .vectors import ALIGNED, ATTACH, AXIS, COUNT, CUBE1, CUBE3, DIMS, DIST, FACE, LINE_DIM, UV

__all__ = ["Replay"]


class Replay:
    """A stand-in for the network that replays a line-vector tree (:func:`~shapeprog.vae.vectors.program_to_tree`): every
    step predicts the tree's next line (one-hot logits scaled by 10, the line's own numbers), so that
    decoding shows what the validity rules make of a given program. ``z`` is the tree itself.

    It has the methods the decoding loop calls on the network (``step._Net``): pass it where the loop
    takes a network, e.g. ``decode._decode_with(Replay(), program_to_tree(program), False, DecodeOptions())``.
    """

    def latent(self, tree):
        return (tree, -1)

    def root_bbox(self, tree) -> list[float]:
        return tree.bbox_dims.tolist()

    def begin(self, h_start, bbox_dims, depth) -> dict:
        node = h_start[0]
        kids = dict(zip(node.cuboid_rows.tolist(), node.children))
        return {"rows": node.lines.tolist(), "kids": kids}

    def step(self, line, h, ctx):
        return (h[0], h[1] + 1)

    def _row(self, h, ctx) -> list[float]:
        rows = ctx["rows"]
        if h[1] < len(rows):
            return rows[h[1]]
        stop = [0.0] * LINE_DIM
        stop[STOP] = 1.0
        return stop

    def command(self, h, ctx):
        return [10.0 * x for x in self._row(h, ctx)[0:7]]

    def cubes(self, h, ctx, cmd):
        return [10.0 * x for x in self._row(h, ctx)[CUBE1.start:CUBE3.stop]]

    def cuboid(self, h, ctx):
        r = self._row(h, ctx)
        return r[DIMS], 10.0 if r[ALIGNED] > 0 else -10.0

    def attach(self, h, ctx, a, b):
        return self._row(h, ctx)[ATTACH]

    def sym(self, h, ctx, a):
        r = self._row(h, ctx)
        return [10.0 * x for x in r[AXIS]] + [r[COUNT], r[DIST]]

    def squeeze(self, h, ctx, a, b, c):
        r = self._row(h, ctx)
        return [10.0 * x for x in r[FACE]] + r[UV]

    def leaf(self, h, ctx):
        return -10.0 if ctx["kids"].get(h[1]) is not None else 10.0

    def child(self, h, ctx):
        return (ctx["kids"][h[1]], -1)
