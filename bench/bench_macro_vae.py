"""The VAE on macro programs (ShapeMOD Appendix C): tree round trip on the shipped refactored chairs, and the
training step against the base model's.

* Round trip: every shipped macro-refactored chair (or the first ``--roundtrip`` of them) goes program ->
  line-vector tree (``macro_program_to_tree``) -> program (``tree_to_macro_program``) -> expansion ->
  execution; the leaf cuboids (sorted) are compared with the original's. Prints how many were compared,
  how many differ in their number of leaves, and the largest corner difference.
* Step time: one training step (forward, loss, backward, fused Adam), ``--hidden``, on the same ``--shapes``
  chairs as macro programs (``MacroVAE``) and as base programs (``VAE``): one shape per step tree by tree
  (``macro_program_loss`` / ``program_loss`` of the model's forward), and ``--batch`` shapes per step through
  the level-by-level batched passes (``macro_batch_loss`` / ``batch_loss`` of ``batch_forward``, what
  ``train.py`` runs); one warm-up pass first. The ratios compare rows of the same run.

Usage::

    OMP_NUM_THREADS=1 python bench/bench_macro_vae.py [--roundtrip 0] [--shapes 64] [--hidden 256] [--batch 8]
"""
from __future__ import annotations

import argparse
import platform
import sys
import time

import torch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--roundtrip", type=int, default=0, help="chairs in the round trip (0: all shipped)")
    ap.add_argument("--shapes", type=int, default=64, help="chairs in the step timing")
    ap.add_argument("--hidden", type=int, default=256)
    ap.add_argument("--batch", type=int, default=8, help="shapes per step of the batched passes")
    args = ap.parse_args()
    torch.set_num_threads(1)

    import shapeprog
    from shapeprog import corpus
    from shapeprog.macros import load_library
    from shapeprog.macros.execute import execute_hierarchy
    from shapeprog.macros.refactored import load_refactored
    from shapeprog.vae.batch import TreeBatch, batch_forward, batch_loss
    from shapeprog.vae.macro_batch import MacroTreeBatch, macro_batch_loss
    from shapeprog.vae.layout import LineLayout, macro_program_to_tree, tree_to_macro_program
    from shapeprog.vae.losses import macro_program_loss, program_loss
    from shapeprog.vae.macro_model import MacroVAE
    from shapeprog.vae.model import VAE
    from shapeprog.vae.vectors import program_to_tree

    print(f"# {' '.join(sys.argv)}  ({platform.machine()}, torch {torch.__version__}, 1 thread)")
    lib = load_library("chair")
    layout = LineLayout(lib)
    print(f"layout: {layout}")
    t0 = time.perf_counter()
    progs, _ = load_refactored("chair")
    ids = list(progs)[: args.roundtrip] if args.roundtrip else list(progs)
    worst, leaf_mismatch, failed = 0.0, 0, 0
    for i in ids:
        h = progs[i]
        try:
            back = tree_to_macro_program(macro_program_to_tree(h, layout, f"chair/{i}.txt"), layout)
            a, b = execute_hierarchy(h, lib).corners, execute_hierarchy(back, lib).corners
        except ValueError as e:
            failed += 1
            print(f"chair/{i}: {e}")
            continue
        if a.shape != b.shape:
            leaf_mismatch += 1
            continue
        ka = torch.tensor(sorted(map(tuple, a.reshape(len(a), -1).tolist())))
        kb = torch.tensor(sorted(map(tuple, b.reshape(len(b), -1).tolist())))
        worst = max(worst, float((ka - kb).abs().max()) if len(ka) else 0.0)
    print(f"round trip: {len(ids)} chairs, {failed} failed, {leaf_mismatch} with another leaf count, largest "
          f"corner difference {worst:.2e} ({time.perf_counter() - t0:.1f} s)")

    train = {int(k) for k in corpus.ids("chair", "train")}
    chosen = [i for i in progs if i in train][: args.shapes]
    macro = [macro_program_to_tree(progs[i], layout) for i in chosen]
    base = [program_to_tree(shapeprog.parse(corpus.read("chair", i), f"chair/{i}.txt")) for i in chosen]
    per_tree = {"macro": lambda m, ts: sum(macro_program_loss(m(t), t, layout)[0] for t in ts),
                "base": lambda m, ts: sum(program_loss(m(t), t)[0] for t in ts)}
    batched = {"macro": lambda m, ts: macro_batch_loss(m, MacroTreeBatch(ts))[0].sum(),
               "base": lambda m, ts: batch_loss(batch_forward(m, TreeBatch(ts)), TreeBatch(ts))[0].sum()}
    times = {}
    for name, trees in (("macro", macro), ("base", base)):
        for mode, size, loss in (("per tree", 1, per_tree[name]), ("batched", args.batch, batched[name])):
            torch.manual_seed(0)
            model = MacroVAE(layout, args.hidden) if name == "macro" else VAE(args.hidden)
            opt = torch.optim.Adam(model.parameters(), lr=1e-4, eps=1e-6, fused=True)
            for timed in (False, True):
                t0 = time.perf_counter()
                for i in range(0, len(trees), size):
                    opt.zero_grad()
                    loss(model, trees[i:i + size]).backward()
                    opt.step()
                if timed:
                    s = time.perf_counter() - t0
                    times[name, mode] = s / len(trees)
                    print(f"{name}, {mode} ({size} per step): {len(trees)} chairs, {s / len(trees) * 1000:.1f} ms per "
                          f"shape, {len(trees) / s:.1f} shapes/s (hidden {args.hidden})")
    for name in ("macro", "base"):
        print(f"{name}: batched / per tree speed-up {times[name, 'per tree'] / times[name, 'batched']:.2f}x")
    print(f"batched: macro / base time per shape {times['macro', 'batched'] / times['base', 'batched']:.2f}")

if __name__ == "__main__":
    main()
