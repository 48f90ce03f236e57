"""How dependable is point cloud -> program: F-score, rootedness, seed spread and time per method on hard inputs.

For the first ``--shapes`` shapes of each category's held-out split (``--split test``: the corpus val split, the
tables' test shapes; ``--split val``: the seeded carve-out of the corpus train split, on which settings are chosen,
with the retrieval index then built without the carve-out), the input is the shape's 10,000-point cuboid-surface
cloud (``corpus_cloud``, normalised), randomly subsampled to a count drawn from ``--min-points`` to ``--max-points``,
with Gaussian noise (sigma ``--noise``, canonical units), then a random uniform scale (x1/10 to x10) and position,
all seeded per shape. Every method runs on that one input with the inference seeds 0 to ``--seeds - 1``; each result
is mapped back through the known transform and scored against the clean cloud (F-score at 0.03, chamfer, rooted).

Methods (``--methods``):

* ``decode``: the papers' single decode (``infer(method="decode")``);
* ``subsets``: the robust method's candidates from encoder subsets alone (no training program, no polish);
* ``search``: the latent search with the ``fast`` schedule (17 decodes, ``method="decode", search=True``);
* ``retrieval``: the nearest training shape alone (``RetrievalIndex.query``, exact stage);
* ``robust``: the default (``infer()`` with no option): subsets, training programs, selection, polish;
* ``fit``: the single decode with fitting (``method="decode", fit=True``, 150 steps).

It prints, per category and method, the mean F-score, chamfer x1000, % rooted, the mean per-shape standard
deviation of F over the seeds and the median wall and CPU seconds of the ``infer`` call (no metrics), then the
command; ``--out`` writes the same as a result file (``shapeio.results``).

Usage::

    OMP_NUM_THREADS=2 python bench/pointcloud_robust.py --shapes 30 --threads 2 \\
        --out docs/results/pointcloud/robust.json
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
import torch

from shapeio.results import column, make_result, markdown, write_result
from shapeprog.pointcloud.data import corpus_cloud, corpus_splits
from shapeprog.pointcloud.infer import infer, load_model, load_pretrained, shape_metrics, _corners_of
from shapeprog.pointcloud.normalize import normalize
from shapeprog.pointcloud.retrieval import RetrievalIndex

METHODS = ("decode", "subsets", "search", "retrieval", "robust", "fit")
SCALE_RANGE, SHIFT = 10.0, 5.0


def make_input(clean: np.ndarray, shape_id: int, lo: int, hi: int, noise: float):
    """``(input, k, b)``: a random subset of ``clean`` (a count from ``lo`` to ``hi``), noise, then ``* k + b``."""
    rng = np.random.default_rng([7, int(shape_id)])
    n = int(rng.integers(lo, hi + 1))
    pick = rng.choice(len(clean), size=min(n, len(clean)), replace=False)
    noisy = clean[pick] + rng.normal(0.0, noise, size=(len(pick), 3))
    k = float(np.exp(rng.uniform(-np.log(SCALE_RANGE), np.log(SCALE_RANGE))))
    b = rng.uniform(-SHIFT, SHIFT, size=3)
    return noisy * k + b, k, b


def run_method(name, x, model, index, seed, robust=None):
    """The result's corners in the input's frame ``(L, 8, 3)``, or None when nothing was decoded."""
    if name == "retrieval":
        unit, t = normalize(x)
        sub = unit[np.random.default_rng(seed).permutation(len(unit))[:2048]]
        prog, off = index.query(torch.from_numpy(sub)).canonical_program()
        return t.invert((_corners_of(prog).double() + torch.from_numpy(off)).numpy())
    kw = {"decode": dict(method="decode"), "subsets": dict(method="robust", retrieval_candidates=0, polish_steps=0),
          "search": dict(method="decode", search=True, search_schedule="fast"),
          "robust": dict(retrieval=index, **(robust or {})), "fit": dict(method="decode", fit=True)}[name]
    try:
        return infer(x, model=model, physics=False, seed=seed, **kw).corners()
    except ValueError:
        return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--categories", nargs="+", default=["chair", "table", "storage"])
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--shapes", type=int, default=30, help="shapes per category (the first of the split)")
    ap.add_argument("--split", default="test", choices=("test", "val"))
    ap.add_argument("--seeds", type=int, default=4, help="inference seeds per shape")
    ap.add_argument("--min-points", type=int, default=2500)
    ap.add_argument("--max-points", type=int, default=10000)
    ap.add_argument("--noise", type=float, default=0.005)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--weights", nargs="*", default=[], help="CATEGORY=FILE: another model for a category")
    ap.add_argument("--robust", nargs="*", default=[], metavar="KEY=VALUE",
                    help="settings of the robust method for comparisons, e.g. subsets=8 polish_steps=0 "
                         "select=chamfer search=True search_schedule=4:0.5 retrieval_candidates=32")
    ap.add_argument("--out", help="result file (JSON, shapeio.results)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    weights = dict(w.split("=", 1) for w in args.weights)
    robust = {}
    for kv in args.robust:
        key, value = kv.split("=", 1)
        robust[key] = {"True": True, "False": False}.get(value, int(value) if value.isdigit() else value)
    command = "python bench/pointcloud_robust.py " + " ".join(sys.argv[1:] if argv is None else argv)
    rows = []
    for cat in args.categories:
        model = load_model(weights[cat], cat) if cat in weights else load_pretrained(cat)
        split = corpus_splits(cat)
        if args.split == "val":
            index = RetrievalIndex.from_corpus(cat, ids=split["train"])
        else:
            from shapeprog.pointcloud.infer import default_index
            index = default_index(cat)
        ids = split["test" if args.split == "test" else "val"][: args.shapes]
        inputs = []
        for i in ids:
            clean, _ = normalize(corpus_cloud(cat, i).astype(np.float64))
            inputs.append((clean,) + make_input(clean, i, args.min_points, args.max_points, args.noise))
        infer(inputs[0][1], model=model, physics=False, retrieval=index)  # warm-up
        for name in args.methods:
            fs, cds, rooted, stds, wall, cpu = [], [], [], [], [], []
            for clean, x, k, b in inputs:
                per = []
                for seed in range(args.seeds):
                    t0, c0 = time.perf_counter(), time.process_time()
                    corners = run_method(name, x, model, index, seed, robust)
                    wall.append(time.perf_counter() - t0)
                    cpu.append(time.process_time() - c0)
                    c = torch.zeros(0, 8, 3) if corners is None else torch.from_numpy((np.asarray(corners) - b) / k)
                    m = shape_metrics(c, torch.from_numpy(clean), stability=False)
                    per.append(m["fscore"])
                    rooted.append(bool(m["rooted"]))
                    cds.append(np.nan if m["cd"] is None else m["cd"])
                fs += per
                stds.append(float(np.std(per)))
            row = {"category": cat, "method": name, "fscore": float(np.mean(fs)), "cd": 1000 * float(np.nanmean(cds)),
                   "rooted": 100 * float(np.mean(rooted)), "std": float(np.mean(stds)),
                   "seconds": statistics.median(wall), "cpu": statistics.median(cpu), "shapes": len(inputs)}
            rows.append(row)
            print(f"{cat:8s} {name:10s} F {row['fscore']:5.1f}  CD x1000 {row['cd']:5.1f}  rooted {row['rooted']:5.1f} %  "
                  f"std of F over seeds {row['std']:4.1f}  wall s {row['seconds']:.3f}  CPU s {row['cpu']:.3f}",
                  flush=True)
    for name in args.methods:
        mine = [r for r in rows if r["method"] == name]
        if len(mine) > 1:
            rows.append({"category": "mean", "method": name, "shapes": sum(r["shapes"] for r in mine),
                         **{key: float(np.mean([r[key] for r in mine]))
                            for key in ("fscore", "cd", "rooted", "std", "seconds", "cpu")}})
            r = rows[-1]
            print(f"{'mean':8s} {name:10s} F {r['fscore']:5.1f}  rooted {r['rooted']:5.1f} %  std {r['std']:4.1f}  "
                  f"wall s {r['seconds']:.3f}")
    print("command: " + command)
    if args.out:
        cols = [column("category", "category"), column("method", "method"), column("shapes", "shapes"),
                column("fscore", "F-score @0.03", 1), column("cd", "CD x1000", 1), column("rooted", "% rooted", 1),
                column("std", "std of F over seeds", 1), column("seconds", "wall s per cloud", 3),
                column("cpu", "CPU s per cloud", 3)]
        notes = [f"{args.split} split ({'the corpus val split' if args.split == 'test' else 'the carve-out'}), the first "
                 f"{args.shapes} shapes per category; inputs: {args.min_points} to {args.max_points} random points of "
                 f"the cuboid-surface cloud, noise sigma {args.noise}, random scale x1/10 to x10 and shift; "
                 f"{args.seeds} inference seeds per shape, {args.threads} torch thread(s). F-score, CD and rooted are "
                 "means over shapes and seeds against the clean cloud; std is the mean per-shape standard deviation "
                 "of F over the seeds; seconds are medians of the infer call (no metrics) as measured."]
        result = make_result("Point cloud -> program on noisy, subsampled, rescaled and shifted held-out clouds",
                             cols, rows, notes, command=command)
        write_result(args.out, result)
        print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
