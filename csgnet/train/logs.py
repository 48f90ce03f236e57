"""What the training modules log: validation values averaged over ranks, and image grids of targets beside
the model's programs for TensorBoard."""
from __future__ import annotations

from collections.abc import Iterable

import lightning as L
import numpy as np
import torch

__all__ = ["EpochValues", "log_means", "log_pairs", "image_grid", "image_logger"]


class EpochValues:
    """Per-item values of one validation epoch, gathered batch by batch, and the first image pairs of the
    epoch for a grid (:func:`log_pairs`).

    Args:
        images: how many (target, prediction) pairs to keep (0: none).
    """

    def __init__(self, images: int = 0):
        self.images = int(images)
        self.values: dict[str, list[np.ndarray]] = {}
        self.grid: tuple[torch.Tensor, torch.Tensor] | None = None

    def add(self, targets: torch.Tensor, preds: torch.Tensor, **values) -> None:
        """Gather one batch.

        Args:
            targets: ``(B, H, W)`` or ``(B, D, H, W)`` bool, kept for the grid while it is not full.
            preds: the renders of the model's programs, shaped like ``targets``.
            **values: ``(B,)`` per-item values (or a scalar per batch), by name.
        """
        for name, value in values.items():
            self.values.setdefault(name, []).append(np.atleast_1d(np.asarray(value)))
        if self.grid is None and self.images:
            self.grid = (targets[: self.images].cpu(), preds[: self.images].cpu())

    def __bool__(self) -> bool:
        return bool(self.values)

    def arrays(self) -> dict[str, np.ndarray]:
        """Each value's batches concatenated: ``{name: (N,) array}``."""
        return {name: np.concatenate(parts) for name, parts in self.values.items()}


def log_means(module: L.LightningModule, means: dict[str, float], prog_bar: Iterable[str] = ()) -> None:
    """Log each of ``means`` with ``sync_dist``: under DDP each rank validates a shard of the set and the
    logged value is the mean of the ranks' means, so every rank's checkpoint callback and plateau
    scheduler see the same number."""
    prog_bar = set(prog_bar)
    for name, value in means.items():
        module.log(name, float(value), prog_bar=name in prog_bar, sync_dist=True)


def log_pairs(module: L.LightningModule, tag: str, targets: torch.Tensor, preds: torch.Tensor) -> bool:
    """Add an :func:`image_grid` of ``targets`` beside ``preds`` (``(N, H, W)``, or ``(N, D, H, W)`` shown
    as silhouettes along the last axis) to the module's TensorBoard at its global step.

    Returns:
        Whether the logger took the image (False without an image logger).
    """
    exp = image_logger(module)
    if exp is None:
        return False
    if targets.dim() == 4:  # 3D: silhouettes along z
        targets, preds = targets.any(-1), preds.any(-1)
    exp.add_image(tag, image_grid(targets, preds), module.global_step)
    return True


def image_grid(targets: torch.Tensor, preds: torch.Tensor, cols: int = 4) -> torch.Tensor:
    """Pairs target | prediction (black shapes on white), ``cols`` pairs per row.

    Args:
        targets: ``(N, H, W)`` bool.
        preds: ``(N, H, W)`` bool.
        cols: pairs per row.

    Returns:
        ``(1, H', W')`` float32 image in ``[0, 1]``.
    """
    targets, preds = targets.bool().cpu(), preds.bool().cpu()
    gap = torch.ones(targets.shape[1], 2, dtype=torch.bool)
    pairs = [torch.cat([a, gap, b], 1) for a, b in zip(targets, preds)]
    rows = [torch.cat([p, torch.ones(2, p.shape[1], dtype=torch.bool)], 0) for p in pairs]
    rows += [torch.ones_like(rows[0])] * (-len(rows) % cols)
    grid = torch.cat([torch.cat(rows[i:i + cols], 1) for i in range(0, len(rows), cols)], 0)
    return (~grid).float()[None]


def image_logger(module: L.LightningModule):
    """The module's logger experiment if it takes images (TensorBoard), else None."""
    exp = getattr(module.logger, "experiment", None) if module.logger is not None else None
    return exp if hasattr(exp, "add_image") else None
