"""Programs per second of the synthetic CSG data generator (:func:`csgnet.data.generate_dataset`).

Times whole dataset generation (sampling, rule checks, de-duplication, file writing, worker start-up)
for one length at a time, and prints the accepted primitive-type and operator frequencies.

Usage::

    python bench/bench_csg_data.py [--workers 2] [--n2d 4000] [--n3d 400]
"""

from __future__ import annotations

import argparse
import collections
import os
import platform
import sys
import tempfile
import time

from csgnet.data import TABLE2, generate_dataset, load_dataset


def _scale_for(dim: int, length: int, n: int) -> float:
    return n / sum(TABLE2[dim][length])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--n2d", type=int, default=4000, help="2D length-13 programs to generate")
    ap.add_argument("--n3d", type=int, default=400, help="3D length-7 programs to generate")
    args = ap.parse_args()
    print("command: python " + " ".join([sys.argv[0]] + sys.argv[1:]))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}")
    for dim, length, n in ((2, 13, args.n2d), (3, 7, args.n3d)):
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
        types = ", ".join(f"{k} {freq[k] / n_prims:.2f}" for k in ("cst" if dim == 2 else "puy"))
        ops = ", ".join(f"{o} {freq[o] / n_ops:.2f}" for o in "+*-")
        print(f"{dim}D length {length}: {total} programs in {dt:.1f} s with workers={args.workers}: "
              f"{total / dt:.0f} programs/s (types: {types}; operators: {ops})")


if __name__ == "__main__":
    main()
