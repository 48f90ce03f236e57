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

from shapeio.results import column, make_result

from ..decode import decode
from ..lang import Program
from ..renderer import render_programs
from ..score import best_iou_matches, score_beams, score_renders

__all__ = ["Row", "evaluate_model", "evaluate_refined", "nearest_neighbour", "markdown_tables", "table_result"]


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


def evaluate_model(model, tests: dict[int, list[Program]], beams=(1, 5, 10), name: str = "model",
                   batch: int = 50, mode: str = "improved", constrained: bool = False,
                   precision: str = "float32", views: int = 1) -> list[Row]:
    """Score ``model`` on ``{length: programs}`` for each beam width, decoding in ``precision``
    (:data:`csgnet.decode.PRECISIONS`; float32, the tables' protocol, by default) with ``views`` mirror views
    (:data:`csgnet.decode.VIEWS`; 1, the paper's decoding, by default).

    Returns rows ``"{name} k=K top-1"`` and, for K > 1, ``"{name} k=K best-of-k (oracle)"`` (with ``views`` > 1,
    ``"{name} k=K, V views ..."``); their ``seconds`` is the decoding + rendering time per image.
    """
    dim = model.config.dim
    model.eval()
    rows: dict[str, Row] = {}
    for k in beams:
        label = f"{name} k={k}" + (f", {views} views" if views > 1 else "")
        top = rows.setdefault(f"{label} top-1", Row(f"{label} top-1"))
        best = rows.setdefault(f"{label} best-of-k (oracle)", Row(f"{label} best-of-k (oracle)")) if k > 1 else None
        seconds, images = 0.0, 0
        for L, progs in sorted(tests.items()):
            ious, cds, biou, bcd = [], [], [], []
            for lo in range(0, len(progs), batch):
                tgt = render_programs(progs[lo: lo + batch], dim)
                t0 = time.perf_counter()
                dec = decode(model, tgt, k, mode=mode, constrained=constrained, precision=precision, views=views)
                _, iou, cd = score_beams(dec, tgt)
                seconds += time.perf_counter() - t0
                images += tgt.shape[0]
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


def evaluate_refined(model, tests: dict[int, list[Program]], beam: int = 10, name: str = "model",
                     per_length: int | None = None, rule: str = "short", precision: str = "float32",
                     views: int = 1) -> Row:
    """The whole parse of :func:`csgnet.inference.parse_shape` (beam search, the beam closest to the target,
    refinement of every valid beam, the ``rule``'s choice) on the first ``per_length`` targets per length:
    a row ``"{name} k=K + refinement ({rule})"`` (``"{name} k=K, V views + ..."`` with ``views`` > 1) with the
    chosen programs' IoU (and chamfer in 2D); ``seconds`` per image. Decoded in ``precision`` (float32, the
    tables' protocol, by default) with ``views`` mirror views (1, the paper's decoding, by default)."""
    from ..inference import parse_shape  # lazy: inference brings PIL (users' images)

    dim = model.config.dim
    row = Row(f"{name} k={beam}" + (f", {views} views" if views > 1 else "") + f" + refinement ({rule})")
    t0, images = time.perf_counter(), 0
    for L, progs in sorted(tests.items()):
        progs = progs[:per_length] if per_length else progs
        if not progs:
            continue
        targets = render_programs(progs, dim).cpu().numpy()
        ious, cds = [], []
        for target in targets:
            parsed = parse_shape(target, model=model, beam=beam, select="match", refine=True, rule=rule,
                                 precision=precision, views=views)
            iou, cd = parsed.refined.after if parsed.refined is not None else (parsed.decoded.iou, parsed.decoded.chamfer)
            ious.append(iou)
            cds.append(cd)
        row.iou[L], row.chamfer[L], row.count[L] = float(np.mean(ious)), float(np.mean(cds)), len(progs)
        images += len(progs)
    row.seconds = (time.perf_counter() - t0) / max(images, 1)
    return row


def nearest_neighbour(train: list[Program], tests: dict[int, list[Program]], dim: int, chunk: int = 2048
                      ) -> Row:
    """The nearest-neighbour baseline: for each test target, the training render with the highest IoU."""
    t0 = time.perf_counter()
    order = sorted(tests)
    targets = {L: render_programs(tests[L], dim) for L in order}
    chunks = ((lo, render_programs(train[lo: lo + chunk], dim)) for lo in range(0, len(train), chunk))
    best_idx = best_iou_matches(torch.cat([targets[L] for L in order]), chunks, plus=1.0 if dim == 3 else 0.0)
    row = Row("nearest neighbour")
    off = 0
    for L in order:
        n = len(tests[L])
        nn = render_programs([train[int(i)] for i in best_idx[off: off + n]], dim)
        iou, cd = score_renders(nn, targets[L], dim)
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


def table_result(rows: list[Row], dim: int, notes=(), command: str | None = None) -> dict:
    """The rows as a result file's content (:func:`shapeio.results.make_result`): per-length IoU, overall IoU,
    (2D) chamfer in pixels and milliseconds per image, with the test programs per length in a note."""
    lengths = sorted({L for r in rows for L in r.count})
    cols = [column("method", "method")] + [column(f"iou_len{L}", f"IoU len {L}", 2, 100.0) for L in lengths]
    cols.append(column("iou", "IoU all", 2, 100.0))
    if dim == 2:
        cols.append(column("chamfer", "CD all (px)", 3))
    cols.append(column("ms", "ms / image", 2))
    data = []
    for r in rows:
        d = {"method": r.method, "iou": r.overall("iou"), "ms": 1000 * r.seconds}
        d.update({f"iou_len{L}": r.iou.get(L) for L in lengths})
        if dim == 2:
            d["chamfer"] = r.overall("chamfer")
        data.append(d)
    counts = ", ".join(f"len {L}: {next(r.count[L] for r in rows if L in r.count)}" for L in lengths)
    title = "Table 3 layout (2D synthetic test)" if dim == 2 else "Table 5 layout (3D synthetic test)"
    return make_result(title, cols, data, [f"Test programs per length: {counts}.", *notes], command)
