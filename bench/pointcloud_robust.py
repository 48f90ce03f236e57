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

With ``--conditions`` the inputs are the test conditions of :mod:`shapeprog.pointcloud.conditions` instead
(``clean``, ``noise-0.01``, ``noise-0.02``, ``uneven``, ``partial``, ``rounded``, ``merged``): each shape's
cloud under each condition (``condition_cloud`` of the program's cuboids in the clean cloud's canonical frame,
``--points`` surface samples, seeded by the shape id), then the same random scale and position as above
(``--min-points``, ``--max-points`` and ``--noise`` are not used). The methods default to ``decode retrieval
robust``; a row per category, condition and method. ``--out FILE`` then writes FILE, one row per condition and
method with each category's F-score and % rooted and their means (``docs/pointcloud.md``), and beside it
``FILE-stem_CATEGORY.json`` per category with every column (``docs/tables/pointcloud_CATEGORY.md``).

Usage::

    OMP_NUM_THREADS=2 python bench/pointcloud_robust.py --shapes 30 --threads 2 \\
        --out docs/results/pointcloud/robust.json
    OMP_NUM_THREADS=2 python bench/pointcloud_robust.py --conditions clean noise-0.01 noise-0.02 uneven partial \\
        rounded merged --shapes 30 --seeds 1 --threads 2 --out docs/results/pointcloud/conditions.json
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from shapeio.results import column, make_result, markdown, write_result
from shapeprog.pointcloud.conditions import CONDITION_POINTS, CONDITIONS, canonical_shape, condition_cloud
from shapeprog.pointcloud.data import corpus_cloud, corpus_splits
from shapeprog.pointcloud.infer import infer, load_model, load_pretrained, shape_metrics, _corners_of
from shapeprog.pointcloud.normalize import normalize
from shapeprog.pointcloud.retrieval import RetrievalIndex

METHODS = ("decode", "subsets", "search", "retrieval", "robust", "fit")
#: The methods measured under the test conditions unless ``--methods`` says otherwise.
CONDITION_METHODS = ("decode", "retrieval", "robust")
SCALE_RANGE, SHIFT = 10.0, 5.0


def placement(shape_id: int, rng: np.random.Generator | None = None):
    """``(k, b)``: the random uniform scale and the shift of a shape's input (``input = points * k + b``)."""
    rng = np.random.default_rng([7, int(shape_id)]) if rng is None else rng
    k = float(np.exp(rng.uniform(-np.log(SCALE_RANGE), np.log(SCALE_RANGE))))
    return k, rng.uniform(-SHIFT, SHIFT, size=3)


def make_input(clean: np.ndarray, shape_id: int, lo: int, hi: int, noise: float):
    """``(input, k, b)``: a random subset of ``clean`` (a count from ``lo`` to ``hi``), noise, then ``* k + b``."""
    rng = np.random.default_rng([7, int(shape_id)])
    n = int(rng.integers(lo, hi + 1))
    pick = rng.choice(len(clean), size=min(n, len(clean)), replace=False)
    noisy = clean[pick] + rng.normal(0.0, noise, size=(len(pick), 3))
    k, b = placement(shape_id, rng)
    return noisy * k + b, k, b


def condition_input(corners: np.ndarray, shape_id: int, condition: str, n_points: int):
    """``(input, k, b)``: the shape's cloud under ``condition`` (seeded by the shape id), then ``* k + b``."""
    k, b = placement(shape_id)
    return condition_cloud(corners, condition, n_points=n_points, seed=int(shape_id)) * k + b, k, b


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


def measure(name, inputs, model, index, seeds: int, robust=None) -> dict:
    """One method on ``inputs`` (``(clean, input, k, b)`` each) with the inference seeds ``0 .. seeds - 1``: the
    row's mean F-score, CD x1000, % rooted, mean per-shape std of F over the seeds, median wall and CPU s."""
    fs, cds, rooted, stds, wall, cpu = [], [], [], [], [], []
    for clean, x, k, b in inputs:
        per = []
        for seed in range(seeds):
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
    return {"method": name, "fscore": float(np.mean(fs)), "cd": 1000 * float(np.nanmean(cds)),
            "rooted": 100 * float(np.mean(rooted)), "std": float(np.mean(stds)),
            "seconds": statistics.median(wall), "cpu": statistics.median(cpu), "shapes": len(inputs),
            "points": float(np.mean([len(x) for _, x, _, _ in inputs]))}


def _print(row: dict) -> None:
    where = row["category"] + ("" if "condition" not in row else f" {row['condition']:10s}")
    print(f"{where:19s} {row['method']:10s} F {row['fscore']:5.1f}  CD x1000 {row['cd']:5.1f}  rooted "
          f"{row['rooted']:5.1f} %  std of F over seeds {row['std']:4.1f}  wall s {row['seconds']:.3f}  CPU s "
          f"{row['cpu']:.3f}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--categories", nargs="+", default=["chair", "table", "storage"])
    ap.add_argument("--methods", nargs="+", default=None, choices=METHODS,
                    help=f"default: all; with --conditions: {' '.join(CONDITION_METHODS)}")
    ap.add_argument("--conditions", nargs="+", choices=CONDITIONS, metavar="CONDITION",
                    help=f"measure under these test conditions ({', '.join(CONDITIONS)}) instead of the noisy subsets")
    ap.add_argument("--points", type=int, default=CONDITION_POINTS,
                    help="with --conditions: surface samples per cloud (conditions that drop points keep fewer)")
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
    methods = args.methods or list(CONDITION_METHODS if args.conditions else METHODS)
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
        if args.conditions:
            shapes = [(i,) + canonical_shape(cat, i) for i in ids]
            sets = {cond: [(clean,) + condition_input(corners, i, cond, args.points) for i, clean, corners in shapes]
                    for cond in args.conditions}
        else:
            inputs = []
            for i in ids:
                clean, _ = normalize(corpus_cloud(cat, i).astype(np.float64))
                inputs.append((clean,) + make_input(clean, i, args.min_points, args.max_points, args.noise))
            sets = {None: inputs}
        first = next(iter(sets.values()))[0][1]
        infer(first, model=model, physics=False, retrieval=index)  # warm-up
        for cond, inputs in sets.items():
            for name in methods:
                row = {"category": cat, **({} if cond is None else {"condition": cond}),
                       **measure(name, inputs, model, index, args.seeds, robust)}
                rows.append(row)
                _print(row)
    groups = [None] if not args.conditions else args.conditions
    for cond in groups:
        for name in methods:
            mine = [r for r in rows if r["method"] == name and r.get("condition") == cond]
            if len(mine) > 1:
                rows.append({"category": "mean", **({} if cond is None else {"condition": cond}), "method": name,
                             "shapes": sum(r["shapes"] for r in mine),
                             **{key: float(np.mean([r[key] for r in mine]))
                                for key in ("fscore", "cd", "rooted", "std", "seconds", "cpu", "points")}})
                _print(rows[-1])
    print("command: " + command)
    if args.out:
        write_results(args, rows, methods, command)
    return 0


def write_results(args, rows: list, methods: list, command: str) -> None:
    """``--out`` (and with ``--conditions`` one file per category beside it)."""
    cols = [column("category", "category"), column("method", "method"), column("shapes", "shapes"),
            column("fscore", "F-score @0.03", 1), column("cd", "CD x1000", 1), column("rooted", "% rooted", 1),
            column("std", "std of F over seeds", 1), column("seconds", "wall s per cloud", 3),
            column("cpu", "CPU s per cloud", 3)]
    split = (f"{args.split} split ({'the corpus val split' if args.split == 'test' else 'the carve-out'}), the first "
             f"{args.shapes} shapes per category")
    scoring = (f"{args.seeds} inference seed(s) per shape, {args.threads} torch thread(s). F-score, CD and rooted are "
               "means over shapes and seeds against the clean cloud; "
               + ("std is the mean per-shape standard deviation of F over the seeds; " if args.seeds > 1 else "")
               + "seconds are medians of the infer call (no metrics) as measured.")
    if not args.conditions:
        notes = [f"{split}; inputs: {args.min_points} to {args.max_points} random points of the cuboid-surface cloud, "
                 f"noise sigma {args.noise}, random scale x1/10 to x10 and shift; {scoring}"]
        result = make_result("Point cloud -> program on noisy, subsampled, rescaled and shifted held-out clouds",
                             cols, rows, notes, command=command)
        write_result(args.out, result)
        print(markdown(result))
        return
    protocol = (f"{split}; inputs: each shape's cloud under each test condition (shapeprog.pointcloud.conditions: "
                f"{args.points} surface samples of the program's cuboids, or of rounded boxes for 'rounded'; "
                "'uneven', 'partial' and 'merged' keep a subset: the per-category files' input points), then a random "
                "scale x1/10 to x10 and shift; results are mapped back and scored against the clean 10,000-point "
                "cloud of the whole shape; methods: decode (the papers' single decode), retrieval (the nearest "
                f"training shape), robust (the default of infer). {scoring}")
    out = Path(args.out)
    for cat in args.categories:
        mine = [r for r in rows if r["category"] == cat]
        per_cols = [column("condition", "condition"), *cols[1:3], column("points", "input points", 0), *cols[3:]]
        per_cols = [c for c in per_cols if c["key"] != "std" or args.seeds > 1]  # one seed: no spread to show
        per = make_result(f"Point cloud -> program under harder test conditions, {cat}", per_cols, mine, [protocol],
                          command=command)
        write_result(out.with_name(f"{out.stem}_{cat}.json"), per)
    summary, cats = [], [c for c in args.categories] + (["mean"] if len(args.categories) > 1 else [])
    for cond in args.conditions:
        for name in methods:
            row = {"condition": cond, "method": name}
            for r in rows:
                if r.get("condition") == cond and r["method"] == name:
                    row[f"f_{r['category']}"], row[f"rooted_{r['category']}"] = r["fscore"], r["rooted"]
            summary.append(row)
    cols = [column("condition", "condition"), column("method", "method")]
    cols += [column(f"f_{c}", f"F {c}", 1) for c in cats] + [column(f"rooted_{cats[-1]}", f"% rooted {cats[-1]}", 1)]
    result = make_result("Point cloud -> program under harder test conditions (F-score @0.03)", cols, summary,
                         [protocol + f" Per category with every column: {out.stem}_CATEGORY.json beside this file."],
                         command=command)
    write_result(out, result)
    print(markdown(result))


if __name__ == "__main__":
    sys.exit(main())
