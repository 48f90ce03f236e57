"""The ShapeAssembly generative model: a hierarchical sequence VAE over programs.

:mod:`~shapeprog.vae.vectors` turns programs into trees of 63-dim line vectors and back,
:mod:`~shapeprog.vae.model` holds the encoder, the decoder and the VAE (plain PyTorch),
:mod:`~shapeprog.vae.losses` the reconstruction and KL losses, and :mod:`~shapeprog.vae.batch` the
teacher-forced pass over a batch of trees, level by level. :mod:`shapeprog.vae.train` (PyTorch Lightning;
not imported here) trains it. See ``docs/shapeassembly_vae.md``.
"""
from __future__ import annotations

from .batch import TreeBatch, batch_forward, batch_loss
from .losses import LOSS_WEIGHTS, program_loss
from .model import VAE, Decoder, Encoder
from .vectors import VectorNode, program_to_tree, tree_to_program

__all__ = ["LOSS_WEIGHTS", "VAE", "Decoder", "Encoder", "TreeBatch", "VectorNode", "batch_forward", "batch_loss",
           "program_loss", "program_to_tree", "tree_to_program"]
