"""The line-vector round trip of the ShapeAssembly VAE over the whole corpus (11,922 programs).

For every corpus program: program -> float32 line-vector tree -> program. Prints how many give the
corpus text back byte for byte (rounded to 3 decimals; and float64 vectors unrounded), and the largest
corner difference between executing the original and the text written from the unrounded float32
vectors (the test suite checks a seeded sample of 300: ``tests/shapeprog/vae/test_vectors.py``).

Usage::

    python bench/bench_vae_vectors.py [--batch 200]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import torch

import shapeprog
from shapeprog import corpus
from shapeprog.vae.vectors import program_to_tree, tree_to_program


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=200, help="programs per execute_batch call")
    args = ap.parse_args(argv)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}")
    names = [(c, i) for c in corpus.CATEGORIES for i in corpus.ids(c, "all")]
    texts = [corpus.read(c, i) for c, i in names]
    progs = [shapeprog.parse(t, file=f"{c}/{i}.txt") for t, (c, i) in zip(texts, names)]

    t0 = time.perf_counter()
    trees = [program_to_tree(p, file=f"{c}/{i}.txt") for p, (c, i) in zip(progs, names)]
    t1 = time.perf_counter()
    back = [shapeprog.to_text(tree_to_program(t, decimals=3)) for t in trees]
    t2 = time.perf_counter()
    print(f"program_to_tree: {len(progs)} programs in {t1 - t0:.1f} s; tree_to_program + to_text: {t2 - t1:.1f} s")
    same3 = sum(a == b for a, b in zip(back, texts))
    same64 = sum(shapeprog.to_text(tree_to_program(program_to_tree(p, dtype=torch.float64))) == t
                 for p, t in zip(progs, texts))
    print(f"corpus text back: float32 rounded to 3 decimals {same3} / {len(texts)}, float64 {same64} / {len(texts)}")

    written = [shapeprog.parse(shapeprog.to_text(tree_to_program(t))) for t in trees]
    worst, where = 0.0, None
    with torch.no_grad():
        for k in range(0, len(progs), args.batch):
            a = shapeprog.execute_batch(progs[k:k + args.batch])
            b = shapeprog.execute_batch(written[k:k + args.batch])
            for j, (x, y) in enumerate(zip(a, b)):
                d = float((x.corners - y.corners).abs().max()) if x.corners.shape == y.corners.shape else float("inf")
                if d > worst or where is None:
                    worst, where = max(d, worst), names[k + j]
    print(f"execute(original) vs execute(text of unrounded float32 vectors): max corner difference {worst:.3g} "
          f"({where[0]}/{where[1]})")
    return 0 if same3 == same64 == len(texts) and worst <= 1e-4 else 1


if __name__ == "__main__":
    sys.exit(main())
