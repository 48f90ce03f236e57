"""ShapeCoder Tables 2 and 3 from a discovery run's folder (``python -m shapeprog discover-abstractions``).

Table 2 (discovery): the "Input Prims" row (naive programs of the run's shapes) and the run's final row
(F, |L|, Num Struct, Num Param, from its ``programs.txt`` and ``library.txt``), with the paper's rows beside.
Table 3 (post hoc inference, :func:`shapeprog.coder.infer`): F of the run's library on the first ``--train``
discovery shapes (train-PHI) and the first ``--heldout`` held-out shapes (validation-PHI), each shape
inferred from its naive program with the library fixed, with the seconds per shape; the per-shape work
goes through a process pool of ``--workers``.

Usage::

    python bench/bench_shapecoder_tables.py RUN_DIR [--category chair] [--train 100] [--heldout 100] [--workers 2]
        [--iterations 5 --max-nodes 10000 --time-limit 5]

``--iterations``, ``--max-nodes`` and ``--time-limit`` set the e-graph limits of the post hoc inference
(default: the paper's 5 / 10,000 / 5 s); other values are ours and the Table 3 header says which were used.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import os
import platform
import sys
import time
from pathlib import Path

from shapeprog.coder import data
from shapeprog.coder.discover import evaluate, summarize
from shapeprog.coder.infer import infer
from shapeprog.coder.lang import Library, parse
from shapeprog.coder.objective import naive_summary, omega
from shapeprog.coder.refactor import MAX_ENODES, MAX_ITERATIONS, TIME_LIMIT

PAPER2 = {"chair": [("Input Prims", 146.0, 6, 29, 61), ("ShapeCoder", 63.6, 33, 10, 27)],
          "table": [("Input Prims", 125.0, 6, 25, 51), ("ShapeCoder", 40.9, 37, 8, 18)],
          "storage": [("Input Prims", 154.0, 6, 30, 62), ("ShapeCoder", 71.3, 31, 11, 33)]}
PAPER3 = {"chair": {"train-PHI": 67.5, "validation-PHI": 70.6}}


def _infer_one(task):
    prims, lib_text, limits = task
    lib = Library.from_text(lib_text)
    t0 = time.process_time()
    r = infer(prims, lib, **limits)
    return r.cost, time.process_time() - t0, r.text


def _phi(recs, lib, workers, limits):
    tasks = [(r.prims, lib.to_text(), limits) for r in recs]
    t0 = time.time()
    with cf.ProcessPoolExecutor(workers) as ex:
        out = list(ex.map(_infer_one, tasks))
    wall = time.time() - t0
    mean = sum(c for c, _, _ in out) / len(out)
    lib_cost = sum(omega(ab, lib) for ab in lib.abstractions)
    used = {name for _, _, t in out for name in [ab.name for ab in lib.abstractions] if name + "(" in t}
    return mean + lib_cost, len(used), sum(c for _, c, _ in out) / len(out), wall


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="a discover-abstractions output folder (library.txt, programs.txt)")
    ap.add_argument("--category", default="chair", choices=data.CATEGORIES)
    ap.add_argument("--train", type=int, default=100)
    ap.add_argument("--heldout", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--iterations", type=int, default=MAX_ITERATIONS, help="e-graph iterations (paper: 5)")
    ap.add_argument("--max-nodes", type=int, default=MAX_ENODES, help="e-node limit (paper: 10,000)")
    ap.add_argument("--time-limit", type=float, default=TIME_LIMIT, help="seconds per refactor call (paper: 5)")
    args = ap.parse_args(argv)
    limits = {"iterations": args.iterations, "max_nodes": args.max_nodes, "time_limit": args.time_limit}
    paper_limits = limits == {"iterations": MAX_ITERATIONS, "max_nodes": MAX_ENODES, "time_limit": TIME_LIMIT}
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"load {os.getloadavg()[0]:.1f}")
    run = Path(args.run)
    lib = Library.from_text((run / "library.txt").read_text(), file=str(run / "library.txt"))
    lines = (run / "programs.txt").read_text().splitlines()
    recs = {r.key: r for r in data.load(args.category)}
    keys = [ln.partition(":")[0] for ln in lines]
    progs = [parse(ln.partition(":")[2], lib, file=str(run / "programs.txt"), line=i + 1) for i, ln in enumerate(lines)]
    errors = []
    for k, p in zip(keys, progs):
        got = evaluate(p, lib, recs[k].prims)
        if got is None:
            raise SystemExit(f"error: the program of {k} does not re-cover its primitives")
        errors.append(got[1])
    naive = naive_summary(recs[k].prims for k in keys)
    s = summarize(progs, lib, errors)
    print(f"\n## Table 2 ({args.category}, {len(keys)} discovery shapes)\n")
    print("| row | F | \\|L\\| | Num Struct | Num Param |\n| --- | --- | --- | --- | --- |")
    print(f"| Input Prims (ours) | {naive.F:.1f} | 6 | {naive.num_struct:.1f} | {naive.num_param:.1f} |")
    print(f"| ShapeCoder (ours) | {s.F:.1f} | {s.library_size} | {s.num_struct:.1f} | {s.num_param:.1f} |")
    for name, f, L, ns, npar in PAPER2[args.category]:
        print(f"| {name} (paper, 400 shapes) | {f} | {L} | {ns} | {npar} |")
    which = "the paper's" if paper_limits else "ours, not the paper's"
    print(f"\n## Table 3 ({args.category}, post hoc inference with the {len(lib)} abstractions; e-graph limits "
          f"{args.iterations} iterations / {args.max_nodes} e-nodes / {args.time_limit:g} s: {which})\n")
    print("| split | shapes | F | abstractions used | CPU s / shape | wall s | paper F |\n| --- | --- | --- | --- | --- | --- | --- |")
    splits = [("train-PHI", data.load(args.category)[:args.train]),
              ("validation-PHI", data.load(args.category, "heldout")[:args.heldout])]
    for name, rs in splits:
        rs = [r for r in rs if len(r.prims) <= 16]
        f, used, cpu, wall = _phi(rs, lib, args.workers, limits)
        paper = PAPER3.get(args.category, {}).get(name, "-")
        print(f"| {name} | {len(rs)} | {f:.1f} | {used} | {cpu:.2f} | {wall:.0f} | {paper} |")


if __name__ == "__main__":
    main()
