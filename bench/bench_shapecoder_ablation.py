"""ShapeCoder ablations (the paper's Table 4 rows that this implementation can run) on the first ``--shapes``
discovery shapes of a category: the full method, no abstractions (the wake alone: the naive programs
refactored with the semantic rewrites), and no semantic rewrites (only the abstraction rules); each with
the same rounds, proposals and seed. Prints F, |L|, Num Struct, Num Param and the wall seconds per row.

Usage::

    python bench/bench_shapecoder_ablation.py [--category chair] [--shapes 60] [--rounds 1] [--proposals 300]
        [--abstractions 8] [--workers 2]
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import os
import platform
import sys
import time

from shapeprog.coder import data
from shapeprog.coder.discover import discover
from shapeprog.coder.config import Config
from shapeprog.coder.objective import naive_summary

PAPER = {"chair": {"full": 63.6, "no abstraction": 104.9, "no semantic rewrites": 75.2}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", default="chair", choices=data.CATEGORIES)
    ap.add_argument("--shapes", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--proposals", type=int, default=300)
    ap.add_argument("--abstractions", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"load {os.getloadavg()[0]:.1f}")
    shapes = data.load(args.category)[:args.shapes]
    base = Config(rounds=args.rounds, n_proposals=args.proposals, n_abstractions=args.abstractions)
    rows = [("full", base), ("no abstraction", Config(rounds=0)),
            ("no semantic rewrites", Config(rounds=args.rounds, n_proposals=args.proposals,
                                            n_abstractions=args.abstractions, semantic_rewrites=False))]
    naive = naive_summary(s.prims for s in shapes)
    print(f"\n| row | F | \\|L\\| | Num Struct | Num Param | wall s | paper F (400 shapes, 4 rounds) |\n"
          f"|---|---|---|---|---|---|---|\n| naive programs | {naive.F:.1f} | 6 | {naive.num_struct:.1f} | "
          f"{naive.num_param:.1f} | - | - |")
    with cf.ProcessPoolExecutor(args.workers) as ex:
        for name, cfg in rows:
            t0 = time.time()
            s = discover(shapes, cfg, executor=ex, log=None).summary()
            paper = PAPER.get(args.category, {}).get(name, "-")
            print(f"| {name} | {s.F:.1f} | {s.library_size} | {s.num_struct:.1f} | {s.num_param:.1f} | "
                  f"{time.time() - t0:.0f} | {paper} |", flush=True)


if __name__ == "__main__":
    main()
