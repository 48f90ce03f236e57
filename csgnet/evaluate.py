"""Evaluation of shape parsers on a synthetic test split, laid out like the paper's Tables 3 and 5.

For each program length and each beam width k, every test target is decoded and each hypothesis is
rendered and scored against the target. Two protocols are reported, labelled:

* **top-1 of k**: the most likely hypothesis (what a user gets without looking at the target);
* **best of k (oracle)**: the hypothesis closest to the target (max IoU, or min chamfer in 2D), the
  protocol behind the paper's beam-search numbers.

The nearest-neighbour baseline answers each target with the training program whose render has the
highest IoU with it (ties: the first). Metrics are those of spec section (h): 2D IoU
``|A∧B| / |A∨B|`` and the edge chamfer in pixels; 3D IoU ``|A∧B| / (|A∨B| + 1)``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from . import metrics
from .decode import beam_search, greedy
from .lang import Program
from .renderer import render_programs, render_tokens

__all__ = ["Row", "evaluate_model", "nearest_neighbour", "markdown_tables"]


@dataclass
class Row:
    """One line of a results table: a method and protocol, with per-length means."""

    method: str
    iou: dict[int, float] = field(default_factory=dict)
    chamfer: dict[int, float] = field(default_factory=dict)
    count: dict[int, int] = field(default_factory=dict)
    seconds: float = 0.0

    def overall(self, what: str) -> float:
        vals = getattr(self, what)
        n = sum(self.count[L] for L in vals)
        return float(sum(vals[L] * self.count[L] for L in vals) / n) if n else float("nan")


def _score(pred: torch.Tensor, target: torch.Tensor, dim: int) -> tuple[np.ndarray, np.ndarray]:
    pred, target = pred.cpu(), target.cpu()
    if dim == 2:
        iou = np.asarray(metrics.iou(pred, target, denominator="union"), dtype=np.float64)
        cd = np.asarray(metrics.chamfer(pred, target), dtype=np.float64)
    else:
        iou = np.asarray(metrics.iou_3d(pred, target), dtype=np.float64)
        cd = np.full(len(iou), np.nan)
    return np.nan_to_num(iou, nan=0.0), cd


def evaluate_model(model, tests: dict[int, list[Program]], beams=(1, 5, 10), name: str = "model",
                   batch: int = 50, mode: str = "improved", constrained: bool = False) -> list[Row]:
    """Score ``model`` on ``{length: programs}`` for each beam width.

    Returns rows ``"{name} k=K top-1"`` and, for K > 1, ``"{name} k=K best-of-k (oracle)"``; their
    ``seconds`` is the decoding + rendering time per image.
    """
    dim = model.config.dim
    model.eval()
    rows: dict[str, Row] = {}
    for k in beams:
        top = rows.setdefault(f"{name} k={k} top-1", Row(f"{name} k={k} top-1"))
        best = rows.setdefault(f"{name} k={k} best-of-k (oracle)", Row(f"{name} k={k} best-of-k (oracle)")) \
            if k > 1 else None
        seconds, images = 0.0, 0
        for L, progs in sorted(tests.items()):
            ious, cds, biou, bcd = [], [], [], []
            for lo in range(0, len(progs), batch):
                tgt = render_programs(progs[lo: lo + batch], dim)
                t0 = time.perf_counter()
                dec = greedy(model, tgt, mode=mode, constrained=constrained) if k == 1 else \
                    beam_search(model, tgt, k, mode=mode, constrained=constrained)
                pred = render_tokens(dec.flat_tokens(), dim, dec.lengths.flatten())
                seconds += time.perf_counter() - t0
                images += tgt.shape[0]
                iou, cd = _score(pred, tgt.repeat_interleave(dec.k, 0), dim)
                iou, cd = iou.reshape(-1, dec.k), cd.reshape(-1, dec.k)
                ious.append(iou[:, 0])
                cds.append(cd[:, 0])
                if best is not None:
                    biou.append(iou.max(1))
                    bcd.append(cd.min(1) if dim == 2 else cd[:, 0])
            for row, a, c in ((top, ious, cds), (best, biou, bcd)):
                if row is None:
                    continue
                a, c = np.concatenate(a), np.concatenate(c)
                row.iou[L], row.chamfer[L], row.count[L] = float(a.mean()), float(c.mean()), len(a)
        top.seconds = seconds / max(images, 1)
        if best is not None:
            best.seconds = top.seconds
    return list(rows.values())


def nearest_neighbour(train: list[Program], tests: dict[int, list[Program]], dim: int, chunk: int = 2048
                      ) -> Row:
    """The nearest-neighbour baseline: for each test target, the training render with the highest IoU."""
    t0 = time.perf_counter()
    targets = {L: render_programs(p, dim).reshape(len(p), -1).float() for L, p in tests.items()}
    all_t = torch.cat(list(targets.values()))
    t_area = all_t.sum(1)
    best = torch.full((all_t.shape[0],), -1.0)
    best_idx = torch.zeros(all_t.shape[0], dtype=torch.long)
    plus = 1.0 if dim == 3 else 0.0
    for lo in range(0, len(train), chunk):
        tr = render_programs(train[lo: lo + chunk], dim).reshape(-1, all_t.shape[1]).float()
        inter = all_t @ tr.T
        union = t_area[:, None] + tr.sum(1)[None] - inter + plus
        iou = torch.where(union > 0, inter / union.clamp(min=1e-9), torch.zeros_like(inter))
        val, idx = iou.max(1)
        better = val > best
        best = torch.where(better, val, best)
        best_idx = torch.where(better, idx + lo, best_idx)
    row = Row("nearest neighbour")
    off = 0
    for L, p in sorted(tests.items()):
        n = len(p)
        nn = render_programs([train[int(i)] for i in best_idx[off: off + n]], dim)
        tgt = render_programs(p, dim)
        iou, cd = _score(nn, tgt, dim)
        row.iou[L], row.chamfer[L], row.count[L] = float(iou.mean()), float(cd.mean()), n
        off += n
    row.seconds = (time.perf_counter() - t0) / max(off, 1)
    return row


def markdown_tables(rows: list[Row], dim: int, note: str = "") -> str:
    """Markdown: per-length IoU (%), overall IoU and (2D) chamfer in pixels, seconds per image."""
    lengths = sorted({L for r in rows for L in r.count})
    head = "| method | " + " | ".join(f"IoU len {L}" for L in lengths) + " | IoU all |"
    sep = "|---|" + "---|" * len(lengths) + "---|"
    if dim == 2:
        head += " CD all (px) |"
        sep += "---|"
    head += " ms / image |"
    sep += "---|"
    lines = [head, sep]
    for r in rows:
        cells = [f"{100 * r.iou[L]:.2f}" if L in r.iou else "" for L in lengths]
        line = f"| {r.method} | " + " | ".join(cells) + f" | {100 * r.overall('iou'):.2f} |"
        if dim == 2:
            line += f" {r.overall('chamfer'):.3f} |"
        line += f" {1000 * r.seconds:.2f} |"
        lines.append(line)
    title = "Table 3 layout (2D synthetic test)" if dim == 2 else "Table 5 layout (3D synthetic test)"
    counts = ", ".join(f"len {L}: {next(r.count[L] for r in rows if L in r.count)}" for L in lengths)
    out = f"### {title}\n\nTest programs per length: {counts}.\n\n" + "\n".join(lines) + "\n"
    if note:
        out += "\n" + note.strip() + "\n"
    return out
