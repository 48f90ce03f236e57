"""Chamfer-distance pairs per second: ``csgnet.metrics.chamfer`` (batched) against a per-pair loop.

The per-pair baseline is the reference's computation written as the original code does it: for every
pair, uint8 0/255 conversion, the blank/full check, ``cv2.Canny`` and ``cv2.distanceTransform`` of both
images, and float64 sums. Both run in one process on the same pairs of rendered random programs, and the
script checks that they agree bit for bit before printing the rates.

Usage::

    python bench/bench_csg_chamfer.py [--pairs 10000] [--length 13] [--targets 0] [--seed 0] [--threads N]
                                      [--batch B] [--repeat 3]

``--targets K`` (K > 0) draws the targets from K distinct shapes, as when beams or samples share their
target; the default 0 makes every pair distinct (the worst case for the batched path).
``--threads N`` sets OpenCV's thread count for both sides and the batched path's worker threads
(default: OpenCV's own setting, and ``chamfer``'s default of ``min(4, cpu_count)`` workers).

Timing is the same for both sides: one untimed warm-up pass, then the best of ``--repeat`` passes, as
wall time and as process CPU time (with one thread the steadier figure on a shared machine; with
several threads CPU time adds up the threads, so only wall time shows their gain).
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
# the same random programs and timing as the render benchmark; its import puts tests/ on the path
from bench_csg_render import random_programs, timed
from csg_testutil import reference_chamfer
from csgnet import metrics


def chamfer_pairs_baseline(pred: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The reference's per-pair loop (one Canny and one distance transform per image per pair;
    ``reference_chamfer`` of ``tests/csg_testutil.py``, the chamfer tests' oracle)."""
    return np.array([reference_chamfer(a, b) for a, b in zip(pred, target)], np.float64)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=10000)
    ap.add_argument("--length", type=int, default=13)
    ap.add_argument("--targets", type=int, default=0, help="distinct targets (0: one per pair)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=None, help="threads for the batched path")
    ap.add_argument("--threads", type=int, default=None,
                    help="OpenCV threads for both sides (and the batched path's workers unless --workers)")
    ap.add_argument("--repeat", type=int, default=3, help="timed passes per side (best is kept)")
    ap.add_argument("--batch", type=int, default=0, help="pairs per batched call (0: all pairs in one call)")
    args = ap.parse_args(argv)
    if args.threads:
        cv2.setNumThreads(args.threads)
        if args.workers is None:
            args.workers = args.threads

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

    base = timed(lambda: chamfer_pairs_baseline(pred, target), args.repeat)
    batch = args.batch or args.pairs

    def batched():
        return np.concatenate([metrics.chamfer(pred[i:i + batch], target[i:i + batch], workers=args.workers)
                               for i in range(0, args.pairs, batch)])

    fast = timed(batched, args.repeat)
    res_base = chamfer_pairs_baseline(pred, target)
    res_fast = batched()

    same = np.array_equal(res_base, res_fast)
    print(f"equal to the per-pair baseline: {same} (max |diff| {np.abs(res_base - res_fast).max():.3g}); "
          f"mean CD {res_fast.mean():.4f}, {np.mean(res_fast == 16.0) * 100:.1f}% penalty pairs")
    print(f"pairs/s (by wall time | by CPU time), {args.pairs} pairs, {batch} per batched call, "
          f"best of {args.repeat}:")
    print(f"  per-pair baseline: {args.pairs / base[0]:9.0f} | {args.pairs / base[1]:9.0f}")
    print(f"  batched chamfer:   {args.pairs / fast[0]:9.0f} | {args.pairs / fast[1]:9.0f}")
    print(f"  speed-up:          {base[0] / fast[0]:8.2f}x | {base[1] / fast[1]:8.2f}x")
    print(f"# load average after the run: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if not same:
        raise SystemExit("batched and per-pair chamfer differ")


if __name__ == "__main__":
    main()
