"""Post hoc inference with the shipped network under two search budgets, on a range of held-out shapes.

For held-out shapes ``--start`` to ``--stop`` of a category (lines 400 onward of ``PN_<category>.txt``; the
first 100 are Table 3's validation-PHI row), post hoc inference with the shipped library and recognition
network (:func:`shapeprog.coder.tables.phi`, as ``table2-coder --phi-network``) runs once with the wake's
search budget (1 s and at most 16 batches of 64 samples per step, the paper's) and once with ``--seconds`` /
``--batches`` (ours). Prints, per budget, F (mean program cost plus the library's cost, Table 3's F), the
shapes, the abstractions used, CPU seconds per shape and wall seconds, then the command line. Shapes 100-199
were never used to choose a budget: they check the larger budget's Table 3 figure on shapes kept apart.

Usage::

    python bench/shapecoder_phi_budget.py --category chair --start 100 --stop 200 --seconds 4 --batches 64 --workers 2
"""
from __future__ import annotations

import argparse
import multiprocessing
import platform
import sys
from concurrent.futures import ProcessPoolExecutor

from shapeprog.coder import data, tables
from shapeprog.coder.infer import load_library, load_network


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--category", default="chair", choices=("chair", "table", "storage"))
    ap.add_argument("--start", type=int, default=100, help="first held-out shape (0-based)")
    ap.add_argument("--stop", type=int, default=200, help="one past the last held-out shape")
    ap.add_argument("--seconds", type=float, default=4.0, help="the larger budget: seconds per search step")
    ap.add_argument("--batches", type=int, default=64, help="the larger budget: batches of 64 per step at most")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    lib, net = load_library(args.category), load_network(args.category)
    recs = data.load(args.category, "heldout")[args.start:args.stop]
    if not recs:
        raise SystemExit(f"error: no held-out {args.category} shapes in [{args.start}, {args.stop})")
    print(f"# {platform.processor() or platform.machine()}, {args.workers} worker(s), held-out {args.category} "
          f"shapes {args.start}-{args.start + len(recs) - 1}")
    pool = (ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("forkserver"))
            if args.workers > 1 else None)
    try:
        for name, kw in (("wake budget (1 s / 16 batches, the paper's)", {}),
                         (f"{args.seconds:g} s / {args.batches} batches (ours)",
                          {"search_seconds": args.seconds, "search_batches": args.batches})):
            r = tables.phi(f"held-out {args.start}-{args.stop}", recs, lib, executor=pool, network=net, **kw)
            print(f"{name}: F {r.F:.2f}, shapes {r.shapes} ({r.skipped} over the primitive limit left out), "
                  f"abstractions used {r.used}, CPU s / shape {r.cpu:.2f}, wall {r.wall:.0f} s", flush=True)
    finally:
        if pool is not None:
            pool.shutdown()
    print("# command: python bench/shapecoder_phi_budget.py " + " ".join(sys.argv[1:] if argv is None else argv))
    return 0


if __name__ == "__main__":
    sys.exit(main())
