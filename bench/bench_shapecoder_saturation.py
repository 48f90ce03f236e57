"""E-graph saturation time, conditional rewrites against the naive scheme (the paper's Table 1: conditional
0.01 / 0.04 / 2.1 s for 8 / 16 / 32 float parameters; naive 0.22 / 2.6 s / timeout).

The programs are 2D scenes of 2, 4 and 8 rectangles (8 / 16 / 32 float parameters) as naive union chains:
mirror pairs about the y axis, the first pair an instance of the planted abstraction
``A0(a, b) = Move(Rectangle(a, b), Add(a, b), Sub(b, a))`` and its mirror image; values at 2 decimals, drawn
under a seed. Each program is refactored with the limits lifted (50 iterations, ``--max-nodes`` e-nodes,
checked before each iteration, so one iteration can overshoot it) and a time limit of ``--timeout`` seconds,
in a process of its own that is killed if it has not answered 30 s after that (the reference kills its e-graph
process the same way), once per scheme:

* ``conditional``: the library's method (:func:`shapeprog.coder.rules.egglog_program`): a value table
  kept by rules and guarded rewrites;
* ``naive``: every pairwise relation of the program's floats is put into the e-graph as e-nodes before the
  run (:func:`shapeprog.coder.rules.naive_relations`) and the rules are plain patterns
  (:func:`shapeprog.coder.rules.naive_egglog_program`).

Prints per size and scheme: programs, median seconds per whole call (building the e-graph, the run and the
extraction; a call that ran out of time counts as ``--timeout``) and median CPU seconds (when every call
returned), median e-nodes at the end and the mean cost before and after (of the calls that returned), and how many
saturated / stopped on the node limit / ran out of time.

Usage::

    python bench/bench_shapecoder_saturation.py [--per-size 5] [--timeout 60] [--max-nodes 1000000]
"""
from __future__ import annotations

import argparse
import collections
import multiprocessing as mp
import os
import platform
import random
import statistics
import sys

from shapeprog.coder.lang import LANG_2D, Library, parse
from shapeprog.coder.refactor import refactor

ABSTRACTION = "A0(F0: Float, F1: Float) = Move(Rectangle(F0,F1),Add(F0,F1),Sub(F1,F0))"


def scene(n_rects: int, seed: int) -> str:
    """A naive union chain of ``n_rects`` rectangles in mirror pairs, the first pair an A0 instance."""
    rng = random.Random(seed)
    r2 = lambda lo, hi: round(rng.uniform(lo, hi), 2)  # noqa: E731
    a, b = r2(0.05, 0.25), r2(0.05, 0.15)
    rects = [(a, b, round(a + b, 2), round(b - a, 2))]
    while len(rects) < n_rects // 2:
        rects.append((r2(0.05, 0.3), r2(0.05, 0.3), r2(0.1, 0.8), r2(-0.8, 0.8)))
    parts = [f"Move(Rectangle({w},{h}),{s * x},{y})" for w, h, x, y in rects for s in (1, -1)]
    rng.shuffle(parts)
    text = parts[-1]
    for p in reversed(parts[:-1]):
        text = f"Union({p},{text})"
    return text


def _one(text, scheme, max_nodes, timeout, queue):
    from egglog import bindings  # noqa: F401  (imported before the clock starts)
    import time
    lib = Library.from_text(ABSTRACTION, LANG_2D)
    c0 = time.process_time()
    r = refactor(parse(text, lib), lib, scheme=scheme, iterations=50, max_nodes=max_nodes, time_limit=timeout)
    queue.put((r.seconds, r.stop, r.nodes, r.cost, r.input_cost, time.process_time() - c0))


#: Seconds a call may run past ``--timeout`` before its process is killed (the e-graph checks the time
#: limit only between iterations; a fresh process also spends a few seconds importing).
GRACE = 30.0


def run_one(text: str, scheme: str, max_nodes: int, timeout: float):
    """(seconds, stop, nodes, cost, input cost, CPU seconds) of one call in a fresh process; a call that
    stops on the time limit, or is killed ``GRACE`` seconds after it, counts as ``"timeout"`` with
    ``seconds = timeout``."""
    ctx = mp.get_context("spawn")  # not fork: a forked egglog or torch can hang
    queue = ctx.Queue()
    proc = ctx.Process(target=_one, args=(text, scheme, max_nodes, timeout, queue))
    proc.start()
    try:
        row = queue.get(timeout=timeout + GRACE)
    except Exception:  # queue.Empty: still running (killed below) or crashed
        row = None
    proc.join(1.0)
    if proc.is_alive():
        proc.kill()
        proc.join()
    if row is None:
        if proc.exitcode not in (None, 0, -9):
            raise SystemExit(f"the {scheme} call failed (exit code {proc.exitcode}) on {text}")
        return timeout, "timeout", None, None, None, None
    if row[1] == "time":
        return (timeout, "timeout") + tuple(row[2:])
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rects", default="2,4,8")
    ap.add_argument("--per-size", type=int, default=5)
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--max-nodes", type=int, default=1_000_000)
    ap.add_argument("--schemes", default="conditional,naive")
    ap.add_argument("--seed", type=int, default=42)
    args = ap.parse_args(argv)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"load {os.getloadavg()[0]:.1f}")
    print(f"{'params':>6} {'scheme':>11} {'n':>3} {'median s':>9} {'CPU s':>7} {'e-nodes':>9} {'cost':>13}  stops")
    for n in (int(s) for s in args.rects.split(",")):
        texts = [scene(n, args.seed + i) for i in range(args.per_size)]
        for scheme in args.schemes.split(","):
            rows = [run_one(t, scheme, args.max_nodes, args.timeout) for t in texts]
            stops = collections.Counter(r[1] for r in rows)
            done = [r for r in rows if r[2] is not None]
            nodes = f"{int(statistics.median(r[2] for r in done)):>9}" if done else f"{'-':>9}"
            cpu = f"{statistics.median(r[5] for r in done):>7.3f}" if len(done) == len(rows) else f"{'-':>7}"
            cost = (f"{statistics.mean(r[4] for r in done):.1f} -> {statistics.mean(r[3] for r in done):.1f}"
                    if done else "-")
            print(f"{4 * n:>6} {scheme:>11} {len(rows):>3} {statistics.median(r[0] for r in rows):>9.3f} {cpu} {nodes} "
                  f"{cost:>13}  {dict(stops)}", flush=True)


if __name__ == "__main__":
    main()
