"""Test helpers for csgnet: random programs (vocabulary programs and arbitrary-parameter programs) and
the reference's own computations written out independently of csgnet (the oracles of the renderer and
chamfer tests; the benchmarks time them as the per-program baselines)."""

from __future__ import annotations

import random

import numpy as np

from csgnet.lang import Draw, Op, Program
from csgnet.primitives import primitive, primitives
from csgnet.renderer.reference import render_np
from csgnet.vocab import vocabulary


def random_program(rng: random.Random, dim: int, n_prims: int, vocab_only: bool = False,
                   lo: int = -12, hi: int = 76, sizes: tuple[int, int] = (0, 64)) -> Program:
    """A valid random postfix program with ``n_prims`` primitives: vocabulary primitives, or any kind
    with positions in ``[lo, hi]`` and radii (heights) in ``sizes`` (both inclusive)."""
    kinds = [p.kind for p in primitives(dim)]
    vocab = vocabulary(dim)
    toks, depth, placed = [], 0, 0
    while placed < n_prims or depth > 1:
        if placed < n_prims and (depth < 2 or rng.random() < 0.5):
            if vocab_only:
                toks.append(vocab.decode([rng.randrange(vocab.num_primitives)]).tokens[0])
            else:
                k = rng.choice(kinds)
                n = len(primitive(k).params)
                n_pos = dim
                pos = [rng.randint(lo, hi) for _ in range(n_pos)]
                size = [rng.randint(*sizes) for _ in range(n - n_pos)]
                toks.append(Draw(k, tuple(pos + size)))
            depth += 1
            placed += 1
        else:
            toks.append(Op(rng.choice("+*-")))
            depth -= 1
    return Program(tuple(toks), dim)


def skimage_2d(kind: str, x: int, y: int, r: int) -> np.ndarray:
    """A 2D primitive drawn by the reference's scikit-image calls (``disk``; ``polygon`` plus
    ``polygon_perimeter``), with modern scikit-image names: (64, 64) bool, ``img[row=y, col=x]``."""
    from skimage import draw

    img = np.zeros((64, 64), bool)
    if kind == "c":
        rr, cc = draw.disk((y, x), r, shape=(64, 64))
        img[rr, cc] = True
        return img
    if kind == "s":
        L = r * 1.412
        rows = [int(y - L / 2.0), int(y - L / 2.0), int(y + L / 2.0), int(y + L / 2.0)]
        cols = [int(x - L / 2.0), int(x + L / 2.0), int(x + L / 2.0), int(x - L / 2.0)]
    else:
        L = 1.732 * r
        rows = [int(y + L / (2 * 1.732))] * 2 + [int(y - L / 1.732)]
        cols = [int(x - L / 2.0), int(x + L / 2.0), x]
    rr, cc = draw.polygon(rows, cols, shape=(64, 64))
    img[rr, cc] = True
    rr, cc = draw.polygon_perimeter(rows, cols, shape=(64, 64))
    img[rr, cc] = True
    return img


def reference_chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """The reference's per-pair chamfer distance (``train_utils.chamfer``): 0/255 images, 16 for an empty
    or full image or an empty Canny edge map, else the symmetric mean edge-to-edge distance."""
    import cv2

    img1 = a.astype(np.uint8) * 255
    img2 = b.astype(np.uint8) * 255
    full = 255 * img1.size
    for s in (int(img1.sum()), int(img2.sum())):
        if s == 0 or s == full:
            return 16.0
    e1, e2 = cv2.Canny(img1, 1, 3), cv2.Canny(img2, 1, 3)
    if e1.sum() == 0 or e2.sum() == 0:
        return 16.0
    d1 = cv2.distanceTransform(~e1, cv2.DIST_L2, 3).astype(np.float64)
    d2 = cv2.distanceTransform(~e2, cv2.DIST_L2, 3).astype(np.float64)
    E1, E2 = e1.astype(np.float64), e2.astype(np.float64)
    return float((np.sum(d1 * E2) / (np.sum(E2) + 1) + np.sum(d2 * E1) / (np.sum(E1) + 1)) / 2.0)


# --- the synthetic-data rules, checked independently on NumPy renders ------------------------------

def render_node(node) -> np.ndarray:
    """The NumPy render of a CSG tree node (a draw or a subtree)."""
    prog = Program((node,), node.dim) if isinstance(node, Draw) else Program.from_tree(node)
    return render_np(prog)


def rules_hold(program: Program, min_pixels: int, min_change: float = 0.1) -> bool:
    """Rule (b) ("operands" reading) at every node and rule (c), from NumPy renders of every subtree."""
    def ok(node) -> bool:
        if isinstance(node, Draw):
            return True
        if not (ok(node.left) and ok(node.right)):
            return False
        A, B = render_node(node.left), render_node(node.right)
        a, b, ab = int(A.sum()), int(B.sum()), int((A & B).sum())
        tau = min_change * (a + b)
        if node.op == "+":
            return a - ab >= tau and b - ab >= tau
        if node.op == "*":
            return a - ab >= tau and b - ab >= tau and ab >= tau
        return ab >= tau and a - ab >= tau

    return ok(program.tree()) and int(render_np(program).sum()) >= min_pixels
