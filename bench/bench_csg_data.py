"""Programs per second of the synthetic CSG data generator (:func:`csgnet.data.generate_dataset`).

Times whole dataset generation (sampling, rule checks, de-duplication, file writing, worker start-up)
for one length at a time, and prints the accepted primitive-type and operator frequencies. First it
prints the share of whole-program candidates (uniform tree shape, the default type and operator
weights) that pass the rules, i.e. the acceptance rate of plain rejection sampling (``retries=0``),
which the bottom-up sampler avoids.

Usage::

    python bench/bench_csg_data.py [--workers 2] [--n2d 4000] [--n3d 400] [--candidates 20000]

``--n2d 0`` / ``--n3d 0`` skip a dimension, ``--candidates 0`` the acceptance rate.
"""

from __future__ import annotations

import argparse
import collections
import os
import platform
import sys
import tempfile
import time

import numpy as np

from csgnet.data import TABLE2, generate_dataset, load_dataset
from csgnet.primitives import primitives
from csgnet.synth import Rules, _draw_candidates, check_programs


def _scale_for(dim: int, length: int, n: int) -> float:
    return n / sum(TABLE2[dim][length])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--n2d", type=int, default=4000, help="2D length-13 programs to generate")
    ap.add_argument("--n3d", type=int, default=400, help="3D length-7 programs to generate")
    ap.add_argument("--candidates", type=int, default=20000,
                    help="2D length-13 candidates for the rejection-sampling acceptance rate")
    args = ap.parse_args()
    print("command: python " + " ".join([sys.argv[0]] + sys.argv[1:]))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}")
    if args.candidates > 0:
        rules = Rules().resolved(2)
        cand = _draw_candidates(2, 13, rules, args.candidates, np.random.default_rng(0))
        ok = int(check_programs(cand, 2, rules).sum())
        print(f"rejection sampling, 2D length 13: {ok} of {args.candidates} candidates pass the rules "
              f"({100 * ok / args.candidates:.2f}%)")
    for dim, length, n in ((2, 13, args.n2d), (3, 7, args.n3d)):
        if n <= 0:
            continue
        with tempfile.TemporaryDirectory() as out:
            t = time.perf_counter()
            counts = generate_dataset(out, dim=dim, scale=_scale_for(dim, length, n), seed=0,
                                      workers=args.workers, lengths=[length], progress=False)
            dt = time.perf_counter() - t
            total = sum(counts[length].values())
            freq = collections.Counter()
            for split in ("train", "val", "test"):
                for p in load_dataset(out, dim, split)[length]:
                    for tok in p.tokens:
                        freq[getattr(tok, "kind", None) or tok.op] += 1
        n_prims = sum(v for k, v in freq.items() if k not in "+*-")
        n_ops = sum(freq[o] for o in "+*-")
        types = ", ".join(f"{p.kind} {freq[p.kind] / n_prims:.2f}" for p in primitives(dim))
        ops = ", ".join(f"{o} {freq[o] / n_ops:.2f}" for o in "+*-")
        print(f"{dim}D length {length}: {total} programs in {dt:.1f} s with workers={args.workers}: "
              f"{total / dt:.0f} programs/s (types: {types}; operators: {ops})")


if __name__ == "__main__":
    main()
