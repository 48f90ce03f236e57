"""Chamfer-distance pairs per second: ``csgnet.metrics.chamfer`` (batched) against a per-pair loop.

The per-pair baseline is the reference's computation written as the original code does it: for every
pair, uint8 0/255 conversion, the blank/full check, ``cv2.Canny`` and ``cv2.distanceTransform`` of both
images, and float64 sums. Both run in one process on the same pairs of rendered random programs, and the
script checks that they agree bit for bit before printing the rates.

Usage::

    python bench/bench_csg_chamfer.py [--pairs 10000] [--length 13] [--targets 0] [--seed 0]

``--targets K`` (K > 0) draws the targets from K distinct shapes, as when beams or samples share their
target; the default 0 makes every pair distinct (the worst case for the batched path).
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time

import numpy as np

import cv2

import csgnet
from bench_csg_render import random_programs  # the same random programs as the render benchmark
from csgnet import metrics


def chamfer_pairs_baseline(pred: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The reference's per-pair loop (one Canny and one distance transform per image per pair)."""
    out = np.empty(len(pred), np.float64)
    full = 255 * pred.shape[-1] * pred.shape[-2]
    for i in range(len(pred)):
        img1 = pred[i].astype(np.uint8) * 255
        img2 = target[i].astype(np.uint8) * 255
        s1, s2 = int(img1.sum()), int(img2.sum())
        if s1 == 0 or s2 == 0 or s1 == full or s2 == full:
            out[i] = 16.0
            continue
        e1 = cv2.Canny(img1, 1, 3)
        e2 = cv2.Canny(img2, 1, 3)
        if e1.sum() == 0 or e2.sum() == 0:
            out[i] = 16.0
            continue
        d1 = cv2.distanceTransform(~e1, cv2.DIST_L2, 3).astype(np.float64)
        d2 = cv2.distanceTransform(~e2, cv2.DIST_L2, 3).astype(np.float64)
        E1, E2 = e1.astype(np.float64), e2.astype(np.float64)
        out[i] = (np.sum(d1 * E2) / (np.sum(E2) + 1) + np.sum(d2 * E1) / (np.sum(E1) + 1)) / 2.0
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=10000)
    ap.add_argument("--length", type=int, default=13)
    ap.add_argument("--targets", type=int, default=0, help="distinct targets (0: one per pair)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=None, help="threads for the batched path")
    args = ap.parse_args(argv)

    print("command:", shlex.join([sys.executable, *sys.argv]))
    print(f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, "
          f"cpu_count={os.cpu_count()}, python {platform.python_version()}, numpy {np.__version__}, "
          f"opencv {cv2.__version__} (cv2 threads {cv2.getNumThreads()})")

    rng = np.random.default_rng(args.seed)
    n_t = args.targets if args.targets > 0 else args.pairs
    t0 = time.perf_counter()
    pred = csgnet.render(random_programs(2, args.pairs, args.length, rng), 2)
    tgt_shapes = csgnet.render(random_programs(2, n_t, args.length, rng), 2)
    target = tgt_shapes[rng.integers(n_t, size=args.pairs)] if args.targets > 0 else tgt_shapes
    print(f"data: {args.pairs} pairs of random length-{args.length} programs, "
          f"{n_t} distinct targets, rendered in {time.perf_counter() - t0:.1f} s; "
          f"{np.mean(~pred.reshape(len(pred), -1).any(1)) * 100:.1f}% empty predictions")

    metrics.chamfer(pred[:64], target[:64])  # warm-up (imports, thread pool)
    t0 = time.perf_counter()
    base = chamfer_pairs_baseline(pred, target)
    t_base = time.perf_counter() - t0
    t0 = time.perf_counter()
    fast = metrics.chamfer(pred, target, workers=args.workers)
    t_fast = time.perf_counter() - t0

    same = np.array_equal(base, fast)
    print(f"equal to the per-pair baseline: {same} (max |diff| {np.abs(base - fast).max():.3g}); "
          f"mean CD {fast.mean():.4f}, {np.mean(fast == 16.0) * 100:.1f}% penalty pairs")
    print(f"per-pair baseline: {args.pairs / t_base:10.0f} pairs/s ({t_base:.2f} s)")
    print(f"batched chamfer:   {args.pairs / t_fast:10.0f} pairs/s ({t_fast:.2f} s)")
    print(f"speed-up: {t_base / t_fast:.2f}x")
    if not same:
        raise SystemExit("batched and per-pair chamfer differ")


if __name__ == "__main__":
    main()
