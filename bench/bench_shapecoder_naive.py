"""The naive cost of the vendored ShapeCoder data: the "Input Prims" row of the ShapeCoder paper's Table 2.

For each category, loads the shapes of the split (parse, execute, 2-decimal re-oriented primitives) and
prints the mean naive cost F, Num Struct (shape-function tokens) and Num Param (free-float and
categorical tokens) per shape, beside the paper's F (discovery split: the first 400 shapes), with the
relative deviation and the seconds spent loading.

Usage::

    python bench/bench_shapecoder_naive.py [--split discovery|heldout|all]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time

from shapeprog.coder import data
from shapeprog.coder.objective import naive_summary

PAPER = {"chair": (146.0, 29, 61), "table": (125.0, 25, 51), "storage": (154.0, 30, 62)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="discovery", choices=data.SPLITS)
    args = ap.parse_args(argv)

    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}")
    print(f"{'category':<9} {'shapes':>6} {'F':>8} {'Struct':>7} {'Param':>7} | {'paper F':>7} {'Struct':>6} "
          f"{'Param':>5} {'dev F':>7} | load s")
    for cat in data.CATEGORIES:
        t0 = time.perf_counter()
        shapes = data.load(cat, args.split, strict=True)
        dt = time.perf_counter() - t0
        row = naive_summary(s.prims for s in shapes)
        pf, ps, pp = PAPER[cat]
        dev = f"{(row.F - pf) / pf:+.2%}" if args.split == "discovery" else "-"
        print(f"{cat:<9} {row.shapes:>6} {row.F:>8.2f} {row.num_struct:>7.2f} {row.num_param:>7.2f} | {pf:>7.1f} "
              f"{ps:>6} {pp:>5} {dev:>7} | {dt:.2f}")


if __name__ == "__main__":
    main()
