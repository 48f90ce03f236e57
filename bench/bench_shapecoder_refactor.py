"""Refactor time per program: the e-graph call (build, values, iterations, extraction) on the naive
programs of discovery shapes with 5, 8 and 9 cuboids (the specification measured 0.065 s / 0.55 s per whole
call for 5 / 8 cuboids, with its own smaller rule set), under the default limits (5 iterations, 10,000
e-nodes, 5 s) and, with ``--saturate``, with the limits lifted (50 iterations, 300,000 e-nodes, 60 s).

Prints per size: programs, median and max seconds per call, median e-nodes at the end, the stop reasons,
and the mean cost before and after.

Usage::

    python bench/bench_shapecoder_refactor.py [--category chair] [--per-size 10] [--saturate]
"""
from __future__ import annotations

import argparse
import collections
import os
import platform
import statistics
import sys
import time

from shapeprog.coder import data
from shapeprog.coder.objective import naive_program
from shapeprog.coder.refactor import refactor


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", default="chair", choices=data.CATEGORIES)
    ap.add_argument("--per-size", type=int, default=10)
    ap.add_argument("--sizes", default="5,8,9")
    ap.add_argument("--saturate", action="store_true")
    args = ap.parse_args(argv)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"load {os.getloadavg()[0]:.1f}")
    shapes = data.load(args.category)
    limits = dict(iterations=50, max_nodes=300_000, time_limit=60.0) if args.saturate else {}
    refactor(*naive_program(shapes[0].prims)[:1], env=naive_program(shapes[0].prims)[1])  # warm-up (import)
    print(f"{'cuboids':>7} {'n':>3} {'median s':>9} {'max s':>7} {'CPU s':>7} {'e-nodes':>8} {'before':>7} {'after':>7}  stops")
    for size in (int(s) for s in args.sizes.split(",")):
        picked = [s for s in shapes if len(s.prims) == size][:args.per_size]
        secs, cpus, nodes, before, after, stops = [], [], [], [], [], collections.Counter()
        for s in picked:
            expr, env = naive_program(s.prims)
            c0 = time.process_time()
            r = refactor(expr, env=env, **limits)
            cpus.append(time.process_time() - c0)
            secs.append(r.seconds)
            nodes.append(r.nodes)
            before.append(r.input_cost)
            after.append(r.cost)
            stops[r.stop] += 1
        if not picked:
            continue
        print(f"{size:>7} {len(picked):>3} {statistics.median(secs):>9.3f} {max(secs):>7.3f} "
              f"{statistics.median(cpus):>7.3f} {int(statistics.median(nodes)):>8} {statistics.mean(before):>7.1f} "
              f"{statistics.mean(after):>7.1f}  {dict(stops)}")


if __name__ == "__main__":
    main()
