"""ShapeMOD data figures: corpus programs -> sub-programs, orderings O_P, signatures; and the
orderings-execute-equal check over the whole corpus.

Prints the command, the machine, per category the programs, sub-programs, enumerated orderings (per
sub-program: mean, median, max), |O_P| before the MAX_ORDERS limit and how many sub-programs reach it,
distinct signatures, failures and cleanup counts, and the conversion time. With ``--check``, every
enumerated ordering of every sub-program (``--check first``: only the first) is executed and compared,
cuboid by cuboid, with its original block; the largest corner difference and the time are printed.

Usage::

    python bench/shapemod_data.py [--workers 2] [--check all|first] [--categories chair table storage]
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import torch

from shapeprog import corpus
from shapeprog.lang import parse
from shapeprog.macros.data import convert_corpus, convert_program, order_errors
from shapeprog.macros.subprogram import MAX_ORDERS, ORDER_TOL


def _check(category: str, ids: list[int], first: bool) -> tuple[int, int, list[tuple[float, str]]]:
    """Worker: convert some programs and execute their orderings; (sub-programs, orderings, errors)."""
    torch.set_num_threads(1)
    items = []
    for i in ids:
        prog = parse(corpus.read(category, i), f"{category}/{i}.txt")
        items += [(s, prog) for s in convert_program(prog, category, i).subprograms]
    errs = order_errors(items, max_orders=1 if first else None)
    n = sum(min(len(s.orders), 1 if first else len(s.orders)) for s, _ in items)
    return len(items), n, [(e, s.key) for e, (s, _) in zip(errs, items)]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=1, help="processes (1: convert in this process)")
    ap.add_argument("--categories", nargs="+", default=list(corpus.CATEGORIES))
    ap.add_argument("--check", choices=("none", "first", "all"), default="none")
    ap.add_argument("--chunk", type=int, default=50, help="programs per task")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"load average {os.getloadavg()[0]:.1f}")
    pool = ProcessPoolExecutor(args.workers) if args.workers > 1 else None
    try:
        data = convert_corpus(args.categories, executor=pool, chunk=args.chunk)
        print(f"conversion: {data.seconds:.1f} s with {args.workers} worker(s), MAX_ORDERS = {MAX_ORDERS}")
        for cat in args.categories:
            subs = data.by_category(cat)
            n = [len(s.orders) for s in subs]
            sigs = {o.signature for s in subs for o in s.orders}
            print(f"{cat}: {data.programs[cat]} programs, {len(subs)} sub-programs "
                  f"({len(subs) / data.programs[cat]:.2f} per program), {sum(n)} orderings "
                  f"(per sub-program mean {statistics.mean(n):.2f}, median {statistics.median(n):g}, max {max(n)}), "
                  f"|O_P| {sum(s.n_orders for s in subs)} before the limit, {sum(s.n_orders > MAX_ORDERS for s in subs)} "
                  f"at the limit, {len(sigs)} distinct signatures, "
                  f"{sum(f.category == cat for f in data.failures)} failures")
        print("cleanup: " + ", ".join(f"{k} {v}" for k, v in sorted(data.counts.items())))
        for f in data.failures:
            print(f"failure: {f}")
        if args.check != "none":
            t0 = time.perf_counter()
            tasks = [(cat, ids[k:k + args.chunk]) for cat in args.categories
                     for ids in [corpus.ids(cat, "all")] for k in range(0, len(ids), args.chunk)]
            if pool is None:
                results = [_check(c, ids, args.check == "first") for c, ids in tasks]
            else:
                futs = [pool.submit(_check, c, ids, args.check == "first") for c, ids in tasks]
                results = [f.result() for f in futs]
            dt = time.perf_counter() - t0
            nsub = sum(r[0] for r in results)
            nord = sum(r[1] for r in results)
            errs = sorted((e for r in results for e in r[2]), reverse=True)
            bad = [e for e in errs if e[0] > ORDER_TOL]
            print(f"check ({args.check}): {nord} orderings of {nsub} sub-programs executed in {dt:.1f} s; "
                  f"largest corner difference {errs[0][0]:.3g} ({errs[0][1]}); {len(bad)} sub-programs above "
                  f"{ORDER_TOL}")
            for e, k in errs[:5]:
                print(f"  {k}: {e:.3g}")
    finally:
        if pool is not None:
            pool.shutdown()


if __name__ == "__main__":
    main()
