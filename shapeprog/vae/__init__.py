"""The ShapeAssembly generative model: a hierarchical sequence VAE over programs.

:mod:`~shapeprog.vae.vectors` turns programs into trees of 63-dim line vectors and back,
:mod:`~shapeprog.vae.model` holds the encoder, the decoder and the VAE (plain PyTorch),
:mod:`~shapeprog.vae.losses` the reconstruction and KL losses, :mod:`~shapeprog.vae.decode` the
validity-checked decoding with the model's entry points (:func:`sample`, :func:`encode`, :func:`decode`,
:func:`interpolate`), and :mod:`~shapeprog.vae.pretrained` weights files and the shipped models
(:func:`load_pretrained`). See ``docs/shapeassembly_vae.md``.
"""
from __future__ import annotations

from .decode import Decoded, InvalidSample, decode, decode_latent, encode, interpolate, sample
from .losses import LOSS_WEIGHTS, program_loss
from .model import VAE, Decoder, Encoder
from .pretrained import load_pretrained
from .vectors import VectorNode, program_to_tree, tree_to_program

__all__ = ["LOSS_WEIGHTS", "VAE", "Decoded", "Decoder", "Encoder", "InvalidSample", "VectorNode", "decode",
           "decode_latent", "encode", "interpolate", "load_pretrained", "program_loss", "program_to_tree", "sample",
           "tree_to_program"]
