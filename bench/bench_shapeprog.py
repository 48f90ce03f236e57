"""ShapeAssembly executor benchmark.

Measures, on a fixed 400-program corpus sample (seed 0, proportional by category):
  * plain execution (no grad), one program per call: programs/s and median ms/program;
  * batched execution (all 400 programs in one ``execute_batch`` call, and batches of 50);
  * one differentiable forward+backward: execute -> 2,048 surface samples -> chamfer against
    2,048 target points -> backward to the program's parameters (median of repeats), with the
    time split into its parts.

Run:  python bench/bench_shapeprog.py [--repeats 3]
"""
from __future__ import annotations

import argparse
import platform
import random
import statistics
import sys
import time

import torch


def sample_ids(n: int = 400, seed: int = 0):
    from shapeprog import corpus

    rng = random.Random(seed)
    allids = {c: corpus.ids(c, "all") for c in corpus.CATEGORIES}
    total = sum(len(v) for v in allids.values())
    out = []
    for c in corpus.CATEGORIES:
        k = round(n * len(allids[c]) / total)
        out += [(c, i) for i in rng.sample(allids[c], k)]
    return out[:n]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3, help="repeats of the single-call pass (best is kept)")
    ap.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: torch's)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)

    from shapeprog import corpus, execute, execute_batch, parse
    from shapeprog.execute import program_parameters
    from shapeprog.metrics import chamfer
    from shapeprog.sampling import sample_surface

    ids = sample_ids()
    progs = [parse(corpus.read(c, i), f"{c}/{i}.txt") for c, i in ids]
    print(f"command: python {' '.join(sys.argv)}")
    print(f"machine: {platform.processor() or platform.machine()}, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}, programs {len(progs)}")

    with torch.no_grad():
        for p in progs[:20]:
            execute(p)  # warm-up
        best_total, best_times = None, None
        for _ in range(args.repeats):
            times = []
            t0 = time.perf_counter()
            for p in progs:
                t = time.perf_counter()
                execute(p)
                times.append(time.perf_counter() - t)
            total = time.perf_counter() - t0
            if best_total is None or total < best_total:
                best_total, best_times = total, times
        med = statistics.median(best_times) * 1e3
        print(f"single calls : {len(progs) / best_total:8.1f} programs/s, median {med:.2f} ms/program "
              f"(reference: 78 programs/s, 9.9 ms)")
        for bs in (50, 400):
            best = None
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                for k in range(0, len(progs), bs):
                    execute_batch(progs[k:k + bs])
                dt = time.perf_counter() - t0
                best = dt if best is None else min(best, dt)
            print(f"batch of {bs:3d} : {len(progs) / best:8.1f} programs/s ({best * 1e3 / len(progs):.2f} ms/program)")

    # differentiable forward + backward on a fixed program
    p = parse(corpus.read("table", 33075))
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        target, _ = sample_surface(execute(p).corners * 1.05, 2048, generator=g)
    parts = {"execute": [], "sample": [], "chamfer": [], "backward": [], "total": []}
    for rep in range(25):
        x = program_parameters(p).requires_grad_(True)
        t0 = time.perf_counter()
        s = execute(p, params=x)
        t1 = time.perf_counter()
        pts, _ = sample_surface(s.corners, 2048, generator=g)
        t2 = time.perf_counter()
        loss = chamfer(pts, target)
        t3 = time.perf_counter()
        loss.backward()
        t4 = time.perf_counter()
        if rep >= 5:
            for k, dt in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t4 - t0)):
                parts[k].append(dt * 1e3)
    m = {k: statistics.median(v) for k, v in parts.items()}
    print(f"forward+backward (table/33075, 2048 samples, chamfer vs 2048): median {m['total']:.1f} ms "
          f"[execute {m['execute']:.1f}, sample {m['sample']:.1f}, chamfer {m['chamfer']:.1f}, "
          f"backward {m['backward']:.1f}] (reference: 32.9 ms)")


if __name__ == "__main__":
    main()
