"""ShapeCoder Tables 2 and 3 from a discovery run's folder (``python -m shapeprog coder discover``).

The tables are :mod:`shapeprog.coder.tables` (``python -m shapeprog coder tables --library CAT=RUN_DIR`` writes
the same); this script adds the machine's description to the output.

Table 2 (discovery): the "Input Prims" row (naive programs of the run's shapes) and the run's final row
(F, |L|, Num Struct, Num Param, from its ``programs.txt`` and ``library.txt``), with the paper's rows beside.
Table 3 (post hoc inference, :func:`shapeprog.coder.infer`): F of the run's library on the first ``--train``
discovery shapes (train-PHI) and the first ``--heldout`` held-out shapes (validation-PHI), each shape
inferred from its naive program with the library fixed, with the seconds per shape; the per-shape work
goes through a process pool of ``--workers``.

Usage::

    python bench/bench_shapecoder_tables.py RUN_DIR [--category chair] [--train 100] [--heldout 100] [--workers 2]
        [--iterations 5 --max-nodes 10000 --time-limit 5] [--passes 3]

``--iterations``, ``--max-nodes`` and ``--time-limit`` set the e-graph limits of the post hoc inference
(default: the paper's 5 / 10,000 / 5 s); other values are ours and the Table 3 header says which were used.
``--passes`` sets the refactor calls per shape (:func:`shapeprog.coder.infer`'s ``passes``; the header names
a value other than the default).
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import os
import platform
import sys

from shapeprog.coder import data, tables
from shapeprog.coder.infer import PASSES
from shapeprog.coder.refactor import MAX_ENODES, MAX_ITERATIONS, TIME_LIMIT


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
    ap.add_argument("--passes", type=int, default=PASSES,
                    help=f"refactor calls per shape, each on the previous one's program (default {PASSES})")
    args = ap.parse_args(argv)
    limits = {"iterations": args.iterations, "max_nodes": args.max_nodes, "time_limit": args.time_limit,
              "passes": args.passes}
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"load {os.getloadavg()[0]:.1f}\n")
    run = tables.from_run(args.run, args.category)
    t2 = tables.table2(run)
    with cf.ProcessPoolExecutor(args.workers) as ex:
        t3 = tables.table3(run, train=args.train, heldout=args.heldout, executor=ex, **limits)
    print(tables.format_tables(run, t2, t3, **limits))


if __name__ == "__main__":
    main()
