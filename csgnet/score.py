"""Rendering and scoring decoded programs against their targets: the one decode -> render -> score path
of inference, evaluation and the paper's tables (IoU and chamfer as spec section (h) defines them:
2D IoU ``|A∧B| / |A∨B|`` and the edge chamfer in pixels; 3D IoU ``|A∧B| / (|A∨B| + 1)``)."""

from __future__ import annotations

from typing import Iterable

import numpy as np
import torch

from . import metrics
from .decode import Decoded
from .renderer import render_tokens

__all__ = ["score_renders", "score_beams", "best_iou_matches"]


def score_renders(pred: torch.Tensor, target: torch.Tensor, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """IoU and chamfer of rendered pairs ``(N, 64, 64[, 64])``: 2D IoU ``|A∧B| / |A∨B|`` (NaN, both empty,
    read as 0) and the edge chamfer in pixels; 3D IoU ``/ (|A∨B| + 1)`` and chamfer NaN."""
    pred, target = pred.cpu(), target.cpu()
    if dim == 2:
        iou = np.asarray(metrics.iou(pred, target, denominator="union"), dtype=np.float64)
        cd = np.asarray(metrics.chamfer(pred, target), dtype=np.float64)
    else:
        iou = np.asarray(metrics.iou_3d(pred, target), dtype=np.float64)
        cd = np.full(len(iou), np.nan)
    return np.nan_to_num(iou, nan=0.0), cd


def score_beams(decoded: Decoded, targets: torch.Tensor) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    """Render every hypothesis of ``decoded`` and score it against its target.

    Returns:
        ``(renders (N * k, ...) bool, iou (N, k), chamfer (N, k))``.
    """
    n, k = decoded.tokens.shape[:2]
    pred = render_tokens(decoded.flat_tokens(), decoded.dim, decoded.lengths.flatten())
    iou, cd = score_renders(pred, targets.repeat_interleave(k, 0), decoded.dim)
    return pred, iou.reshape(n, k), cd.reshape(n, k)


def best_iou_matches(queries: torch.Tensor, chunks: Iterable[tuple[int, torch.Tensor]], plus: float = 0.0
                     ) -> torch.Tensor:
    """For each query, the index of the candidate with the highest IoU ``|A∧B| / (|A∨B| + plus)``.

    Args:
        queries: ``(N, ...)`` bool images or volumes.
        chunks: ``(offset, candidates (M, ...) bool)`` blocks of the candidate set, in index order (one
            matrix product per block, so the candidates never need to be in memory at once).
        plus: 0 for the 2D IoU, 1 for the 3D one.

    Returns:
        ``(N,)`` int64 candidate indices (ties: the lowest index).
    """
    q = queries.reshape(len(queries), -1).float()
    area = q.sum(1)
    best = torch.full((len(q),), -1.0)
    best_idx = torch.zeros(len(q), dtype=torch.long)
    for lo, cand in chunks:
        c = cand.reshape(len(cand), -1).float()
        inter = q @ c.T
        union = area[:, None] + c.sum(1)[None] - inter + plus
        iou = torch.where(union > 0, inter / union.clamp(min=1e-9), torch.zeros_like(inter))
        val, idx = iou.max(1)
        better = val > best
        best = torch.where(better, val, best)
        best_idx = torch.where(better, idx + lo, best_idx)
    return best_idx
