"""How well does the VAE reconstruct held-out shapes: encode -> decode of the corpus val split, F-score at 0.03.

For the first ``--shapes`` programs of a category's val split (the test split of every ShapeAssembly table), each
model encodes the program to its mean code and decodes it back (``decode_latent``, semantic validity, no
rejection: the VAE's reconstruction; one that decodes to nothing scores F 0). Both shapes are sampled (10,000
surface points each; the input's seeded by its id, the reconstruction's by ``--seed``),
mapped into the canonical frame of the input's cloud (AABB diagonal 2, the point-cloud tables' frame), and
scored with ``shapeprog.pointcloud.infer.shape_metrics``: F-score at 0.03, chamfer, rooted. It prints, per model,
the mean F-score, the mean chamfer x1000, % of reconstructions that decode to at least one cuboid, % rooted and
the mean leaf cuboids against the inputs', then the command; ``--out`` writes the same as a result file
(``shapeio.results``).

Usage::

    OMP_NUM_THREADS=1 python bench/vae_reconstruct.py --category chair --shapes 100 \\
        --weights shipped=shapeprog/weights/vae_chair.pt continued=runs_in_progress/vae_chair_cont.pt
"""
from __future__ import annotations

import argparse
import shlex
import sys

import numpy as np
import torch

from shapeio.results import column, make_result, markdown, write_result
from shapeprog import corpus
from shapeprog.execute import execute
from shapeprog.lang import parse
from shapeprog.pointcloud.data import corpus_cloud
from shapeprog.pointcloud.infer import shape_metrics
from shapeprog.pointcloud.normalize import normalize
from shapeprog.vae.decode import decode_latent, encode
from shapeprog.vae.pretrained import PRETRAINED, load_model, load_pretrained
from shapeprog.vae.validity import InvalidSample

POINTS = 10_000


def reconstruct_row(name: str, vae, category: str, ids: list[int], seed: int) -> dict:
    """One model's mean figures over the val programs ``ids``."""
    fs, cds, decoded, rooted, leaves, inputs = [], [], [], [], [], []
    for shape_id in ids:
        text = corpus.read(category, shape_id)
        target = corpus_cloud(category, shape_id, POINTS, seed)
        unit, t = normalize(target)
        try:
            corners = execute(decode_latent(vae.decoder, encode(vae, text, file=f"{category}/{shape_id}")).program).corners
        except (ValueError, InvalidSample):  # decoded to no program: F 0, nothing rooted
            corners = torch.zeros(0, 8, 3)
        back = torch.from_numpy(t.apply(corners.detach().double().numpy().reshape(-1, 3)).reshape(-1, 8, 3))
        m = shape_metrics(back, torch.from_numpy(unit), points=POINTS, seed=seed, stability=False)
        fs.append(m["fscore"])
        cds.append(np.nan if m["cd"] is None else m["cd"])
        decoded.append(len(corners) > 0)
        rooted.append(bool(m["rooted"]))
        leaves.append(len(corners))
        inputs.append(len(execute(parse(text)).corners))
    return {"model": name, "shapes": len(ids), "fscore": float(np.mean(fs)), "cd": 1000 * float(np.nanmean(cds)),
            "decoded": 100 * float(np.mean(decoded)), "rooted": 100 * float(np.mean(rooted)),
            "leaves": float(np.mean(leaves)), "input_leaves": float(np.mean(inputs))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--category", default="chair", choices=sorted(PRETRAINED))
    ap.add_argument("--weights", nargs="+", metavar="LABEL=FILE",
                    help="VAE weights files (default: the shipped model of the category)")
    ap.add_argument("--shapes", type=int, default=100, help="the first N programs of the val split")
    ap.add_argument("--seed", type=int, default=0, help="seed of the surface samples")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", help="write a result file (JSON)")
    args = ap.parse_args(argv)
    if args.shapes < 1:
        ap.error("--shapes must be at least 1")
    torch.set_num_threads(args.threads)
    ids = sorted(corpus.ids(args.category, "val"))[: args.shapes]
    rows = []
    for spec in args.weights or [None]:
        if spec is None:
            label, vae = f"shipped ({PRETRAINED[args.category]})", load_pretrained(args.category)
        else:
            label, sep, path = spec.partition("=")
            vae = load_model(path if sep else spec, category=args.category)
        rows.append(reconstruct_row(label, vae, args.category, ids, args.seed))
        r = rows[-1]
        print(f"{label}: F {r['fscore']:.1f}  CD x1000 {r['cd']:.1f}  decoded {r['decoded']:.1f} %  rooted "
              f"{r['rooted']:.1f} %  leaves {r['leaves']:.1f} (inputs {r['input_leaves']:.1f})", flush=True)
    command = shlex.join(["python", "bench/vae_reconstruct.py", *(sys.argv[1:] if argv is None else argv)])
    cols = [column("model", "model"), column("shapes", "shapes"), column("fscore", "F-score @0.03", 1),
            column("cd", "CD x1000", 1), column("decoded", "% decoded", 1), column("rooted", "% rooted", 1),
            column("leaves", "leaf cuboids", 1), column("input_leaves", "input leaf cuboids", 1)]
    notes = [f"{args.category}, the first {len(ids)} programs of the corpus val split; encode to the mean code, decode "
             "with semantic validity and no rejection; 10,000 surface points of each shape in the canonical frame of "
             "the input's cloud (AABB diagonal 2); F-score at 0.03, chamfer, rooted (shapeprog.pointcloud.infer."
             "shape_metrics)."]
    result = make_result(f"VAE reconstruction of held-out {args.category}s", cols, rows, notes=notes, command=command)
    if args.out:
        write_result(args.out, result)
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
