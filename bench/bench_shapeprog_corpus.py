"""Whole-corpus figures of the ShapeAssembly executor, and stability on a corpus sample.

Prints, for all 11,922 corpus programs: seconds per precision (float32, float64; ``execute_batch`` in
batches of 200, no grad), leaves per shape (min / median / mean / max), the extent statistics
(max |vertex| / half root bbox above 1.0001, 1.01, 1.05, 1.5, with the largest), and the programs whose
float32 and float64 corners differ by more than 2e-5. With ``--stability N``: how many of N random corpus
shapes are stable with identity and with solid-box link inertia, and the seconds per shape.

Usage::

    python bench/bench_shapeprog_corpus.py [--stability 40] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import platform
import random
import statistics
import sys
import time

import torch

import shapeprog
from shapeprog import corpus
from shapeprog.physics import stability


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=200)
    ap.add_argument("--stability", type=int, default=0, help="also test N random corpus shapes for stability")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, threads {torch.get_num_threads()}")
    names = [(c, i) for c in corpus.CATEGORIES for i in corpus.ids(c, "all")]
    progs = [shapeprog.parse(corpus.read(c, i), file=f"{c}/{i}.txt") for c, i in names]
    corners = {}
    with torch.no_grad():
        for dtype in (torch.float32, torch.float64):
            t0 = time.perf_counter()
            shapes = []
            for k in range(0, len(progs), args.batch):
                shapes += shapeprog.execute_batch(progs[k:k + args.batch], dtype=dtype)
            dt = time.perf_counter() - t0
            bad = [f"{c}/{i}" for (c, i), s in zip(names, shapes) if not torch.isfinite(s.corners).all()]
            corners[dtype] = [s.corners.double() for s in shapes]
            print(f"{str(dtype)[6:]}: {len(progs)} programs in {dt:.1f} s ({len(progs) / dt:.0f} programs/s), "
                  f"non-finite: {len(bad)} {bad[:5]}")
            if dtype == torch.float32:
                leaves = [s.corners.shape[0] for s in shapes]
                ext = [float((s.corners.abs() / (s.root_dims / 2)).max()) for s in shapes]
    print(f"leaves per shape: min {min(leaves)}, median {statistics.median(leaves):g}, "
          f"mean {statistics.mean(leaves):.2f}, max {max(leaves)}")
    counts = [sum(e > t for e in ext) for t in (1.0001, 1.01, 1.05, 1.5)]
    worst = max(range(len(ext)), key=ext.__getitem__)
    print(f"extent > 1.0001 / 1.01 / 1.05 / 1.5: {counts}; largest {names[worst][0]}/{names[worst][1]} "
          f"{ext[worst]:.3f}")
    diffs = sorted(((float((a - b).abs().max()), f"{c}/{i}")
                    for (c, i), a, b in zip(names, corners[torch.float32], corners[torch.float64])), reverse=True)
    above = [(d, n) for d, n in diffs if d > 2e-5]
    print(f"float32 vs float64 max corner difference > 2e-5: {len(above)} programs")
    for d, n in above[:6]:
        print(f"  {n}: {d:.2g}")
    if len(above) > 6:
        print(f"  {len(above) - 6} more: {above[-1][0]:.2g} to {above[6][0]:.2g}")

    if args.stability:
        rng = random.Random(args.seed)
        sample = rng.sample(range(len(progs)), args.stability)
        for inertia in ("identity", "box"):
            t0 = time.perf_counter()
            stable = sum(stability(corners[torch.float32][k].float(), inertia=inertia) for k in sample)
            dt = time.perf_counter() - t0
            print(f"stability ({inertia} inertia): {stable} of {len(sample)} random corpus shapes stable, "
                  f"{dt / len(sample):.2f} s per shape")


if __name__ == "__main__":
    main()
