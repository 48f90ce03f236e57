"""The generation metrics' ground-truth row: the corpus val split of one category measured against its train split.

Builds the category's references (train and val executed and sampled, the train features fitted), runs
every metric of :func:`shapeprog.vae.gentable.evaluate_generation` on the val programs (coverage excepted),
prints the markdown table beside the paper's figures and the seconds per metric. With
``--check-recall N`` it also compares the two-stage nearest-chamfer search with the exhaustive one on N
val shapes against the whole train split (recall of the exact nearest shape, and the mean distances).

Usage::

    OMP_NUM_THREADS=1 python bench/bench_genmetrics.py --category chair [--workers 2] [--fool-epochs 12]
        [--no-stability] [--check-recall 40]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import torch

from shapeprog.vae.genmetrics import nearest_chamfer
from shapeprog.vae.gentable import References, evaluate_generation, format_table, table_notes
from shapeprog.vae.pointnet import PRETRAINED_SHA256, load_classifier


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", default="chair", choices=("chair", "table", "storage"))
    ap.add_argument("--workers", type=int, default=1, help="processes for the per-shape work (1: in this process)")
    ap.add_argument("--fool-epochs", type=int, default=12)
    ap.add_argument("--fool-average-last", type=int, default=4)
    ap.add_argument("--fool-points", type=int, default=512)
    ap.add_argument("--candidates", type=int, default=16)
    ap.add_argument("--no-stability", action="store_true")
    ap.add_argument("--check-recall", type=int, default=0, help="compare with the exhaustive search on N val shapes")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    print(f"# command: {' '.join(['python'] + sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}, workers {args.workers}; load average {os.getloadavg()[0]:.1f}")
    t0, c0 = time.perf_counter(), time.process_time()
    model, _, meta = load_classifier()  # checks the file against PRETRAINED_SHA256
    pool = None
    if args.workers > 1:
        pool = ProcessPoolExecutor(max_workers=args.workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        refs = References.build(args.category, model, seed=args.seed, log=print)
        row = evaluate_generation(refs.val_programs, refs, name="ground truth: corpus val", model=model,
                                  executor=pool, stability=not args.no_stability, fool_epochs=args.fool_epochs,
                                  fool_average_last=args.fool_average_last, fool_points=args.fool_points,
                                  with_coverage=False, candidates=args.candidates, seed=args.seed, log=print)
        if args.check_recall:
            q = refs.val_chamfer[:args.check_recall]
            t = time.perf_counter()
            fast = nearest_chamfer(q, refs.train_chamfer, candidates=args.candidates, executor=pool)
            t_fast = time.perf_counter() - t
            t = time.perf_counter()
            full = nearest_chamfer(q, refs.train_chamfer, candidates=None, executor=pool)
            t_full = time.perf_counter() - t
            print(f"two-stage vs exhaustive nearest chamfer, {len(q)} val shapes x {len(refs.train_chamfer)} train: "
                  f"same nearest shape {int((fast[1] == full[1]).sum())} / {len(q)}, mean distance "
                  f"{fast[0].mean():.5f} vs {full[0].mean():.5f} (largest excess {np.max(fast[0] - full[0]):.2g}); "
                  f"{t_fast:.1f} s vs {t_full:.1f} s")
    finally:
        if pool is not None:
            pool.shutdown()
    notes = table_notes(meta, PRETRAINED_SHA256, args.fool_epochs, args.fool_average_last, args.fool_points,
                   len(refs.train_chamfer[0]), args.candidates, not args.no_stability)
    print()
    print(format_table([row], args.category, notes))
    if row.fool_detail is not None:
        f = row.fool_detail
        print(f"% fool detail: generated (val) as real {f.generated_as_real:.2f}, real (train) as generated "
              f"{f.real_as_generated:.2f}, per averaged epoch {[round(x, 2) for x in f.per_epoch]}, "
              f"{f.train} + {f.train} training and {f.held_out} + {f.held_out} held-out shapes")
    print(f"seconds per metric: {row.seconds}")
    print(f"total: {time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU in the main process; "
          f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
