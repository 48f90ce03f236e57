"""Reconstruction by the VAE: the programs decoded from the mean codes of trees (:func:`reconstruct`),
the target surfaces of the original programs (:func:`target_surfaces`) and the F-score between them
(:func:`reconstruction_fscores`), as logged by :class:`shapeprog.vae.train.VAEModule`.
"""
from __future__ import annotations

import torch

from ..execute import execute
from ..macros.execute import compile_hierarchy
from ..metrics import fscore
from ..sampling import sample_surface
from .batch import TreeBatch, encode_batch
from .decode import decode_latent
from .layout import LineLayout, tree_to_macro_program
from .macro_decode import decode_macro
from .macro_model import MacroVAE
from .model import VAE
from .vectors import VectorNode, tree_to_program

__all__ = [
    "reconstruct",
    "reconstruction_fscores",
    "target_surfaces",
    "tree_program",
]


# ------------------------------------------------------------------------------------------ reconstruction


def tree_program(tree, layout: LineLayout | None = None):
    """The ShapeAssembly program a tree stands for: :func:`~shapeprog.vae.vectors.tree_to_program` of a
    :class:`VectorNode`; the expansion (:func:`shapeprog.macros.execute.compile_hierarchy`) of the macro
    program of a :class:`~shapeprog.vae.layout.MacroNode` (``layout`` needed)."""
    if isinstance(tree, VectorNode):
        return tree_to_program(tree)
    return compile_hierarchy(tree_to_macro_program(tree, layout), layout.library).program


def reconstruct(vae: VAE, trees: list[VectorNode]) -> list:
    """The programs decoded from the mean codes of ``trees``: ``decode_latent(vae.decoder, mu, reject=False)``
    (:mod:`shapeprog.vae.decode`) of each tree's mu, None where decoding raises a ``ValueError``. For a
    :class:`~shapeprog.vae.macro_model.MacroVAE` and macro trees: the expanded ShapeAssembly program of each
    decoded macro program (:func:`~shapeprog.vae.macro_decode.decode_macro`)."""
    device, dtype = next(vae.parameters()).device, next(vae.parameters()).dtype
    if isinstance(vae, MacroVAE):
        out = []
        with torch.no_grad():
            for t in trees:
                try:
                    out.append(decode_macro(vae, vae.encode(t.to(device, dtype))[1]).program)
                except ValueError:
                    out.append(None)
        return out
    with torch.no_grad():
        batch = TreeBatch([t.to("cpu") for t in trees]).to(device, dtype)
        mu, _ = vae.encoder.sampler(encode_batch(vae.encoder, batch))
        out = []
        for z in mu:
            try:
                out.append(decode_latent(vae.decoder, z, reject=False).program)
            except ValueError:
                out.append(None)
    return out


def target_surfaces(trees: list[VectorNode], points: int = 10_000, seed: int = 0,
                    layout: LineLayout | None = None) -> list[torch.Tensor]:
    """``points`` surface samples ``(points, 3)`` of each tree's executed program (:func:`tree_program`;
    ``layout`` for macro trees): the targets of :func:`reconstruction_fscores`, drawn once for a fixed set of
    shapes."""
    gen = torch.Generator().manual_seed(int(seed))
    return [sample_surface(execute(tree_program(t, layout)).corners, points, gen)[0] for t in trees]


def reconstruction_fscores(trees: list[VectorNode], programs: list, points: int = 10_000, seed: int = 0,
                           targets: list[torch.Tensor] | None = None,
                           layout: LineLayout | None = None) -> list[float | None]:
    """The F-score (0-100, :func:`shapeprog.metrics.fscore`) of each tree's shape against a program's.

    ``points`` surface samples of each executed shape are compared (10,000 in the paper); the target
    program is :func:`~shapeprog.vae.vectors.tree_to_program` of the tree.

    Args:
        trees: the targets.
        programs: one program (or None) per tree, e.g. :func:`reconstruct` of the trees.
        points: surface samples per shape.
        seed: the samples' draw.
        targets: :func:`target_surfaces` of ``trees`` with the same ``points`` and ``seed``, when already
            drawn (the same scores, without executing and sampling the targets again).

    Returns:
        One F-score per tree, None where the program is None or cannot be executed or sampled (no leaf
        cuboid, a non-finite corner).
    """
    if targets is None:
        targets = target_surfaces(trees, points, seed, layout)
    gen = torch.Generator().manual_seed(int(seed) + 1)
    out: list[float | None] = []
    for target, program in zip(targets, programs):
        try:
            if program is None:
                raise ValueError("no program")
            pred, _ = sample_surface(execute(program).corners, points, gen)
        except ValueError:  # ExecutionError, no leaf cuboid, degenerate surface
            out.append(None)
            continue
        out.append(fscore(pred, target))
    return out


def _same_trees(a: list[VectorNode], b: list[VectorNode]) -> bool:
    """Whether two lists hold the same trees (equal line vectors and structure)."""
    def same(x, y) -> bool:
        if x is None or y is None:
            return x is y
        return (len(x.children) == len(y.children) and torch.equal(x.lines.cpu(), y.lines.cpu())
                and all(same(c, d) for c, d in zip(x.children, y.children)))
    return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))


def _corners(program) -> torch.Tensor:
    """A program's leaf cuboids ``(L, 8, 3)``; none (a white picture) when there is no program or it cannot be
    executed."""
    try:
        return torch.zeros(0, 8, 3) if program is None else execute(program).corners
    except ValueError:
        return torch.zeros(0, 8, 3)
