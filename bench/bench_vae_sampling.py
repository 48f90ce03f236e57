"""Unconditional generation with the ShapeAssembly VAE's validity-checked decoder: programs per second.

Three measurements on one model (random initialisation unless ``--weights``):

1. ``sample()``: latents z ~ N(0, I) decoded with rejection, up to ``--max-tries`` draws per sample.
   Prints valid programs per second, the share valid on the first draw and within ``--max-tries``, and
   the rejection rate (refused draws / all draws).
2. ``decode()`` without rejection on fresh latents: programs per second and lines skipped per program.
3. Corpus replay: ``--replay`` programs of the category are decoded through the validity rules while the
   real network runs every step and head the decoding needs (its outputs are replaced by the program's
   own lines). This is the work of a trained model that writes programs like the corpus, so its
   programs per second estimate the throughput of a trained model, which a random model cannot show
   (an untrained decoder almost never writes a valid program).

Usage::

    python bench/bench_vae_sampling.py [--hidden 256] [--n 100] [--weights PATH] [--category chair]

``--weights`` takes a weights file or a training checkpoint (:func:`shapeprog.vae.pretrained.load_model`).
"""
from __future__ import annotations

import argparse
import collections
import os
import platform
import random
import sys
import time

import torch

from shapeprog import corpus, parse
from shapeprog.vae import VAE, sample
from shapeprog.vae.pretrained import load_model
from shapeprog.vae.decode import DecodeOptions, InvalidSample, _decode_with, decode, decode_latent
from shapeprog.vae.step import _Net
from shapeprog.vae.replay import Replay
from shapeprog.vae.vectors import program_to_tree


class _Timed:
    """The real network running every call the decoding makes, with the replayed program's outputs."""

    def __init__(self, net, hidden_dim: int, generator: torch.Generator):
        self.net, self.replay, self.H, self.gen = net, Replay(), hidden_dim, generator

    def latent(self, tree):
        return (self.net.latent(torch.randn(self.H, generator=self.gen)), self.replay.latent(tree))

    def root_bbox(self, tree):
        self.net.root_bbox(torch.randn(self.H, generator=self.gen))
        return self.replay.root_bbox(tree)

    def begin(self, h, bbox_dims, depth):
        return (self.net.begin(h[0], bbox_dims, depth), self.replay.begin(h[1], bbox_dims, depth))

    def step(self, line, h, ctx):
        return (self.net.step(line, h[0], ctx[0]), self.replay.step(line, h[1], ctx[1]))

    def child(self, h, ctx):
        return (self.net.child(h[0], ctx[0]), self.replay.child(h[1], ctx[1]))

    def __getattr__(self, name):  # command, cubes, cuboid, attach, sym, squeeze, leaf
        real, fake = getattr(self.net, name), getattr(self.replay, name)

        def both(h, ctx, *args):
            real(h[0], ctx[0], *args)
            return fake(h[1], ctx[1], *args)

        return both


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hidden", type=int, default=256, help="hidden_dim of a randomly initialised model")
    ap.add_argument("--weights", default=None, help="a VAE weights file or training checkpoint to load instead")
    ap.add_argument("--n", type=int, default=100, help="samples for sample() and decode()")
    ap.add_argument("--max-tries", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--replay", type=int, default=100, help="corpus programs replayed (0: skip)")
    ap.add_argument("--category", default="chair", choices=corpus.CATEGORIES)
    args = ap.parse_args(argv)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}")
    torch.manual_seed(args.seed)
    vae = load_model(args.weights) if args.weights else VAE(args.hidden)
    H = vae.decoder.hidden_dim
    print(f"# model: hidden_dim {H}, {'weights ' + args.weights if args.weights else 'random initialisation'}")

    t0, c0 = time.perf_counter(), time.process_time()
    out = sample(vae, args.n, seed=args.seed, max_tries=args.max_tries)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    valid = [d for d in out if d.tries <= args.max_tries]
    draws = sum(min(d.tries, args.max_tries) for d in out)
    refused = draws - len(valid)
    print(f"sample(n={args.n}, max_tries={args.max_tries}): {wall:.2f} s wall, {cpu:.2f} s CPU; "
          f"{len(valid) / wall:.1f} valid programs/s ({len(out) / wall:.1f} programs/s incl. fallbacks, "
          f"{draws / wall:.1f} draws/s)")
    print(f"  valid on the first draw {sum(d.tries == 1 for d in out) / len(out):.1%}, within {args.max_tries} draws "
          f"{len(valid) / len(out):.1%}; rejection rate {refused / draws:.1%} of {draws} draws; "
          f"statements per valid program {sum(d.text.count(chr(9)) for d in valid) / max(len(valid), 1):.1f}")

    gen = torch.Generator().manual_seed(args.seed + 1)
    zs = [torch.randn(H, generator=gen) for _ in range(args.n)]
    t0 = time.perf_counter()
    res = [decode(vae, z) for z in zs]
    wall = time.perf_counter() - t0
    print(f"decode() without rejection: {len(res) / wall:.1f} programs/s; lines skipped per program "
          f"{sum(d.skipped for d in res) / len(res):.1f}; statements per program "
          f"{sum(d.text.count(chr(9)) for d in res) / len(res):.1f}")
    reasons = collections.Counter()
    for z in zs:
        try:
            decode_latent(vae.decoder, z, reject=True)
        except InvalidSample as e:
            reasons[f"node {e.node}, step {e.step}: {e.reason}"] += 1
    print("  why the same latents are refused with rejection: "
          + "; ".join(f"{n} x {r}" for r, n in reasons.most_common(3)))

    if args.replay > 0:
        ids = corpus.ids(args.category, "all")
        random.Random(args.seed).shuffle(ids)
        ids = ids[:args.replay]
        trees = [program_to_tree(parse(corpus.read(args.category, i), f"{args.category}/{i}.txt"), dtype=torch.float64)
                 for i in ids]
        opts = DecodeOptions()
        vae.eval()
        with torch.no_grad():
            net = _Timed(_Net(vae.decoder), H, torch.Generator().manual_seed(args.seed))
            t0, c0 = time.perf_counter(), time.process_time()
            refused = []
            for i, tree in zip(ids, trees):
                try:
                    _decode_with(net, tree, True, opts)
                except InvalidSample:
                    refused.append(f"{args.category}/{i}")
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            t0 = time.perf_counter()
            for tree in trees:
                _decode_with(Replay(), tree, False, opts)
            rules = time.perf_counter() - t0
        print(f"corpus replay ({len(trees)} {args.category} programs, network of hidden_dim {H} run at every step): "
              f"{len(trees) / wall:.1f} programs/s ({cpu / len(trees) * 1e3:.1f} ms CPU each); "
              f"{1 - len(refused) / len(trees):.1%} pass every rule; rules and execution alone "
              f"{rules / len(trees) * 1e3:.1f} ms per program")
        print(f"  refused: {', '.join(refused) or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
