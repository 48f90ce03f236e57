"""The ShapeAssembly generative model: a hierarchical sequence VAE over programs.

:mod:`~shapeprog.vae.vectors` turns programs into trees of 63-dim line vectors and back,
:mod:`~shapeprog.vae.model` holds the encoder, the decoder and the VAE (plain PyTorch),
:mod:`~shapeprog.vae.losses` the reconstruction and KL losses, and
:mod:`~shapeprog.vae.pretrained` weights files and the shipped models. See ``docs/shapeassembly_vae.md``.
"""
from __future__ import annotations

from .losses import LOSS_WEIGHTS, program_loss
from .model import VAE, Decoder, Encoder
from .pretrained import load_pretrained
from .vectors import VectorNode, program_to_tree, tree_to_program

__all__ = ["LOSS_WEIGHTS", "VAE", "Decoder", "Encoder", "VectorNode", "load_pretrained", "program_loss", "program_to_tree",
           "tree_to_program"]
