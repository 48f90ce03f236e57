"""The ShapeAssembly generative model: a hierarchical sequence VAE over programs.

:mod:`~shapeprog.vae.vectors` turns programs into trees of 63-dim line vectors and back,
:mod:`~shapeprog.vae.model` holds the encoder, the decoder and the VAE (plain PyTorch),
:mod:`~shapeprog.vae.losses` the reconstruction and KL losses, :mod:`~shapeprog.vae.batch` the
teacher-forced pass over a batch of trees, level by level, :mod:`~shapeprog.vae.decode` the
validity-checked decoding with the model's entry points (:func:`sample`, :func:`encode`, :func:`decode`,
:func:`interpolate`), and :mod:`~shapeprog.vae.pretrained` weights files and the shipped models
(:func:`load_pretrained`). :mod:`shapeprog.vae.train` (PyTorch Lightning; not imported here) trains it on
the trees of :mod:`~shapeprog.vae.data` and scores reconstructions with :mod:`~shapeprog.vae.reconstruct`.
Generation evaluation (not imported here): :mod:`~shapeprog.vae.genmetrics` the metrics of generated
programs, :mod:`~shapeprog.vae.gentable` their table, :mod:`~shapeprog.vae.pointnet` the PointNet
classifier they use; :mod:`~shapeprog.vae.structure` program structure (:func:`structural_novelty`,
editability counts, the token :func:`edit_distance`) and :mod:`~shapeprog.vae.smoothness` interpolation
smoothness. See ``docs/shapeassembly_vae.md``.

Macro programs (ShapeMOD, Appendix C): :mod:`~shapeprog.vae.layout` computes a :class:`LineLayout` from a
macro library and turns hierarchical macro programs into trees and back, :mod:`~shapeprog.vae.macro_model`
holds the :class:`MacroVAE` sized by it, :func:`macro_program_loss` its masked typed losses, and
:mod:`~shapeprog.vae.macro_decode` its validity decoding (:func:`sample_macro`, :func:`encode_macro`,
:func:`decode_macro`). See ``docs/shapemod.md``.
"""
from __future__ import annotations

from .batch import TreeBatch, batch_forward, batch_loss
from .decode import Decoded, InvalidSample, decode, decode_latent, encode, interpolate, sample
from .layout import LineLayout, MacroNode, macro_program_to_tree, tree_to_macro_program
from .losses import LOSS_WEIGHTS, MACRO_LOSS_WEIGHTS, macro_program_loss, program_loss
from .macro_decode import MacroDecoded, decode_macro, encode_macro, sample_macro
from .macro_model import MacroVAE
from .model import VAE, Decoder, Encoder
from .pretrained import load_pretrained
from .structure import edit_distance, structural_novelty, structure_key
from .vectors import VectorNode, program_to_tree, tree_to_program

__all__ = ["LOSS_WEIGHTS", "VAE", "Decoded", "Decoder", "Encoder", "InvalidSample", "TreeBatch", "VectorNode",
           "batch_forward", "batch_loss", "decode", "decode_latent", "encode", "interpolate", "load_pretrained",
           "program_loss", "program_to_tree", "sample", "tree_to_program", "structural_novelty", "structure_key",
           "edit_distance",
           "LineLayout", "MACRO_LOSS_WEIGHTS", "MacroDecoded", "MacroNode", "MacroVAE", "decode_macro", "encode_macro",
           "macro_program_loss", "macro_program_to_tree", "sample_macro", "tree_to_macro_program"]
