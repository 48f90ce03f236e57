"""Checkpoints written atomically: an interrupted run never leaves a truncated checkpoint behind."""
from __future__ import annotations

import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO

from shapeio import atomic_write

__all__ = ["AtomicCheckpointIO"]


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning checkpoint IO that writes to a temporary file and renames it into place.

    Configs name it as a trainer plugin (``class_path: csgnet.train.checkpoint.AtomicCheckpointIO``).
    """

    def save_checkpoint(self, checkpoint, path, storage_options=None):
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} does not take storage_options")
        atomic_write(path, lambda f: torch.save(checkpoint, f), mkdir=True)
