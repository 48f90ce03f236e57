"""The paper's Table 4 (real 2D shapes) and Table 6 (primitive detection) protocols, on this project's data.

:func:`table4`: the chamfer distance between test PartNet silhouettes and their parses (nearest
neighbour; each model at k = 1 and k = 10) after 0 to unlimited refinement iterations, with times.
:func:`table6`: the k programs of a beam search read as primitive detections on synthetic 2D test
programs; AP per primitive type, mAP and images per second. :func:`table4_markdown` and
:func:`table6_markdown` print the rows; :func:`subset` draws a subset of images.

See docs/csgnet.md ("Commands" and "Results") for the exact protocols.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import torch

from shapeio.results import column, make_result

from ..decode import Decoded, beam_search, decode, greedy
from ..score import best_iou_matches, score_beams, score_renders
from ..lang import Draw, Program
from ..primitives import primitives
from ..refinement import refine_beams
from ..renderer import render_programs

__all__ = ["Table4Row", "table4", "table4_markdown", "nearest_silhouettes", "subset", "ITERATIONS",
           "Table6Row", "table6", "table6_markdown", "beam_detections", "primitive_boxes", "box_iou",
           "average_precision", "detection_ap", "detection_classes", "PAPER_TABLE4", "PAPER_TABLE6"]

ITERATIONS: tuple = (0, 1, 2, 4, 10, None)
"""Refinement iteration limits of Table 4 (None: to convergence)."""


def detection_classes() -> dict[str, str]:
    """The detection classes, kind letter -> name: the 2D primitives of the current table (the paper's
    circle, square and triangle)."""
    return {p.kind: p.name for p in primitives(2)}


PAPER_TABLE4 = {"CSGNetStack supervised, k = 10": 1.38, "CSGNetStack RL, k = 10": 1.02,
                "CSGNetStack RL, k = 10, refined": 0.34}
"""The paper's CAD numbers quoted beside ours (CD in pixels; the paper's 2D CAD set, not ours)."""
PAPER_TABLE6 = {10: 83.0, 40: 84.3}
"""The paper's detection mAP (%) at k = 10 and 40."""


def _it_name(it) -> str:
    return "∞" if it is None else str(it)


def subset(n_total: int, n: int | None, seed: int = 0) -> np.ndarray:
    """Indices of ``n`` of ``n_total`` items, drawn without replacement with ``seed`` and sorted
    (all of them when ``n`` is None or not smaller than ``n_total``)."""
    if n is None or n >= n_total:
        return np.arange(n_total)
    if n < 1:
        raise ValueError(f"the subset size must be positive, got {n}")
    return np.sort(np.random.default_rng(seed).choice(n_total, size=n, replace=False))


# ---------------------------------------------------------------------------------------------
# Table 4

@dataclass
class Table4Row:
    """One line of Table 4.

    Attributes:
        method: e.g. ``"CSGNetStack (rl.pt)"`` or ``"nearest neighbour"``.
        protocol: ``"k=1"``, ``"k=10 best-of-k (oracle)"`` or ``"training silhouette, max IoU"``.
        chamfer: mean CD per refinement iteration limit (``0`` = no refinement, ``None`` = unlimited).
        per_image: the per-target CDs behind each mean, ``(N,)`` float64.
        iou: mean IoU (``|A∧B| / |A∨B|``) before refinement.
        decode_seconds: decoding (or nearest-neighbour search) time per image.
        refine_seconds: refinement time per image, per iteration limit.
    """

    method: str
    protocol: str
    chamfer: dict = field(default_factory=dict)
    per_image: dict = field(default_factory=dict)
    iou: float = float("nan")
    decode_seconds: float = 0.0
    refine_seconds: dict = field(default_factory=dict)


def _check_targets(targets, name: str) -> torch.Tensor:
    t = torch.as_tensor(np.asarray(targets)).bool()
    if t.dim() != 3 or tuple(t.shape[1:]) != (64, 64):
        raise ValueError(f"{name} must be (N, 64, 64) images, got shape {tuple(t.shape)}")
    if len(t) and not t.reshape(len(t), -1).any(1).all():
        raise ValueError(f"{name}: empty images have no chamfer distance to refine against")
    return t


def nearest_silhouettes(train, targets, chunk: int = 4096) -> np.ndarray:
    """For each target ``(N, 64, 64)``, the index of the training image ``(M, 64, 64)`` with the highest
    IoU ``|A∧B| / |A∨B|`` (ties: the lowest index)."""
    tr = torch.as_tensor(np.asarray(train)).bool()
    chunks = ((lo, tr[lo: lo + chunk]) for lo in range(0, len(tr), chunk))
    return best_iou_matches(_check_targets(targets, "targets"), chunks).numpy()


def table4(models: Sequence[tuple[str, torch.nn.Module]], targets, train=None, beams: Sequence[int] = (1, 10),
           iterations: Sequence = ITERATIONS, constrained: bool = False, mode: str = "improved", batch: int = 50,
           progress: Callable[[str], None] | None = None) -> list[Table4Row]:
    """Run the Table 4 protocol.

    Args:
        models: ``(label, model)`` pairs: 2D CSGNet / CSGNetStack (:func:`csgnet.inference.load_model`).
        targets: ``(N, 64, 64)`` bool test images (e.g. a :func:`subset` of the silhouettes' test split).
        train: ``(M, 64, 64)`` training images for the nearest-neighbour row (None: no such row).
        beams: beam widths; ``1`` is greedy decoding, larger widths report the best of k by CD.
        iterations: refinement iteration limits; ``0`` is the unrefined parse, ``None`` runs to convergence.
        constrained: grammar-constrained decoding (off: the paper's decoding).
        mode: beam-search mode (:mod:`csgnet.decode`).
        batch: images decoded together.
        progress: called with a line of text as each row finishes.

    Returns:
        The rows, nearest neighbour first, then per model and beam width.
    """
    tgt = _check_targets(targets, "targets")
    n = len(tgt)
    if n == 0:
        raise ValueError("table4 needs at least one target image")
    iterations = list(iterations)
    if 0 not in iterations:
        iterations = [0] + iterations
    say = progress or (lambda s: None)
    rows: list[Table4Row] = []
    if train is not None:
        t0 = time.perf_counter()
        idx = nearest_silhouettes(train, tgt)
        nn_img = torch.as_tensor(np.asarray(train)[idx]).bool()
        secs = (time.perf_counter() - t0) / n
        iou, cd = score_renders(nn_img, tgt, 2)
        rows.append(Table4Row("nearest neighbour", "training silhouette, max IoU", {0: float(cd.mean())}, {0: cd},
                              float(iou.mean()), secs))
        say(f"nearest neighbour: CD {cd.mean():.3f}")
    for label, model in models:
        if model.config.dim != 2:
            raise ValueError(f"{label}: Table 4 is a 2D protocol, got a {model.config.dim}D model")
        model.eval()
        greedy(model, tgt[:1], constrained=constrained, mode=mode)  # warm-up (caches) outside the timing
        for k in beams:
            programs: list[list[Program]] = []
            cds, ious = [], []
            t0 = time.perf_counter()
            for lo in range(0, n, batch):
                x = tgt[lo: lo + batch]
                dec = decode(model, x, k, constrained=constrained, mode=mode)
                _, iou, cd = score_beams(dec, x)
                best = cd.argmin(1)  # best of k by chamfer (k = 1: the greedy program)
                cds.append(cd[np.arange(len(cd)), best])
                ious.append(iou[np.arange(len(cd)), best])
                programs += [[dec.program(i, j) for j in range(dec.k)] for i in range(dec.tokens.shape[0])]
            secs = (time.perf_counter() - t0) / n
            cd0 = np.concatenate(cds)
            row = Table4Row(label, "k=1" if k == 1 else f"k={k} best-of-k (oracle)", {0: float(cd0.mean())},
                            {0: cd0}, float(np.concatenate(ious).mean()), secs)
            for it in iterations:
                if it == 0:
                    continue
                t0 = time.perf_counter()
                vals = np.array([refine_beams(p, tgt[i].numpy(), maxiter=it).score for i, p in enumerate(programs)])
                row.refine_seconds[it] = (time.perf_counter() - t0) / n
                row.per_image[it], row.chamfer[it] = vals, float(vals.mean())
            rows.append(row)
            say(f"{label} {row.protocol}: CD " + ", ".join(f"{_it_name(i)}: {v:.3f}" for i, v in row.chamfer.items()))
    return rows


def table4_markdown(rows: Sequence[Table4Row], note: str = "", iterations: Sequence = ITERATIONS) -> str:
    """Table 4 as markdown, with the paper's CAD figures quoted below it."""
    its = [0] + [i for i in iterations if i != 0]
    last = next((i for i in reversed(its) if i != 0), None) if len(its) > 1 else 0
    head = "| method | protocol | " + " | ".join(f"CD {_it_name(i)} it." for i in its) + \
        " | IoU % (0 it.) | decode ms/image |" + (f" refine ({_it_name(last)} it.) s/image |" if len(its) > 1 else "")
    sep = "|---|---|" + "---|" * len(its) + "---|---|" + ("---|" if len(its) > 1 else "")
    lines = [head, sep]
    for r in rows:
        cells = [f"{r.chamfer[i]:.3f}" if i in r.chamfer else "–" for i in its]
        line = f"| {r.method} | {r.protocol} | " + " | ".join(cells) + f" | {100 * r.iou:.2f} | {1000 * r.decode_seconds:.1f} |"
        if len(its) > 1:
            line += f" {r.refine_seconds[last]:.2f} |" if last in r.refine_seconds else " – |"
        lines.append(line)
    n = len(next(iter(rows[0].per_image.values()))) if rows else 0
    paper = "; ".join(f"{k}: {v:.2f}" for k, v in PAPER_TABLE4.items())
    out = (f"### Table 4 layout (2D real shapes: PartNet silhouettes, test split)\n\n{n} test images. CD: chamfer "
           f"distance in pixels (lower is better), after 0, 1, 2, ... Powell refinement iterations of every beam "
           f"(best kept).\n\n" + "\n".join(lines) + "\n\n"
           f"Paper, Table 4 (its CAD set, a different image set; not comparable number for number): {paper}.\n")
    if note:
        out += "\n" + note.strip() + "\n"
    return out


def table4_result(rows: Sequence[Table4Row], iterations: Sequence = ITERATIONS, notes=(),
                  command: str | None = None, title: str = "Table 4 layout (2D real shapes: PartNet silhouettes, "
                  "test split)", paper: bool = True) -> dict:
    """Table 4 as a result file's content (:func:`shapeio.results.make_result`): CD after each refinement
    iteration limit, IoU before refinement, decoding milliseconds per image."""
    its = [0] + [i for i in iterations if i != 0]
    cols = [column("method", "method"), column("protocol", "protocol")]
    cols += [column(f"cd_{_it_name(i)}", f"CD {_it_name(i)} it.", 3) for i in its]
    cols += [column("iou", "IoU % (0 it.)", 2, 100.0), column("ms", "decode ms / image", 1)]
    data = []
    for r in rows:
        d = {"method": r.method, "protocol": r.protocol, "iou": r.iou, "ms": 1000 * r.decode_seconds}
        d.update({f"cd_{_it_name(i)}": r.chamfer.get(i) for i in its})
        data.append(d)
    n = len(next(iter(rows[0].per_image.values()))) if rows else 0
    head = [f"{n} test images. CD: chamfer distance in pixels (lower is better)"
            + (" after 0, 1, 2, ... Powell refinement iterations of every beam (best kept)." if len(its) > 1 else ".")]
    if paper:
        quoted = "; ".join(f"{k}: {v:.2f}" for k, v in PAPER_TABLE4.items())
        head.append(f"The paper's Table 4 is measured on its CAD set, another image set, so its figures are not "
                    f"comparable number for number: {quoted}.")
    return make_result(title, cols, data, [*head, *notes], command)


# ---------------------------------------------------------------------------------------------
# Table 6

def primitive_boxes(draws: Sequence[Draw], cache: dict | None = None) -> dict:
    """Pixel bounding boxes ``(row0, col0, row1, col1)`` (inclusive) of 2D primitives, each rendered
    alone on the 64x64 canvas (``None`` for a primitive that draws no pixel). Results are added to
    ``cache`` (a dict) when given, and looked up there first."""
    cache = {} if cache is None else cache
    todo = sorted({d for d in draws if d not in cache}, key=lambda d: (d.kind, d.params))
    if todo:
        for d in todo:
            if not isinstance(d, Draw) or d.dim != 2:
                raise ValueError(f"primitive boxes are for 2D primitives, got {d!r}")
        imgs = render_programs([Program((d,), 2) for d in todo], 2).numpy()
        rows_on, cols_on = imgs.any(2), imgs.any(1)
        for d, r, c in zip(todo, rows_on, cols_on):
            if not r.any():
                cache[d] = None
                continue
            rr, cc = np.flatnonzero(r), np.flatnonzero(c)
            cache[d] = (int(rr[0]), int(cc[0]), int(rr[-1]), int(cc[-1]))
    return {d: cache[d] for d in draws}


def box_iou(a, b) -> np.ndarray:
    """IoU of inclusive pixel boxes: ``a`` ``(N, 4)`` against ``b`` ``(M, 4)`` → ``(N, M)``."""
    a = np.asarray(a, dtype=np.int64).reshape(-1, 4)
    b = np.asarray(b, dtype=np.int64).reshape(-1, 4)
    h = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]) + 1
    w = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]) + 1
    inter = np.clip(h, 0, None) * np.clip(w, 0, None)
    area_a = (a[:, 2] - a[:, 0] + 1) * (a[:, 3] - a[:, 1] + 1)
    area_b = (b[:, 2] - b[:, 0] + 1) * (b[:, 3] - b[:, 1] + 1)
    return inter / (area_a[:, None] + area_b[None] - inter)


def average_precision(detections: Sequence[tuple[int, float, tuple]], truths: dict[int, Sequence[tuple]],
                      iou_threshold: float = 0.5) -> float:
    """AP of one class.

    Args:
        detections: ``(image, score, box)`` triples (box: inclusive pixel box, or None: never matches).
        truths: ``image -> [box, ...]``, the ground-truth boxes of the class.
        iou_threshold: the IoU a true positive needs (0.5).

    Returns:
        The area under the interpolated precision-recall curve; NaN when there is no ground truth.
    """
    n_pos = sum(len(v) for v in truths.values())
    if n_pos == 0:
        return float("nan")
    order = sorted(range(len(detections)), key=lambda i: -detections[i][1])  # stable: ties keep input order
    used = {img: np.zeros(len(v), bool) for img, v in truths.items()}
    tp = np.zeros(len(order))
    for rank, i in enumerate(order):
        img, _, box = detections[i]
        gts = truths.get(img, ())
        if box is None or not len(gts):
            continue
        iou = box_iou([box], gts)[0]
        iou = np.where(used[img], -1.0, iou)
        j = int(iou.argmax())
        if iou[j] >= iou_threshold:
            used[img][j] = True
            tp[rank] = 1.0
    ctp = np.cumsum(tp)
    recall = ctp / n_pos
    precision = ctp / np.arange(1, len(order) + 1)
    # all-point interpolation: precision made non-increasing from the right, summed over recall steps
    r = np.concatenate([[0.0], recall, [1.0]])
    p = np.concatenate([[0.0], precision, [0.0]])
    p = np.maximum.accumulate(p[::-1])[::-1]
    steps = np.flatnonzero(r[1:] != r[:-1])
    return float(np.sum((r[steps + 1] - r[steps]) * p[steps + 1]))


def detection_ap(detections: Sequence[dict], truths: Sequence[Sequence[Draw]], iou_threshold: float = 0.5,
                 cache: dict | None = None) -> dict[str, float]:
    """AP per primitive type.

    Args:
        detections: per image, ``{Draw: score}``.
        truths: per image, the ground-truth primitives (duplicates count once).
        iou_threshold: box IoU for a match.
        cache: a box cache for :func:`primitive_boxes`.

    Returns:
        ``{"circle": AP, "square": AP, "triangle": AP}`` (NaN for a type with no ground truth).
    """
    if len(detections) != len(truths):
        raise ValueError(f"{len(detections)} detection sets for {len(truths)} images")
    cache = {} if cache is None else cache
    allp = [d for det in detections for d in det] + [d for gt in truths for d in gt]
    boxes = primitive_boxes(allp, cache)
    out = {}
    for kind, name in detection_classes().items():
        dets = [(i, float(s), boxes[d]) for i, det in enumerate(detections) for d, s in det.items() if d.kind == kind]
        gts = {}
        for i, gt in enumerate(truths):
            bs = [boxes[d] for d in dict.fromkeys(gt) if d.kind == kind and boxes[d] is not None]
            if bs:
                gts[i] = bs
        out[name] = average_precision(dets, gts, iou_threshold)
    return out


def beam_detections(decoded: Decoded) -> list[dict[Draw, float]]:
    """Per target, ``{primitive: fraction of the k beam programs that contain it}``."""
    out = []
    k = decoded.k
    for i in range(decoded.tokens.shape[0]):
        counts: dict[Draw, int] = {}
        for j in range(k):
            if not torch.isfinite(decoded.logprob[i, j]):
                continue  # a slot that never held a hypothesis
            for d in set(decoded.program(i, j).draws):
                counts[d] = counts.get(d, 0) + 1
        out.append({d: c / k for d, c in counts.items()})
    return out


@dataclass
class Table6Row:
    """Detection results at one beam width: AP per type, mAP (NaN types left out), images per second."""

    k: int
    ap: dict
    images: int
    images_per_second: float

    @property
    def map(self) -> float:
        vals = [v for v in self.ap.values() if not np.isnan(v)]
        return float(np.mean(vals)) if vals else float("nan")


def table6(model, programs: Sequence[Program], beams: Sequence[int] = (10, 40), batch: int = 50,
           constrained: bool = False, mode: str = "improved", iou_threshold: float = 0.5,
           progress: Callable[[str], None] | None = None) -> list[Table6Row]:
    """Run the Table 6 protocol on synthetic 2D target programs (see the module docstring)."""
    if model.config.dim != 2:
        raise ValueError(f"Table 6 is a 2D protocol, got a {model.config.dim}D model")
    programs = list(programs)
    if not programs:
        raise ValueError("table6 needs at least one target program")
    targets = render_programs(programs, 2)
    truths = [p.draws for p in programs]
    model.eval()
    beam_search(model, targets[:1], 2, constrained=constrained, mode=mode)  # warm-up outside the timing
    cache: dict = {}
    rows = []
    for k in beams:
        if k < 1:
            raise ValueError(f"beam widths must be positive, got {k}")
        dets: list[dict] = []
        t0 = time.perf_counter()
        for lo in range(0, len(programs), batch):
            dec = beam_search(model, targets[lo: lo + batch], k, constrained=constrained, mode=mode)
            dets += beam_detections(dec)
        secs = time.perf_counter() - t0
        ap = detection_ap(dets, truths, iou_threshold, cache)
        rows.append(Table6Row(k, ap, len(programs), len(programs) / secs))
        if progress:
            progress(f"k={k}: mAP {100 * rows[-1].map:.1f}")
    return rows


def table6_markdown(rows: Sequence[Table6Row], note: str = "") -> str:
    """Table 6 as markdown, the paper's mAP beside ours."""
    names = list(detection_classes().values())
    lines = ["| k | " + " | ".join(f"AP {n} %" for n in names) + " | mAP % | paper mAP % | images/s |",
             "|---|" + "---|" * len(names) + "---|---|---|"]
    for r in rows:
        cells = " | ".join(f"{100 * r.ap[n]:.1f}" for n in names)
        paper = f"{PAPER_TABLE6[r.k]:.1f}" if r.k in PAPER_TABLE6 else "–"
        lines.append(f"| {r.k} | {cells} | {100 * r.map:.1f} | {paper} | {r.images_per_second:.1f} |")
    n = rows[0].images if rows else 0
    out = (f"### Table 6 layout (primitive detection, 2D synthetic test programs)\n\n{n} target programs; a "
           f"primitive's score is the fraction of the k beam programs containing it; AP at box IoU 0.5.\n\n"
           + "\n".join(lines) + "\n")
    if note:
        out += "\n" + note.strip() + "\n"
    return out


def table6_result(labelled: Sequence[tuple[str, Sequence[Table6Row]]], notes=(), command: str | None = None) -> dict:
    """Table 6 as a result file's content, one block of rows per ``(label, rows)`` model: AP per primitive
    type, mAP, the paper's mAP, images per second."""
    names = list(detection_classes().values())
    cols = [column("method", "method"), column("k", "k")] + [column(f"ap_{n}", f"AP {n} %", 1, 100.0) for n in names]
    cols += [column("map", "mAP %", 1, 100.0), column("paper_map", "paper mAP %", 1),
             column("images_per_second", "images/s", 1)]
    data = []
    for label, rows in labelled:
        for r in rows:
            d = {"method": label, "k": r.k, "map": r.map, "paper_map": PAPER_TABLE6.get(r.k),
                 "images_per_second": r.images_per_second}
            d.update({f"ap_{n}": r.ap[n] for n in names})
            data.append(d)
    n = labelled[0][1][0].images if labelled and labelled[0][1] else 0
    return make_result("Table 6 layout (primitive detection, 2D synthetic test programs)", cols, data,
                       [f"{n} target programs; a primitive's score is the fraction of the k beam programs containing "
                        f"it; AP at box IoU 0.5.", *notes], command)
