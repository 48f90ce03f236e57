"""The e-graph's two value schedules side by side (``refactor(..., values="eager"|"lagged")``): the cost of
the refactored naive programs of the first N discovery shapes of each category, with the shipped library,
and why each call stopped.

    python bench/bench_shapecoder_values.py [--shapes 20] [--categories chair table storage] [--time-limit 5]
"""
import argparse
import collections
import sys
import time

from shapeprog.coder import data, load_library
from shapeprog.coder.objective import naive_program
from shapeprog.coder.refactor import TIME_LIMIT, VALUE_SCHEDULES, refactor


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", type=int, default=20)
    ap.add_argument("--categories", nargs="+", default=["chair", "table", "storage"])
    ap.add_argument("--time-limit", type=float, default=TIME_LIMIT)
    args = ap.parse_args(argv)
    print("| category | shapes | schedule | mean cost | CPU s | stops (reason, iterations: count) |")
    print("| --- | --- | --- | --- | --- | --- |")
    diff = 0
    for cat in args.categories:
        lib = load_library(cat)
        costs = {v: [] for v in VALUE_SCHEDULES}
        cpu = collections.Counter()
        stops = {v: collections.Counter() for v in VALUE_SCHEDULES}
        for rec in data.load(cat)[:args.shapes]:
            expr, env = naive_program(rec.prims)
            for v in VALUE_SCHEDULES:
                t = time.process_time()
                r = refactor(expr, lib, env=env, values=v, time_limit=args.time_limit)
                cpu[v] += time.process_time() - t
                costs[v].append(r.cost)
                stops[v][(r.stop, r.iterations)] += 1
        diff += sum(abs(a - b) > 1e-9 for a, b in zip(*costs.values()))
        for v in VALUE_SCHEDULES:
            st = ", ".join(f"{s} {i}: {n}" for (s, i), n in sorted(stops[v].items()))
            print(f"| {cat} | {len(costs[v])} | {v} | {sum(costs[v]) / len(costs[v]):.3f} | {cpu[v]:.1f} | {st} |")
    print(f"\nprograms whose cost differs between the schedules: {diff}")
    print("command: python bench/bench_shapecoder_values.py " + " ".join(sys.argv[1:] if argv is None else argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
