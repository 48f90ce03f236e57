"""What the training modules show in TensorBoard: image grids of targets beside the model's programs."""
from __future__ import annotations

import lightning as L
import torch

__all__ = ["image_grid", "image_logger"]


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
