"""ShapeAssembly executor benchmark: plain-execution throughput and one differentiable step.

Measured on a fixed 400-program corpus sample (seed 0, proportional by category), parsing excluded:

  * plain execution (float32, no grad), four ways:
      - one program per ``execute`` call (compiling the program is part of every call);
      - one program per call of a prebuilt ``ExecutionPlan`` (compiled beforehand, not timed);
      - ``execute_batch`` in batches of 50, and all 400 programs in one call (compiling included);
  * one differentiable forward + backward on table/33075: execute -> 2,048 area-weighted surface
    samples -> chamfer against 2,048 target points -> backward to every continuous parameter,
    timed per part (median of repeats):
      - with the program's plan built once (what every step of ``shapeprog.fit`` runs);
      - with ``execute`` per step (compiling included);
      - in-run baseline: the plan path with the brute-force nearest-neighbour search
        (``chamfer(..., method="brute")``, every distance in torch, as before the k-d tree).

Every figure is given as wall time and as CPU time of this process (``time.process_time``); on a
machine shared with other jobs the CPU time is the steadier of the two. The load average is printed
before and after. Reference figures (from the specification, a 2-core machine like this one):
78 programs/s (median 9.9 ms per program) and 32.9 ms per forward + backward.

Run:  python bench/bench_shapeprog.py [--threads 1] [--repeats 3] [--device cpu|cuda]
"""
from __future__ import annotations

import argparse
import os
import platform
import random
import statistics
import sys
import time

import torch

from shapeprog import corpus, execute, execute_batch, parse
from shapeprog.execute import ExecutionPlan, program_parameters
from shapeprog.metrics import chamfer
from shapeprog.sampling import sample_surface

REF_PROGRAMS_PER_S = 78.0
REF_MEDIAN_MS = 9.9
REF_STEP_MS = 32.9


def sample_ids(n: int = 400, seed: int = 0):
    rng = random.Random(seed)
    allids = {c: corpus.ids(c, "all") for c in corpus.CATEGORIES}
    total = sum(len(v) for v in allids.values())
    out = []
    for c in corpus.CATEGORIES:
        k = round(n * len(allids[c]) / total)
        out += [(c, i) for i in rng.sample(allids[c], k)]
    return out[:n]


class Clock:
    """Wall and CPU seconds of a block; synchronises the GPU when one is used."""

    def __init__(self, device: torch.device):
        self.cuda = device.type == "cuda"

    def now(self):
        if self.cuda:
            torch.cuda.synchronize()
        return time.perf_counter(), time.process_time()


def load() -> str:
    try:
        return "load average " + " ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover - not on every platform
        return "load average unknown"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3, help="repeats of each throughput pass (best is kept)")
    ap.add_argument("--steps", type=int, default=40, help="timed forward+backward steps per variant")
    ap.add_argument("--threads", type=int, default=1, help="torch.set_num_threads (0: torch's default)")
    ap.add_argument("--device", default="cpu", help="cpu or cuda")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)

    clock = Clock(device)
    ids = sample_ids()
    progs = [parse(corpus.read(c, i), f"{c}/{i}.txt") for c, i in ids]
    print(f"command: python {' '.join(sys.argv)}")
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}, device {device}, programs {len(progs)}, {load()}")

    def best_of(fn):
        """Best (wall, cpu) seconds of ``fn`` over the repeats."""
        best = None
        for _ in range(args.repeats):
            w0, c0 = clock.now()
            fn()
            w1, c1 = clock.now()
            if best is None or w1 - w0 < best[0]:
                best = (w1 - w0, c1 - c0)
        return best

    def report(name, secs, n=len(progs), extra=""):
        wall, cpu = secs
        print(f"  {name:38s} wall {n / wall:8.1f} programs/s ({wall * 1e3 / n:5.2f} ms/program, "
              f"{n / wall / REF_PROGRAMS_PER_S:5.1f}x ref) | cpu {n / cpu:8.1f} programs/s "
              f"({n / cpu / REF_PROGRAMS_PER_S:5.1f}x ref){extra}")

    print(f"plain execution, float32, no grad (reference: {REF_PROGRAMS_PER_S:g} programs/s, "
          f"median {REF_MEDIAN_MS} ms/program)")
    with torch.no_grad():
        for p in progs[:20]:
            execute(p, device=device)  # warm-up
        per_call = []

        def singles():
            per_call.clear()
            for p in progs:
                t = time.perf_counter()
                execute(p, device=device)
                per_call.append(time.perf_counter() - t)

        secs = best_of(singles)
        med = statistics.median(per_call) * 1e3
        report("one program per execute() call", secs,
               extra=f"; median {med:.2f} ms/program ({REF_MEDIAN_MS / med:.1f}x ref)")
        plans = [ExecutionPlan([p], device=device) for p in progs]
        report("one program per prebuilt plan.run()", best_of(lambda: [pl.run() for pl in plans]))
        for bs in (50, 400):
            report(f"execute_batch, batches of {bs}",
                   best_of(lambda: [execute_batch(progs[k:k + bs], device=device) for k in range(0, len(progs), bs)]))

    # one differentiable step on a fixed program
    p = parse(corpus.read("table", 33075))
    g = torch.Generator(device=device).manual_seed(0)
    with torch.no_grad():
        target, _ = sample_surface(execute(p, device=device).corners * 1.05, 2048, generator=g)
    plan = ExecutionPlan([p], device=device)
    variants = {
        "plan built once (fit)": (lambda x: plan.run([x])[0], "auto"),
        "execute() per step": (lambda x: execute(p, device=device, params=x), "auto"),
        "baseline: brute-force chamfer": (lambda x: plan.run([x])[0], "brute"),
    }
    print(f"forward + backward, table/33075, 2,048 samples, chamfer vs 2,048 points, median of {args.steps} "
          f"(reference: {REF_STEP_MS} ms)")
    for name, (run, method) in variants.items():
        parts = {k: ([], []) for k in ("execute", "sample", "chamfer", "backward", "total")}
        for rep in range(args.steps + 5):
            x = program_parameters(p, device=device).requires_grad_(True)
            t0 = clock.now()
            s = run(x)
            t1 = clock.now()
            pts, _ = sample_surface(s.corners, 2048, generator=g)
            t2 = clock.now()
            loss = chamfer(pts, target, method=method)
            t3 = clock.now()
            loss.backward()
            t4 = clock.now()
            if rep >= 5:
                for k, (a, b) in zip(parts, ((t0, t1), (t1, t2), (t2, t3), (t3, t4), (t0, t4))):
                    parts[k][0].append((b[0] - a[0]) * 1e3)
                    parts[k][1].append((b[1] - a[1]) * 1e3)
        for i, kind in enumerate(("wall", "cpu")):
            m = {k: statistics.median(v[i]) for k, v in parts.items()}
            print(f"  {name:30s} {kind:4s} {m['total']:6.1f} ms ({REF_STEP_MS / m['total']:4.1f}x ref) = "
                  f"execute {m['execute']:.1f} + sample {m['sample']:.1f} + chamfer {m['chamfer']:.1f} "
                  f"+ backward {m['backward']:.1f}")
    print(f"after: {load()}")


if __name__ == "__main__":
    main()
