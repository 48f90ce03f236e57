"""Training throughput of the ShapeAssembly VAE: the per-tree pass against the batched pass, shapes per second.

One training step is forward, loss, backward and an Adam step. ``per-tree`` is the reference's loop: each
shape is its own step through ``VAE.forward`` and ``program_loss``. Adam is torch's fused one, as
``VAEModule`` uses it. ``batched B`` steps once per B shapes
through ``TreeBatch`` (plan built from the trees, as the DataLoader's collate does), ``batch_forward`` and
``batch_loss`` (the mean over the B shapes). The shapes are the first ``--shapes`` of the category's train
split, drawn in a seeded shuffle, so every setting sees the same ones; one warm-up pass runs first.

``--curve SECONDS`` then trains a fresh model (the same initial weights) for SECONDS of wall clock at each
batch size with the spec's Adam (lr 1e-4, eps 1e-6) and reports the steps taken, the shapes seen and the
mean loss per shape (z = mu) of ``--val`` other shapes of the train split: which batch size gets furthest in
equal time (early training only).

Usage::

    OMP_NUM_THREADS=1 python bench/bench_vae_train.py [--category chair] [--hidden 256] [--shapes 192]
        [--batch 1 8 32] [--threads 1] [--device cpu] [--curve 45 --val 64]
"""

from __future__ import annotations

import argparse
import os
import platform
import random
import sys
import time

import torch

import shapeprog
from shapeprog import corpus
from shapeprog.vae import VAE, program_loss, program_to_tree
from shapeprog.vae.batch import TreeBatch, batch_forward, batch_loss


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def per_tree(vae, opt, trees, device) -> float:
    t0 = time.perf_counter()
    for t in trees:
        total, _ = program_loss(vae(t.to(device)), t.to(device))
        opt.zero_grad()
        total.backward()
        opt.step()
    _sync(device)
    return time.perf_counter() - t0


def batched(vae, opt, trees, size, device) -> tuple[float, float]:
    """(seconds in all, seconds building plans)."""
    plan = 0.0
    t0 = time.perf_counter()
    for k in range(0, len(trees), size):
        p0 = time.perf_counter()
        batch = TreeBatch(trees[k:k + size]).to(device)
        plan += time.perf_counter() - p0
        total, _ = batch_loss(batch_forward(vae, batch), batch)
        opt.zero_grad()
        total.mean().backward()
        opt.step()
    _sync(device)
    return time.perf_counter() - t0, plan


def curve(trees, held, hidden, size, seconds, device) -> tuple[int, int, float]:
    """(steps, shapes seen, held-out loss per shape) after ``seconds`` of training at batch ``size``."""
    torch.manual_seed(0)
    vae = VAE(hidden).to(device)
    opt = torch.optim.Adam(vae.parameters(), lr=1e-4, eps=1e-6, fused=True)
    order = torch.Generator().manual_seed(1)
    steps = seen = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        perm = torch.randperm(len(trees), generator=order).tolist()
        for k in range(0, len(perm), size):
            batch = TreeBatch([trees[i] for i in perm[k:k + size]]).to(device)
            total, _ = batch_loss(batch_forward(vae, batch), batch)
            opt.zero_grad()
            total.mean().backward()
            opt.step()
            steps, seen = steps + 1, seen + batch.size
            if time.perf_counter() - t0 >= seconds:
                break
    with torch.no_grad():
        batch = TreeBatch(held).to(device)
        loss = float(batch_loss(batch_forward(vae, batch, sample=False), batch)[0].mean())
    return steps, seen, loss


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", default="chair", choices=corpus.CATEGORIES)
    ap.add_argument("--hidden", type=int, default=256, help="hidden_dim of the VAE (the reference's 256)")
    ap.add_argument("--shapes", type=int, default=192, help="shapes per measurement")
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 8, 32], help="batched sizes to measure")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--curve", type=float, default=0.0, help="seconds of training per batch size (0: skip)")
    ap.add_argument("--val", type=int, default=64, help="held-out shapes of the --curve loss")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}, device {device}, load average {os.getloadavg()[0]:.1f}")
    ids = corpus.ids(args.category, "train")
    random.Random(0).shuffle(ids)

    def load(chosen):
        return [program_to_tree(shapeprog.parse(corpus.read(args.category, i), f"{args.category}/{i}.txt"))
                for i in chosen]

    held, rest = ids[: args.val], ids[args.val:]
    trees = load(rest[: args.shapes])
    nodes = sum(len(list(t.nodes())) for t in trees)
    rows = sum(n.lines.shape[0] for t in trees for n, _ in t.nodes())
    print(f"# {len(trees)} {args.category} shapes: {nodes / len(trees):.1f} nodes and {rows / len(trees):.1f} lines "
          f"per shape; hidden_dim {args.hidden}; one step = forward + loss + backward + Adam (fused)")

    torch.manual_seed(0)
    vae = VAE(args.hidden).to(device)
    opt = torch.optim.Adam(vae.parameters(), lr=1e-4, eps=1e-6, fused=True)  # as VAEModule on CPU and CUDA
    warm = trees[: min(16, len(trees))]
    per_tree(vae, opt, warm, device)
    secs = per_tree(vae, opt, trees, device)
    base = len(trees) / secs
    print(f"per-tree (batch 1, VAE.forward + program_loss): {base:7.1f} shapes/s")
    for size in args.batch:
        batched(vae, opt, warm, size, device)
        secs, plan = batched(vae, opt, trees, size, device)
        rate = len(trees) / secs
        print(f"batched {size:3d} (TreeBatch + batch_forward + batch_loss): {rate:7.1f} shapes/s "
              f"({rate / base:4.1f}x per-tree; plan building {100 * plan / secs:.0f}% of the time)")
    if args.curve > 0:
        train, held = load(rest), load(held)
        print(f"# {args.curve:g} s of training per batch size on {len(train)} shapes; loss per shape of {len(held)} "
              f"held-out shapes (z = mu)")
        for size in sorted({1, *args.batch}):
            steps, seen, loss = curve(train, held, args.hidden, size, args.curve, device)
            print(f"batch {size:3d}: {steps:5d} steps, {seen:5d} shapes, held-out loss {loss:8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
