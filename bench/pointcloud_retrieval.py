"""The nearest-training-shape index: build time and memory, time per query, and how often the two-stage search
finds the exact nearest shape (against the exhaustive search) for several lattices and candidate counts.

Queries are test-split clouds of a make-clouds cache (the corpus val split, never indexed), ``--points`` points
each, in the canonical frame. The exhaustive search (every reference measured exactly) runs on the first
``--exhaustive`` queries through a process pool of ``--workers``; every lattice x candidates cell then reports
how many of those queries found the exact nearest shape and the mean excess distance of the others.

Usage::

    python -m shapeprog pointcloud make-clouds --category chair --out clouds
    python bench/pointcloud_retrieval.py --clouds clouds --category chair --queries 100 --exhaustive 8 --workers 2
"""
from __future__ import annotations

import argparse
import datetime
import multiprocessing
import os
import platform
import shlex
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import torch

from shapeprog.pointcloud.dataset import CloudDataset
from shapeprog.pointcloud.retrieval import INDEX_CANDIDATES, INDEX_GRID, RetrievalIndex


def _cpu() -> float:
    return time.process_time()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clouds", required=True, help="a make-clouds folder")
    ap.add_argument("--category", default="chair", choices=("chair", "table", "storage"))
    ap.add_argument("--points", type=int, default=2048, help="points per query cloud")
    ap.add_argument("--queries", type=int, default=100, help="queries timed with the default settings")
    ap.add_argument("--exhaustive", type=int, default=8, help="queries also searched exhaustively (slow)")
    ap.add_argument("--lattices", type=int, nargs="+", default=[8, 12, 16, 24])
    ap.add_argument("--candidates", type=int, nargs="+", default=[1, 4, 8, 16, 32])
    ap.add_argument("--workers", type=int, default=2, help="processes for the exhaustive search")
    args = ap.parse_args(argv)
    print(f"# command: python bench/pointcloud_retrieval.py {shlex.join(sys.argv[1:] if argv is None else argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"{torch.get_num_threads()} thread(s), load {os.getloadavg()[0]:.1f}, {datetime.date.today().isoformat()}")

    test = CloudDataset(args.clouds, args.category, "test", points=args.points, seed=0)
    n = min(len(test), max(args.queries, args.exhaustive))
    queries = [test[i]["points"].double() for i in range(n)]

    c0 = _cpu()
    index = RetrievalIndex.from_cache(args.clouds, args.category)
    build = _cpu() - c0
    mib = sum(t.numel() * t.element_size() for t in (index.clouds, index.splat, index.field)) / 2**20
    print(f"index: {len(index)} references, grid {INDEX_GRID}^3, built in {build:.1f} CPU s, {mib:.0f} MiB")

    q = queries[:args.queries]
    c0 = _cpu()
    index.search(q)
    per = (_cpu() - c0) / len(q)
    index.shortlist(q[0])  # the coarse stage alone, once warmed up
    coarse = []
    for x in q[:20]:
        t = _cpu()
        index.shortlist(x)
        coarse.append(_cpu() - t)
    print(f"{len(q)} queries, default settings ({INDEX_CANDIDATES} candidates): {per:.3f} CPU s per query "
          f"(the coarse stage {1000 * sum(coarse) / len(coarse):.1f} ms)")

    e = queries[:args.exhaustive]
    w0 = time.time()
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(args.workers, mp_context=ctx) as pool:
        exact = index.search(e, executor=pool, candidates=None, chunk=1)
    print(f"exhaustive search of {len(e)} queries: {time.time() - w0:.0f} s wall on {args.workers} process(es)")

    print("\n| lattice | " + " | ".join(f"{k} candidate{'s' if k > 1 else ''}" for k in args.candidates) + " |")
    print("|---|" + "---|" * len(args.candidates))
    for g in args.lattices:
        idx = index if g == INDEX_GRID else RetrievalIndex.from_cache(args.clouds, args.category, grid=g)
        cells = []
        for k in args.candidates:
            found = idx.search(e, candidates=k)
            hits = sum(a.id == b.id for a, b in zip(found, exact))
            excess = [a.distance / b.distance - 1 for a, b in zip(found, exact) if a.id != b.id and b.distance > 0]
            cells.append(f"{hits}/{len(e)}" + (f", +{100 * sum(excess) / len(excess):.1f} %" if excess else ""))
        print(f"| {g}^3{' (default)' if g == INDEX_GRID else ''} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
