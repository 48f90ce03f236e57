"""Speed of the 2D training jitter: the batched gather (:func:`csgnet.train.augment.jitter`) against the
per-image ``scipy.ndimage.affine_transform`` loop it replaced (:func:`~csgnet.train.augment.jitter_reference`),
on the same images and draws, in one run.

    python bench/bench_jitter.py --threads 1
    python bench/bench_jitter.py --device cuda --batch 300

Both give the same pixels (``tests/csgnet/train/test_augment.py``); the figures are milliseconds per batch
(median of ``--repeats``) and their ratio.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np
import torch

from csgnet.train.augment import jitter, jitter_reference


def _time(fn, images, repeats: int, device: str) -> float:
    """Median seconds of ``fn(images, rng)`` over ``repeats`` calls after one warm-up."""
    times = []
    for i in range(repeats + 1):
        rng = np.random.default_rng(i)
        if device == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        fn(images, rng)
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return float(np.median(times[1:]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--batch", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    images = torch.from_numpy(np.random.default_rng(0).random((args.batch, 64, 64)) < 0.5).to(args.device)
    assert torch.equal(jitter(images, np.random.default_rng(1)).cpu(),
                       torch.from_numpy(jitter_reference(images, np.random.default_rng(1))))
    old = _time(jitter_reference, images, args.repeats, args.device)
    new = _time(jitter, images, args.repeats, args.device)
    print(f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}, device {args.device}, load average {os.getloadavg()[0]:.2f}")
    print(f"jitter of {args.batch} images: scipy per image {1000 * old:.2f} ms, batched gather {1000 * new:.2f} ms, "
          f"{old / new:.1f}x")
    print("command: python " + " ".join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
