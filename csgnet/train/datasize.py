"""The data-size study (CSGNet's Figures 6 and 9): the same supervised run on growing shares of a training set.

Every run trains the same model preset from the same seed for the same number of batches; only the share of
each length's training programs it may draw from changes. The models are then scored on the same test
programs (:func:`csgnet.paper.tables.evaluate_model`). ``python -m csgnet datasize`` runs it.
"""
from __future__ import annotations

from typing import Callable, Sequence

import lightning as L

from .supervised import CSGDataModule, CSGNetModule
from .sweep import one_epoch_trainer

__all__ = ["data_size_runs", "MAX_DATASIZE_STEPS"]

#: Most training batches of one run of the study.
MAX_DATASIZE_STEPS = 100_000


def data_size_runs(data_dir: str, fractions: Sequence[float], steps: int, dim: int = 2, stack: bool = False,
                   size: str = "small", batch_size: int = 100, lr: float = 1e-3, seed: int = 0,
                   progress: Callable[[str], None] | None = None) -> list[tuple[float, int, object]]:
    """Train one model per share of the training set; returns ``(fraction, programs seen, model)`` per run."""
    if not fractions:
        raise ValueError("the study needs at least one training fraction")
    if not 1 <= int(steps) <= MAX_DATASIZE_STEPS:
        raise ValueError(f"steps must lie in 1..{MAX_DATASIZE_STEPS}, got {steps}")
    say = progress or (lambda s: None)
    out = []
    for f in fractions:
        L.seed_everything(seed, workers=True, verbose=False)
        module = CSGNetModule(dim=dim, stack=stack, size=size, lr=lr, log_images=0, seed=seed)
        data = CSGDataModule(dim=dim, data_dir=data_dir, batch_size=batch_size, steps_per_epoch=int(steps),
                             val_per_length=2, seed=seed, train_fraction=float(f))
        trainer = one_epoch_trainer(limit_val_batches=1)  # one small validation batch: the lr schedule reads it
        trainer.fit(module, datamodule=data)
        n = sum(t.shape[0] for t in data.train_tables.values())
        say(f"fraction {f:g}: {n} training programs, {steps} batches done")
        out.append((float(f), n, module.model.eval()))
    return out
