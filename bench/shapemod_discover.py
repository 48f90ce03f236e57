"""ShapeMOD discovery speed: best-program searches per second, serial against a process pool, and one
discovery round serial against the pool (the same result either way).

Prints the command, the machine, the searches per second (sub-programs, all their current orderings,
beam search) of ``--items`` random chair sub-programs under a library (default: the shipped chair
library) in this process and through ``ProcessPoolExecutor(--workers)``, and the wall time of one
discovery round (``--limit`` shapes, ``--steps`` proposal steps) both ways.

Usage::

    python bench/shapemod_discover.py [--items 1000] [--workers 2] [--limit 300] [--steps 200]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from shapeprog.macros import load_library
from shapeprog.macros.api import collection
from shapeprog.macros.discover import discover
from shapeprog.macros.state import evaluate
from shapeprog.macros.config import load_config


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", default="chair")
    ap.add_argument("--items", type=int, default=1000, help="sub-programs searched")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--limit", type=int, default=300, help="shapes of the discovery round")
    ap.add_argument("--steps", type=int, default=200, help="proposal steps of the discovery round")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    nodes, ids = collection(args.category, "all", None, args.seed)
    rng = np.random.default_rng(args.seed)
    pick = sorted(rng.choice(len(nodes.keys), size=min(args.items, len(nodes.keys)), replace=False).tolist())
    items = [nodes.lines[i] for i in pick]
    lib = load_library(args.category)
    active = [m.name for m in lib.macros]
    cfg = load_config()
    t = time.perf_counter()
    f1, _ = evaluate(lib, active, items, cfg)
    serial = time.perf_counter() - t
    with ProcessPoolExecutor(args.workers) as pool:
        evaluate(lib, active, items[:10], cfg, pool)  # start the workers
        t = time.perf_counter()
        f2, _ = evaluate(lib, active, items, cfg, pool)
        par = time.perf_counter() - t
    assert f1 == f2
    n_orders = sum(len(x) for x in items)
    print(f"best-program search, {len(items)} sub-programs ({n_orders} orderings), |L| = {len(lib)}: "
          f"serial {len(items) / serial:.1f} /s ({serial:.2f} s); {args.workers} processes "
          f"{len(items) / par:.1f} /s ({par:.2f} s); speed-up {serial / par:.2f}x; mean f {f1:.3f}")
    small, _ = collection(args.category, "all", args.limit, args.seed)
    cfg = load_config(None, num_rounds=1, cand_cluster_num=args.steps, abs_shape_num=500)
    t = time.perf_counter()
    a = discover(small, cfg, seed=args.seed, log=None)
    serial = time.perf_counter() - t
    with ProcessPoolExecutor(args.workers) as pool:
        t = time.perf_counter()
        b = discover(small, cfg, seed=args.seed, executor=pool, log=None)
        par = time.perf_counter() - t
    same = a.history[0]["f_after"] == b.history[0]["f_after"] and [m.name for m in a.macros] == [
        m.name for m in b.macros]
    h = a.history[0]
    print(f"one discovery round, {args.limit} shapes ({len(small.keys)} sub-programs), {args.steps} proposal steps: "
          f"serial {serial:.1f} s (proposal {h['seconds_proposal']} s, integration {h['seconds_integration']} s); "
          f"{args.workers} processes {par:.1f} s; speed-up {serial / par:.2f}x; same result: {same}; "
          f"f {h['f_before']:.2f} -> {h['f_after']:.2f}")


if __name__ == "__main__":
    main()
