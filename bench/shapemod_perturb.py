"""ShapeMOD's perturbation study (the paper's Fig. 7): FD to the validation set against the noise sigma
added to the continuous parameters of programs without macros and with a ShapeMOD library.

Protocol (``docs/shapemod.md``, "Perturbation study"): ``--n`` shapes drawn at random (``--seed``) from the
category's train split are refactored twice, with the base library (No Macros: every float of the
ShapeAssembly lines) and with the ShapeMOD library (the macro calls' free floats); a shape either fails is
left out of both. For each sigma, every continuous parameter (not the bbox lines, not translate counts)
gets ``sigma * N(0, 1)`` (``shapeprog.macros.perturb``), the programs are executed, 2,500 surface points
per shape are sampled and the shipped PointNet classifier's features (``shapeprog/weights/pointnet_cls.pt``,
the generation tables' FD) are compared with the val split's by the Fréchet distance. ``--repeats`` noise
draws per sigma give the mean and the spread (min-max) of FD; the script also counts, per draw, the shapes
whose bounding-box diagonal grew beyond twice the unperturbed one (FD is dominated by those at large sigma).

    python bench/shapemod_perturb.py --category chair --n 500 --repeats 3 \\
        --png docs/figures/shapemod_perturbation.png
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch

from shapeprog import corpus
from shapeprog.vae.genmetrics import classifier_clouds, classifier_features, execute_samples, frechet_distance, gaussian_fit
from shapeprog.macros import Library, hierarchy, load_library
from shapeprog.macros.perturb import PerturbablePrograms
from shapeprog.macros.refactored import refactor_corpus
from shapeprog.vae.pointnet import load_classifier
from shapeio.files import atomic_write

SIGMAS = (0.0, 0.01, 0.025, 0.05, 0.1, 0.15, 0.2)
#: A perturbed shape whose bounding-box diagonal exceeds this many times its unperturbed one is counted as
#: blown up (FD is dominated by a few such shapes at large sigma).
BLOWN_UP = 2.0


def _diagonals(corners) -> np.ndarray:
    return np.array([float((c.reshape(-1, 3).max(0).values - c.reshape(-1, 3).min(0).values).norm())
                     for c in corners])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", default="chair", choices=corpus.CATEGORIES)
    ap.add_argument("--library", help="a shipped library's category or a library file (default: --category)")
    ap.add_argument("--n", type=int, default=500, help="train shapes perturbed (random subset)")
    ap.add_argument("--sigmas", type=float, nargs="+", default=list(SIGMAS))
    ap.add_argument("--repeats", type=int, default=3, help="noise draws per sigma")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--png", type=Path, help="write the plot here (needs matplotlib)")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    print("command: python bench/shapemod_perturb.py " + " ".join(shlex.quote(a) for a in
                                                                 (sys.argv[1:] if argv is None else argv)))
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, torch threads 1")
    t0 = time.perf_counter()
    name = args.library or args.category
    if Path(name).is_file():
        lib = Library.from_text(Path(name).read_text(encoding="utf-8"), name)
    else:
        lib = load_library(name)
    model = load_classifier()[0]

    # the validation set's features
    val = [p for _, p in corpus.load(args.category, "val")]
    val_corners, errors = execute_samples(val)
    val_corners = [c for c in val_corners if c is not None]
    val_fit = gaussian_fit(classifier_features(classifier_clouds(val_corners, seed=args.seed + 1), model))
    print(f"val: {len(val_corners)} {args.category} shapes ({len(errors)} failed) in {time.perf_counter() - t0:.0f} s")

    # the perturbed shapes, refactored without and with macros
    ids = corpus.ids(args.category, "train")
    pick = set(int(i) for i in np.random.default_rng(args.seed).choice(ids, size=min(args.n, len(ids)),
                                                                        replace=False))
    ids = [i for i in ids if i in pick]
    runs = {"No Macros": refactor_corpus(args.category, Library(), "base", ids=ids),
            "ShapeMOD": refactor_corpus(args.category, lib, name, ids=ids)}
    ok = [k for k, (a, b) in enumerate(zip(runs["No Macros"].shapes, runs["ShapeMOD"].shapes))
          if a.error is None and b.error is None]
    for k, (a, b) in enumerate(zip(runs["No Macros"].shapes, runs["ShapeMOD"].shapes)):
        if k not in ok:
            print(f"left out: {args.category}/{a.shape_id}: {a.error or b.error}")
    programs = {m: PerturbablePrograms([hierarchy.parse(r.shapes[k].text) for k in ok]) for m, r in runs.items()}
    n_cont = {m: float(np.mean(p.n_continuous)) for m, p in programs.items()}
    print(f"train shapes: {len(ok)} of {len(ids)} drawn (seed {args.seed}); continuous parameters per shape: "
          + ", ".join(f"{m} {v:.2f}" for m, v in n_cont.items()) + f"; ready in {time.perf_counter() - t0:.0f} s")
    orig, _ = execute_samples([corpus.read(args.category, ids[k]) for k in ok])
    fd_orig = frechet_distance(classifier_features(classifier_clouds(orig, seed=args.seed + 2), model), val_fit)
    print(f"FD of the {len(ok)} unperturbed corpus programs to val: {fd_orig:.3f}")

    fd = {m: [] for m in programs}
    blown = {m: [] for m in programs}  # per sigma and draw: shapes grown beyond BLOWN_UP x their diagonal
    diag0 = {m: _diagonals(pp.perturb(0.0, np.random.default_rng(0))) for m, pp in programs.items()}
    for s_i, sigma in enumerate(args.sigmas):
        for m, pp in programs.items():
            vals, big = [], []
            for r in range(args.repeats if sigma > 0 else 1):
                corners = pp.perturb(sigma, np.random.default_rng([args.seed, s_i, r]))
                feats = classifier_features(classifier_clouds(corners, seed=args.seed + 2 + r), model)
                vals.append(frechet_distance(feats, val_fit))
                big.append(int((_diagonals(corners) > BLOWN_UP * diag0[m]).sum()))
            fd[m].append(vals)
            blown[m].append(big)
        print(f"sigma {sigma:g}: " + ", ".join(f"{m} {np.mean(fd[m][-1]):.3f}" for m in programs)
              + f"  ({time.perf_counter() - t0:.0f} s)", flush=True)

    seconds = time.perf_counter() - t0
    print(f"\n{args.category}: FD to the val split ({len(val_corners)} shapes) of {len(ok)} perturbed train shapes; "
          f"mean over {args.repeats} noise draws (min-max); {seconds:.0f} s\n")
    print("| sigma | " + " | ".join(f"FD {m}" for m in programs) + " | "
          + " | ".join(f"blown up, {m}" for m in programs) + " |\n|---|" + "---|" * (2 * len(programs)))
    for s_i, sigma in enumerate(args.sigmas):
        cells = []
        for m in programs:
            v = fd[m][s_i]
            cells.append(f"{np.mean(v):.3f}" + (f" ({min(v):.3f}-{max(v):.3f})" if len(v) > 1 else ""))
        for m in programs:
            cells.append(" / ".join(str(b) for b in blown[m][s_i]))
        print(f"| {sigma:g} | " + " | ".join(cells) + " |")
    print(f"\n'blown up': shapes (of {len(ok)}) whose bounding-box diagonal grew beyond {BLOWN_UP:g}x the "
          "unperturbed one, per noise draw.")
    result = {"category": args.category, "library": name, "n": len(ok), "seed": args.seed, "repeats": args.repeats,
              "sigmas": args.sigmas, "fd": fd, "fd_unperturbed_corpus": fd_orig,
              "blown_up": blown, "blown_up_factor": BLOWN_UP, "continuous_per_shape": n_cont,
              "val_shapes": len(val_corners), "seconds": round(seconds, 1)}
    if args.json:
        from shapeio import atomic_write
        atomic_write(args.json, json.dumps(result, indent=1) + "\n")
        print(f"\nwrote {args.json}")
    if args.png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5.5, 4), dpi=100)
        for m, style in zip(programs, ("o--", "s-")):
            mean = [np.mean(v) for v in fd[m]]
            lo = [min(v) for v in fd[m]]
            hi = [max(v) for v in fd[m]]
            ax.plot(args.sigmas, mean, style, ms=4, label=f"{m} ({n_cont[m]:.1f} params/shape)")
            ax.fill_between(args.sigmas, lo, hi, alpha=0.2)
        ax.set_xlabel("sigma (noise std. dev. added to continuous parameters)")
        ax.set_ylabel("FD to the val set (log scale)")
        ax.set_yscale("log")
        ax.set_title(f"{args.category}: {len(ok)} train shapes, {args.repeats} draws per sigma")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        args.png.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(args.png, lambda f: fig.savefig(f, format="png"))
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
