"""F-score against seconds per cloud of the latent search, for several search schedules.

For the first ``--limit`` shapes of a make-clouds cache's test split (``--split val``: its validation
carve-out, on which a schedule should be chosen), each schedule's inference
(``infer(x, search=True, search_schedule=...)``; ``none`` is the papers' single decode) runs on the same
noisy, subsampled, scaled and moved input as ``python -m shapeprog pointcloud tables`` builds
(``shapeprog.pointcloud.tables``), and the result is scored the way the tables score it (F-score at 0.03
against the clean cloud, canonical units). The script prints, per schedule, the mean F-score, the mean
chamfer x1000, the share of rooted results, the decodes, and the median and 90th-percentile CPU seconds of
the ``infer`` call (no metrics, no physics: what a user waits for), then the command line. No fitting.

``--retrieval 0 4 16`` runs every schedule also with retrieval-augmented decoding (``infer(...,
retrieval=index, retrieval_candidates=K)``; 0: without), the index built from the cache's training
clouds (``RetrievalIndex.from_cache``: the corpus train split, never the test split; with ``--split val``
the carve-out's ``train`` part alone, so that a validation shape is never its own candidate); the row then also
gives the share of clouds whose kept program is a training program.

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

from shapeprog.pointcloud.dataset import load_cache, read_split
from shapeprog.pointcloud.infer import infer, load_model, load_pretrained, shape_metrics
from shapeprog.pointcloud.retrieval import RetrievalIndex
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
    ap.add_argument("--retrieval", type=int, nargs="+", default=[0],
                    help="training programs competing with the decoded one (0: no retrieval); one row per value")
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
    index = None
    if any(k > 0 for k in args.retrieval):
        c0 = time.process_time()
        splits = ("train",) if args.split == "val" else ("train", "val")
        index = RetrievalIndex.from_cache(args.clouds, args.category, splits=splits)
        print(f"# retrieval index: {len(index)} training shapes, built in {time.process_time() - c0:.1f} CPU s")
    for name, schedule in zip(args.schedules, schedules):
        for k in args.retrieval:
            fs, cds, rooted, cpu, decodes, kept = [], [], [], [], 0, 0
            for i, clean in zip(ids, cleans):
                x, scale, b = _inputs(clean, int(i), args.seed)
                target = torch.from_numpy(clean)
                c0 = time.process_time()
                try:
                    r = infer(x, model=model, physics=False, seed=args.seed, method="decode",
                              search=schedule is not None,
                              search_schedule=schedule, retrieval=index if k > 0 else None,
                              retrieval_candidates=max(k, 1))
                except ValueError:
                    r = None
                cpu.append(time.process_time() - c0)
                if r is None:
                    m = shape_metrics(torch.zeros(0, 8, 3), target)
                else:
                    corners = torch.from_numpy((np.asarray(r.corners()) - b) / scale)
                    m = shape_metrics(corners, target, seed=args.seed, stability=False)
                    decodes += r.search["decodes"] if r.search else 1
                    kept += int(bool(r.retrieval and r.retrieval["chosen"]))
                fs.append(m["fscore"] or 0.0)
                rooted.append(bool(m["rooted"]))
                cds.append(m["cd"] if m["cd"] is not None else float("nan"))
            label = name if k == 0 else f"{name} + retrieval {k}"
            extra = "" if k == 0 else f", training program kept {100 * kept / n:.1f} %"
            print(f"{label:>50s}: F {np.mean(fs):.1f}, CD x1000 {1000 * np.nanmean(cds):.1f}, "
                  f"rooted {100 * np.mean(rooted):.1f} %, {decodes / n:.0f} decodes{extra}, "
                  f"CPU s median {np.median(cpu):.3f}, p90 {np.percentile(cpu, 90):.3f}", flush=True)
    print("# command: python bench/pointcloud_search_budget.py " + " ".join(sys.argv[1:] if argv is None else argv))
    return 0


if __name__ == "__main__":
    sys.exit(main())
