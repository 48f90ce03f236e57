"""The reward-shaping sweep (CSGNet's Table 1): REINFORCE runs that differ only in the exponent γ of the reward.

Each run starts from the same supervised weights, sees the same target batches (same seed) for the same number
of optimiser steps, and differs only in γ of ``R = (1 - CD / (64 sqrt 2)) ** γ``; the tuned models are then
scored with the Table 4 protocol (chamfer distance at k = 1 and best of k) on the same test images, beside the
supervised start. ``python -m csgnet table1`` runs it; ``python -m csgnet paper run csg-t1`` runs the listed
protocol.
"""
from __future__ import annotations

import copy
from typing import Callable, Sequence

import lightning as L
import numpy as np
import torch

from ..inference import load_model
from .reinforce import ReinforceModule, TargetDataModule

__all__ = ["reward_sweep", "one_epoch_trainer", "MAX_SWEEP_STEPS"]

#: Most optimiser steps of one run of the sweep.
MAX_SWEEP_STEPS = 100_000


def one_epoch_trainer(**kwargs) -> L.Trainer:
    """A quiet CPU trainer for one epoch of a study's run: no logger, checkpoints, progress bar or sanity check
    (``kwargs`` add to or override these settings)."""
    settings = dict(max_epochs=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                    enable_model_summary=False, num_sanity_val_steps=0, accelerator="cpu", devices=1)
    return L.Trainer(**{**settings, **kwargs})


def reward_sweep(init: str, gammas: Sequence[float], steps: int, train_images: np.ndarray, batch_size: int = 64,
                 lr: float = 0.01, seed: int = 0, accumulate: int = 1, progress: Callable[[str], None] | None = None
                 ) -> list[tuple[str, torch.nn.Module]]:
    """REINFORCE-tune the weights ``init`` for ``steps`` batches (one SGD update per ``accumulate`` batches)
    once per ``gammas`` value.

    Returns ``(label, model)`` pairs: the supervised start first, then one tuned model per γ (in eval mode).
    ``train_images`` are the ``(N, 64, 64)`` bool targets; every run draws the same batches (``seed``).
    """
    if not gammas:
        raise ValueError("the sweep needs at least one gamma")
    if not 1 <= int(steps) <= MAX_SWEEP_STEPS:
        raise ValueError(f"steps must lie in 1..{MAX_SWEEP_STEPS}, got {steps}")
    for g in gammas:
        if not (np.isfinite(g) and g > 0):
            raise ValueError(f"gamma must be a positive number, got {g}")
    say = progress or (lambda s: None)
    start = load_model(init)
    out = [("supervised start (no REINFORCE)", start)]
    for g in gammas:
        L.seed_everything(seed, workers=True, verbose=False)
        module = ReinforceModule(init=str(init), gamma=float(g), lr=lr, log_images=0, seed=seed)
        data = TargetDataModule.from_arrays(train_images, train_images[:batch_size], batch_size=batch_size,
                                            steps_per_epoch=int(steps), seed=seed)
        trainer = one_epoch_trainer(limit_val_batches=0, accumulate_grad_batches=int(accumulate),
                                    gradient_clip_val=10.0, gradient_clip_algorithm="norm")
        trainer.fit(module, datamodule=data)
        model = copy.deepcopy(module.model).eval()
        say(f"gamma {g:g}: {steps} batches done")
        out.append((f"REINFORCE, gamma = {g:g}", model))
    return out
