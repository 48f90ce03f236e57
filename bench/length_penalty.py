"""Choosing the price per primitive of the ``short`` refinement rule (``csgnet.rewrite.LENGTH_PENALTY``) on
the validation split of a synthetic dataset.

For each validation program (``--per-length`` per length) the script renders its target, decodes it with
beam search (``--beam``), takes the beam closest to the target as the start (``parse --select match``),
and then, for each price λ of ``--penalties``, runs the short refinement rule with that price
(``csgnet.refinement.refine_guarded(..., penalty=λ, use_fit=False)``: every valid beam refined, pruned, the
choice grafted and extended; what ``parse --refine --no-fit`` does: at a price near 0 fitting would draw
single cells, so the price is chosen without it and fitting uses the chosen one). It prints, per λ, the chosen programs' mean IoU, mean primitives, the mean
absolute difference from the true program's primitives, and the share of programs longer than the truth;
then the chosen λ: the largest price whose mean IoU is at most ``MAX_VAL_IOU_COST`` below λ = 0's (the shortest
programs for a bounded cost). The true programs' length is shown, not used: the generator's programs are
not the shortest that draw their shapes (its rules accept an operand that changes a tenth of the result).

    python -m csgnet generate --dim 2 --scale 0.01 --out data/synthetic2d
    python bench/length_penalty.py --dim 2 --data data/synthetic2d --per-length 20
    python bench/length_penalty.py --dim 3 --data data/synthetic --per-length 20
"""
from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time

import numpy as np
import torch

from csgnet import render
from csgnet.data import load_dataset
from csgnet.cli.common import is_valid_text
from csgnet.inference import infer, load_model, load_pretrained
from csgnet.lang import parse
from csgnet.refinement import refine_guarded
from csgnet.rewrite import LENGTH_PENALTY, MAX_VAL_IOU_COST

DEFAULT_PENALTIES = (0.0, 0.001, 0.0025, 0.005, 0.0075, 0.01, 0.015, 0.02, 0.03)


def choose_penalty(rows: list[dict], max_cost: float) -> float:
    """The largest λ of ``rows`` (one dict per λ with ``penalty`` and mean ``iou``) whose mean IoU is at most
    ``max_cost`` below that of λ = 0."""
    base = next(r for r in rows if r["penalty"] == 0.0)["iou"]
    return max(r["penalty"] for r in rows if r["iou"] >= base - max_cost)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2)
    ap.add_argument("--data", required=True, help="dataset folder written by `python -m csgnet generate`")
    ap.add_argument("--weights", default=None, help="weights file (default: the shipped default model)")
    ap.add_argument("--per-length", type=int, default=20)
    ap.add_argument("--beam", type=int, default=10)
    ap.add_argument("--views", type=int, choices=(1, 2, 4, 8, 16), default=1,
                    help="3D: mirror views per decode (csgnet.decode.VIEWS; default 1; parse decodes 3D with 8)")
    ap.add_argument("--penalties", type=float, nargs="+", default=list(DEFAULT_PENALTIES))
    ap.add_argument("--refine-iters", type=int, default=None, help="Powell iterations (default: to convergence)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=None, help="also write the table as a result file (JSON)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    if 0.0 not in args.penalties:
        args.penalties = [0.0] + list(args.penalties)
    model = load_model(args.weights) if args.weights else load_pretrained(args.dim)
    programs = [p for ps in load_dataset(args.data, args.dim, "val").values() for p in ps[: args.per_length]]
    targets = render([p.text() for p in programs], args.dim)
    t0 = time.process_time()
    starts = infer(model, targets, beam=args.beam, select="match", precision="float32",  # the same on every CPU
                   views=args.views if args.dim == 3 else 1)
    per_penalty: dict[float, list[tuple[float, int, int]]] = {lam: [] for lam in args.penalties}
    for prog, target, start in zip(programs, targets, starts):
        valid = [parse(b, args.dim) for b in start.beams if is_valid_text(b, args.dim)]
        for lam in args.penalties:
            if not start.valid:
                per_penalty[lam].append((0.0, 0, len(prog.draws)))
                continue
            ref = refine_guarded(start.program, valid, target, maxiter=args.refine_iters, penalty=lam,
                                 use_fit=False)
            per_penalty[lam].append((ref.after[0], len(ref.program.draws), len(prog.draws)))
    seconds = time.process_time() - t0
    rows = []
    for lam, vals in per_penalty.items():
        a = np.asarray(vals, dtype=float)
        rows.append({"penalty": lam, "iou": a[:, 0].mean(), "primitives": a[:, 1].mean(),
                     "length_error": np.abs(a[:, 1] - a[:, 2]).mean(), "longer": (a[:, 1] > a[:, 2]).mean(),
                     "truth": a[:, 2].mean()})
    print(f"# {args.dim}D validation programs: {len(programs)} ({args.per_length} per length) of {args.data}, "
          f"beam {args.beam}, model {args.weights or 'shipped default'}; {seconds:.0f} CPU s")
    print(f"# machine: {platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}, threads {args.threads}")
    print("| λ (IoU per primitive) | mean IoU | mean primitives | true primitives | mean abs. length error "
          "| longer than the truth |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['penalty']:g} | {100 * r['iou']:.2f} | {r['primitives']:.2f} | {r['truth']:.2f} "
              f"| {r['length_error']:.3f} | {100 * r['longer']:.1f}% |")
    chosen = choose_penalty(rows, MAX_VAL_IOU_COST)
    print(f"chosen λ: {chosen:g} (the largest whose mean IoU is at most {100 * MAX_VAL_IOU_COST:g} points below "
          f"λ = 0's); csgnet.rewrite.LENGTH_PENALTY[{args.dim}] is {LENGTH_PENALTY[args.dim]:g}")
    command = "python " + shlex.join(sys.argv if argv is None else [sys.argv[0], *argv])
    print("command: " + command)
    if args.out:
        from shapeio.results import column, make_result, write_result

        cols = [column("penalty", "λ (IoU per primitive)"), column("iou", "mean IoU", 2, 100.0),
                column("primitives", "mean primitives", 2), column("truth", "true primitives", 2),
                column("length_error", "mean abs. length error", 3), column("longer", "longer than the truth (%)", 1, 100.0)]
        views = f"{args.views} mirror views, " if args.dim == 3 and args.views > 1 else ""
        notes = [f"{len(programs)} validation programs ({args.per_length} per length) of {args.data}, beam {args.beam}, "
                 f"{views}model {args.weights or 'the shipped default'}. Chosen: λ = {chosen:g}, the largest whose mean IoU is at "
                 f"most {100 * MAX_VAL_IOU_COST:g} points below λ = 0's."]
        print(f"wrote {write_result(args.out, make_result(f'The short rule: price per primitive ({args.dim}D)', cols, rows, notes, command))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
