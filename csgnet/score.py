"""Rendering and scoring decoded programs against their targets: the one decode -> render -> score path
of inference, evaluation and the paper's tables (IoU and chamfer as spec section (h) defines them:
2D IoU ``|A∧B| / |A∨B|`` and the edge chamfer in pixels; 3D IoU ``|A∧B| / (|A∨B| + 1)``)."""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np
import torch

from . import metrics
from .decode import Decoded
from .lang import Program, parse
from .primitives import SIZE
from .renderer import render_programs, render_tokens

__all__ = ["score_renders", "score_beams", "best_iou_matches", "program_scores"]


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


def _check_target(target) -> np.ndarray:
    """A (64, 64) image or (64, 64, 64) volume, NumPy or torch -> bool of the same shape, not empty."""
    if type(target).__module__.startswith("torch"):
        target = target.detach().cpu().numpy()
    t = np.asarray(target)
    if t.shape not in ((SIZE,) * 2, (SIZE,) * 3):
        raise ValueError(f"target must be one ({SIZE}, {SIZE}, {SIZE}) volume or one image of shape "
                         f"({SIZE}, {SIZE}), got {t.shape}")
    t = t != 0
    if not t.any():
        what = "image" if t.ndim == 2 else "volume"
        raise ValueError(f"target {what} is empty (all False): there is nothing to refine against")
    return t


def _check_program(program, dim: int) -> Program:
    """A ``dim``-D program (text is parsed leniently) for a ``dim``-D target."""
    if isinstance(program, str):
        program = parse(program, dim, strict=False)  # malformed text raises ParseError (a ValueError)
    if not isinstance(program, Program):
        raise TypeError(f"program must be a csgnet.lang.Program or program text, got {type(program).__name__}")
    if program.dim != dim:
        raise ValueError(f"a {dim}D target needs {dim}D programs, got a {program.dim}D program: "
                         f"{program.text()!r}")
    return program


def program_scores(programs: Sequence[Program | str], target) -> list[tuple[float, float]]:
    """``(iou, chamfer)`` of each program against one target, as :func:`csgnet.score.score_renders`:
    2D: IoU ``|A∧B| / |A∨B|`` (0 when both are empty) and the paper's edge chamfer in pixels
    (:func:`csgnet.metrics.chamfer`); 3D: IoU ``|A∧B| / (|A∨B| + 1)`` and chamfer NaN (not defined).
    An invalid program renders empty."""
    t = _check_target(target)
    pred = render_programs([_check_program(p, t.ndim) for p in programs], t.ndim).cpu()
    t = torch.from_numpy(t)
    ious, cds = score_renders(pred, t.expand(len(pred), *t.shape), t.ndim)
    return [(float(a), float(b)) for a, b in zip(ious, cds)]
