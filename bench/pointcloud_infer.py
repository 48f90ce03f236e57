"""Seconds per cloud of ``shapeprog.pointcloud.infer`` on the CPU, with and without the fitting polish.

Inputs are 2,048-point clouds of corpus test shapes (the corpus val split) with Gaussian noise (sigma 0.005,
canonical units), scaled by 3.7 and moved, as a user's cloud would be. For each of ``--shapes`` shapes the
script times :func:`~shapeprog.pointcloud.infer` three ways after one warm-up call: ``decode`` (encode +
decode + align, no metrics: what a user waits for), ``+ metrics`` (chamfer, F-score, rooted, no stability
test), ``--fit`` (``fit_steps`` Adam steps, metrics before and after, no stability test), ``--search``
(the latent search of :mod:`shapeprog.pointcloud.search`, no metrics) and ``--search --fit``. It prints the
median and the maximum wall seconds and the process's CPU seconds of each, and the command line.

Usage::

    OMP_NUM_THREADS=1 python bench/pointcloud_infer.py [--shapes 10] [--weights FILE] [--fit-steps 150]
"""
from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time

import numpy as np
import torch

from shapeprog import corpus
from shapeprog.pointcloud.data import corpus_cloud
from shapeprog.pointcloud.infer import FIT_STEPS, infer, load_model, load_pretrained


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", type=int, default=10)
    ap.add_argument("--weights", help="weights file (default: the shipped chair model)")
    ap.add_argument("--fit-steps", type=int, default=FIT_STEPS)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    model = load_model(args.weights, "chair") if args.weights else load_pretrained("chair")
    rng = np.random.default_rng(0)
    clouds = []
    for i in corpus.ids("chair", "val")[: args.shapes]:
        c = corpus_cloud("chair", i, 2048).astype(np.float64)
        clouds.append((c + rng.normal(0, 0.005, c.shape)) * 3.7 + np.array([1.0, -2.0, 0.5]))
    infer(clouds[0], model=model, physics=False, method="decode")  # warm-up
    modes = {"decode": dict(method="decode", physics=False),
             "+ metrics": dict(method="decode", physics=True, stability=False),
             "--fit": dict(method="decode", fit=True, fit_steps=args.fit_steps, physics=True, stability=False),
             "--search": dict(search=True, physics=False),
             "--search --fit": dict(search=True, fit=True, fit_steps=args.fit_steps, physics=True, stability=False)}
    print(f"# {platform.processor() or platform.machine()}, torch {torch.__version__}, {args.threads} thread(s), "
          f"{len(clouds)} chairs of 2048 points")
    for name, kw in modes.items():
        wall, cpu = [], []
        for x in clouds:
            t0, c0 = time.perf_counter(), time.process_time()
            infer(x, model=model, **kw)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        print(f"{name:15s} wall median {statistics.median(wall):.3f} s, max {max(wall):.3f} s; "
              f"CPU median {statistics.median(cpu):.3f} s")
    print("command: " + " ".join([sys.executable.split("/")[-1]] + sys.argv))
    return 0


if __name__ == "__main__":
    sys.exit(main())
