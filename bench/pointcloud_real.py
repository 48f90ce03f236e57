"""The real-geometry check: the shipped point-cloud models on the two vendored real clouds.

``comp_pc.obj`` (a table) and ``simp_pc.obj`` (a chair, by its look; the source calls both tables), from
``shapeprog.corpus.example_points``, are 10,000 points each sampled from real PartNet meshes, where every
training cloud was sampled from part cuboids. For each cloud and each shipped model of its category (the
default, the latent-regression model, the model of macro programs), ``infer`` runs with one decode, with
fitting and with the latent search, and the default model once more on the cloud turned 90 degrees about
its up axis (the front direction is not normalised). The script prints chamfer x1000 and F-score at 0.03
(canonical units, against the whole input cloud), rooted and stable, seconds, then the command line.

Usage::

    OMP_NUM_THREADS=1 python bench/pointcloud_real.py
"""
from __future__ import annotations

import argparse
import platform
import sys
import time

import numpy as np
import torch

from shapeprog import corpus
from shapeprog.pointcloud.infer import infer, load_model
from shapeprog.pointcloud.model import WEIGHTS

MODELS = {"e2e (default)": "pointcloud_e2e_{}.pt", "latent": "pointcloud_latent_{}.pt",
          "e2e, ShapeMOD macros": "pointcloud_e2e_{}_macros.pt"}
CLOUDS = {"comp_pc.obj": "table", "simp_pc.obj": "chair"}
TURN_Y = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # 90 degrees about +y (up)


def row(cloud, label, decoding, x, category, model, seed, **kw) -> str:
    t = time.perf_counter()
    m = infer(x, category=category, model=model, seed=seed, stability=True, **{"method": "decode", **kw}).metrics
    s = time.perf_counter() - t
    cd = "-" if m["cd"] is None else f"{1000 * m['cd']:.1f}"
    return f"| {cloud} | {label} | {decoding} | {cd} | {m['fscore']:.1f} | {m['rooted']} | {m['stable']} | {s:.2f} |"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    print(f"# {platform.processor() or platform.machine()}, torch {torch.__version__}, {args.threads} thread(s)")
    print("| cloud | model | decoding | CD x1000 | F-score | rooted | stable | s |")
    print("|---|---|---|---:|---:|---|---|---:|")
    for cloud, category in CLOUDS.items():
        x = corpus.example_points(cloud)
        for label, weights in MODELS.items():
            model = load_model(WEIGHTS / weights.format(category), category)
            for decoding, kw in (("one decode", {}), ("one decode + Opt Program", {"fit": True}),
                                 ("latent search", {"search": True})):
                print(row(cloud, f"{category} {label}", decoding, x, category, model, args.seed, **kw), flush=True)
        model = load_model(WEIGHTS / MODELS["e2e (default)"].format(category), category)
        print(row(cloud, f"{category} e2e (default)", "one decode, turned 90 degrees about up", x @ TURN_Y.T,
                  category, model, args.seed), flush=True)
    print(f"\ncommand: python {' '.join(sys.argv)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
