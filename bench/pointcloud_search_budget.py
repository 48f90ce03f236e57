"""F-score against seconds per cloud of the latent search, for several search schedules.

For the first ``--limit`` shapes of a make-clouds cache's test split (``--split val``: its validation
carve-out, on which a schedule should be chosen), each schedule's inference
(``infer(x, search=True, search_schedule=...)``; ``none`` is the papers' single decode) runs on the same
noisy, subsampled, scaled and moved input as ``python -m shapeprog pointcloud-tables`` builds
(``shapeprog.pointcloud.tables``), and the result is scored the way the tables score it (F-score at 0.03
against the clean cloud, canonical units). The script prints, per schedule, the mean F-score, the mean
chamfer x1000, the share of rooted results, the decodes, and the median and 90th-percentile CPU seconds of
the ``infer`` call (no metrics, no physics: what a user waits for), then the command line. No fitting.

Usage::

    OMP_NUM_THREADS=1 python bench/pointcloud_search_budget.py --clouds clouds --limit 100 \\
        --schedules none 8:0.5,8:0.25 16:0.75,16:0.5,16:0.35,16:0.25,16:0.18,16:0.12
"""
from __future__ import annotations

import argparse
import platform
import sys
import time

import numpy as np
import torch

from shapeprog.pointcloud.data import load_cache, read_split
from shapeprog.pointcloud.infer import infer, load_model, load_pretrained, shape_metrics
from shapeprog.pointcloud.search import parse_schedule
from shapeprog.pointcloud.tables import _inputs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clouds", required=True, help="the make-clouds folder")
    ap.add_argument("--category", default="chair")
    ap.add_argument("--weights", help="weights file (default: the shipped model of the category)")
    ap.add_argument("--limit", type=int, default=100, help="the first N shapes of the split")
    ap.add_argument("--split", default="test", choices=("val", "test"),
                    help="the cache's split: test (the corpus val split, the tables' shapes) or val (the carve-out "
                         "of the corpus train split, for choosing a schedule)")
    ap.add_argument("--schedules", nargs="+", default=["none"],
                    help="'none' (one decode), 'fast', 'default' or samples:sigma,... "
                         "(shapeprog.pointcloud.search.parse_schedule)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    schedules = [None if s == "none" else parse_schedule(s) for s in args.schedules]
    model = load_model(args.weights, args.category) if args.weights else load_pretrained(args.category)
    cache = load_cache(args.clouds, args.category)
    ids = read_split(args.clouds, args.category)[args.split][: args.limit]
    cleans = cache.normalized(cache.index(ids)).astype(np.float64)
    n = len(ids)
    print(f"# {platform.processor() or platform.machine()}, torch {torch.__version__}, {args.threads} thread(s), "
          f"{n} {args.category} {args.split} shapes, {args.weights or 'shipped model'}")
    for name, schedule in zip(args.schedules, schedules):
        fs, cds, rooted, cpu, decodes = [], [], [], [], 0
        for i, clean in zip(ids, cleans):
            x, k, b = _inputs(clean, int(i), args.seed)
            target = torch.from_numpy(clean)
            c0 = time.process_time()
            try:
                r = infer(x, model=model, physics=False, seed=args.seed, search=schedule is not None,
                          search_schedule=schedule)
            except ValueError:
                r = None
            cpu.append(time.process_time() - c0)
            if r is None:
                m = shape_metrics(torch.zeros(0, 8, 3), target)
            else:
                corners = torch.from_numpy((np.asarray(r.corners()) - b) / k)
                m = shape_metrics(corners, target, seed=args.seed, stability=False)
                decodes += r.search["decodes"] if r.search else 1
            fs.append(m["fscore"] or 0.0)
            rooted.append(bool(m["rooted"]))
            cds.append(m["cd"] if m["cd"] is not None else float("nan"))
        print(f"{name:>50s}: F {np.mean(fs):.1f}, CD x1000 {1000 * np.nanmean(cds):.1f}, "
              f"rooted {100 * np.mean(rooted):.1f} %, {decodes / n:.0f} decodes, CPU s median {np.median(cpu):.3f}, p90 {np.percentile(cpu, 90):.3f}",
              flush=True)
    print("# command: python bench/pointcloud_search_budget.py " + " ".join(sys.argv[1:] if argv is None else argv))
    return 0


if __name__ == "__main__":
    sys.exit(main())
