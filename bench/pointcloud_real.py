"""The real-geometry check: the shipped point-cloud models on the two vendored real clouds.

``comp_pc.obj`` (a table) and ``simp_pc.obj`` (a chair, by its look; the source calls both tables), from
``shapeprog.corpus.example_points``, are 10,000 points each sampled from real PartNet meshes, where every
training cloud was sampled from part cuboids. For each cloud and each shipped model of its category (the
default, the latent-regression model, the model of macro programs), ``infer`` runs with one decode, with
fitting and with the latent search, and the default model once more on the cloud turned 90 degrees about
its up axis (the front direction is not normalised). The script prints, per cloud and model, the F-score at
0.03 (canonical units, against the whole input cloud) of each decoding and whether every result is rooted and
stable, then the command; ``--out`` writes the same as a result file.

Usage::

    OMP_NUM_THREADS=1 python bench/pointcloud_real.py --out docs/results/pointcloud/real_clouds.json
"""
from __future__ import annotations

import argparse
import shlex
import sys

import numpy as np
import torch

from shapeio.results import column, make_result, markdown, write_result
from shapeprog import corpus
from shapeprog.pointcloud.infer import infer, load_model
from shapeprog.pointcloud.model import WEIGHTS

MODELS = {"e2e (default)": "pointcloud_e2e_{}.pt", "latent": "pointcloud_latent_{}.pt",
          "e2e, ShapeMOD macros": "pointcloud_e2e_{}_macros.pt"}
CLOUDS = {"comp_pc.obj": "table", "simp_pc.obj": "chair"}
TURN_Y = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # 90 degrees about +y (up)


DECODINGS = (("decode", "one decode", {}), ("fit", "+ Opt Program", {"fit": True}),
             ("search", "latent search", {"search": True}))


def metrics(x, category, model, seed, **kw) -> dict:
    """``infer``'s metrics of one cloud (the single decode, extended by ``kw``), with the stability test."""
    return infer(x, category=category, model=model, seed=seed, stability=True, **{"method": "decode", **kw}).metrics


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="also write the table as a result file (JSON, shapeio.results)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    rows = []
    for cloud, category in CLOUDS.items():
        x = corpus.example_points(cloud)
        for label, weights in MODELS.items():
            model = load_model(WEIGHTS / weights.format(category), category)
            found = {key: metrics(x, category, model, args.seed, **kw) for key, _, kw in DECODINGS}
            rows.append({"cloud": f"{cloud} ({category})", "model": label,
                         **{key: m["fscore"] for key, m in found.items()},
                         "rooted": all(m["rooted"] for m in found.values()),
                         "stable": all(m["stable"] for m in found.values())})
        model = load_model(WEIGHTS / MODELS["e2e (default)"].format(category), category)
        m = metrics(x @ TURN_Y.T, category, model, args.seed)
        rows.append({"cloud": f"{cloud} ({category})", "model": "e2e (default), the cloud turned 90 degrees about up",
                     "decode": m["fscore"], "fit": None, "search": None, "rooted": m["rooted"], "stable": m["stable"]})
    cols = [column("cloud", "cloud"), column("model", "model"),
            *(column(key, f"F-score, {name}", 1) for key, name, _ in DECODINGS),
            column("rooted", "all rooted"), column("stable", "all stable")]
    notes = ["F-score at 0.03 (canonical units) against the whole input cloud; rooted and stable of every result "
             f"of the row; seed {args.seed}."]
    result = make_result("Shipped point-cloud models on the two real clouds", cols, rows, notes=notes,
                         command=shlex.join(["python", "bench/pointcloud_real.py", *(sys.argv[1:] if argv is None
                                                                                     else argv)]))
    if args.out:
        write_result(args.out, result)
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
