"""ShapeCoder wake ablation: the refactor-only wake against the wake with dreams and a recognition network, on
the first ``--shapes`` discovery shapes of a category, the same rounds, proposals and seed. Prints F, |L|, Num
Struct, Num Param and the wall seconds per row, the network's training figures per round and which candidate
won each shape's wake (the network's program, the store's replacements / rebuild, or a refactor-only one).

Usage::

    python bench/bench_shapecoder_wake.py [--category chair] [--shapes 40] [--rounds 1] [--proposals 300]
        [--abstractions 8] [--workers 2] [--dreams 400] [--train-seconds 90] [--wake-seconds 1.0]
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import multiprocessing
import os
import platform
import sys
import time

from shapeprog.coder import data
from shapeprog.coder.discover import discover
from shapeprog.coder.config import Config
from shapeprog.coder.objective import naive_summary


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", default="chair", choices=data.CATEGORIES)
    ap.add_argument("--shapes", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--proposals", type=int, default=300)
    ap.add_argument("--abstractions", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dreams", type=int, default=400, help="valid dreams per function")
    ap.add_argument("--train-seconds", type=float, default=90.0, help="training budget per round")
    ap.add_argument("--train-lr", type=float, default=1e-3)
    ap.add_argument("--dropout", type=float, default=0.1)
    ap.add_argument("--wake-seconds", type=float, default=1.0)
    ap.add_argument("--only", choices=("refactor", "network"), help="run one row only")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"torch {torch.__version__}, CUDA {torch.cuda.is_available()}, load {os.getloadavg()[0]:.1f}")
    shapes = data.load(args.category)[:args.shapes]
    common = dict(rounds=args.rounds, n_proposals=args.proposals, n_abstractions=args.abstractions)
    rows = [("refactor-only wake", Config(**common)),
            ("network wake", Config(**common, wake="network", n_dreams=args.dreams, train_seconds=args.train_seconds,
                                    train_lr=args.train_lr, dropout=args.dropout, wake_seconds=args.wake_seconds,
                                    device="cpu"))]
    if args.only:
        rows = [r for r in rows if r[1].wake == args.only]
    naive = naive_summary(s.prims for s in shapes)
    table = [f"| naive programs | {naive.F:.1f} | 6 | {naive.num_struct:.1f} | {naive.num_param:.1f} | - |"]
    for name, cfg in rows:
        notes = []

        def log(line, notes=notes):
            if line.startswith(("network:", "round")) and ("wake" in line or line.startswith("network")):
                notes.append(line)
                print("#", line, flush=True)

        ctx = multiprocessing.get_context("forkserver") if cfg.wake == "network" else None
        t0 = time.time()
        with cf.ProcessPoolExecutor(args.workers, mp_context=ctx) as ex:
            r = discover(shapes, cfg, executor=ex, log=log)
        s = r.summary()
        print("# phases: " + "; ".join(f"round {h['round']} {h['phase']} F={h['F']:.1f} at {h['seconds']:.0f} s"
                                       for h in r.log), flush=True)
        table.append(f"| {name} | {s.F:.1f} | {s.library_size} | {s.num_struct:.1f} | {s.num_param:.1f} | "
                     f"{time.time() - t0:.0f} |")
        print(table[-1], flush=True)
    print("\n| row | F | \\|L\\| | Num Struct | Num Param | wall s |\n|---|---|---|---|---|---|")
    print("\n".join(table))


if __name__ == "__main__":
    main()
