"""ShapeCoder discovery wall time per phase: F, |L|, Num Struct, Num Param and the elapsed seconds after each
phase (wake, integration) of a discovery run, either read from a run folder's ``log.json`` (``--from``)
or measured on a small run of the first ``--shapes`` discovery shapes of a category.

Usage::

    python bench/bench_shapecoder_discovery.py --from RUN_DIR
    python bench/bench_shapecoder_discovery.py [--category chair] [--shapes 40] [--rounds 1] [--proposals 300]
        [--abstractions 5] [--workers 2]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from shapeprog.coder import data
from shapeprog.coder.discover import discover_category
from shapeprog.coder.config import Config


def _table(log: list, title: str) -> None:
    print(f"\n{title}\n")
    print("| round | phase | F | \\|L\\| | Num Struct | Num Param | elapsed s | phase s |\n|---|---|---|---|---|---|---|---|")
    prev = 0.0
    for h in log:
        print(f"| {h['round']} | {h['phase']} | {h['F']:.2f} | {h['L']} | {h['num_struct']:.2f} | {h['num_param']:.2f} "
              f"| {h['seconds']:.0f} | {h['seconds'] - prev:.0f} |")
        prev = h["seconds"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="run", help="a discover-abstractions output folder")
    ap.add_argument("--category", default="chair", choices=data.CATEGORIES)
    ap.add_argument("--shapes", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--proposals", type=int, default=300)
    ap.add_argument("--abstractions", type=int, default=5)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"load {os.getloadavg()[0]:.1f}")
    if args.run:
        log = json.loads((Path(args.run) / "log.json").read_text())
        _table(log["log"], f"run {args.run}: final {log['summary']}")
        return
    cfg = Config(rounds=args.rounds, n_proposals=args.proposals, n_abstractions=args.abstractions)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.time()
        res = discover_category(args.category, tmp, cfg, args.shapes, args.workers, log=None)
        wall = time.time() - t0
    _table(res.log, f"{args.category}, first {args.shapes} shapes, {cfg}: {wall:.0f} s wall, |L| {res.library.size}")


if __name__ == "__main__":
    main()
