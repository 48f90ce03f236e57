"""ShapeCoder's recognition network: training and sampling speed on a shipped library.

Training: pairs per second on the dreams of the library, three ways in one run: every batch padded to the network's full conditioning length (144 tokens, the code before the
padding was cut), each batch cut to its longest scene (plain shuffled batches, ``TrainConfig(bucket=False)``),
and cut batches of scenes of similar length (``bucket=True``, the default). Also the held-out loss after
the same number of seconds of training each way, from the same initial weights.

Sampling (the wake's search): samples per second of batches of 64 for the first ``--scenes`` discovery shapes,
with the network trained above, incremental decoding (the default) against decoding the whole sequence at
every step (``sample(..., incremental=False)``); both give the same samples (counted).

Usage::

    python bench/bench_recnet.py [--category chair] [--dreams 400] [--seconds 60] [--threads 1] [--scenes 20]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import torch

from shapeprog.coder import data, load_library
from shapeprog.coder.dream import dream
from shapeprog.coder.lang import to_text
from shapeprog.coder.recnet import NetConfig, RecognitionNet, sample
from shapeprog.coder.vocab import Vocab
from shapeprog.coder.train import TrainConfig, batch_loss, batches, tensorize


def _full_loss(model, b):
    """The loss over the full padded conditioning length (no cut)."""
    t = int((b.targets != -100).sum(1).max())
    tl, vl = model(b.ranks, b.fields, b.cmask, b.tokens[:, :t], b.tok_ranks[:, :t])
    vl = vl.masked_fill(~(torch.arange(vl.shape[-1])[None] < b.n_values[:, None])[:, None, :], -1e9)
    ce = torch.nn.functional.cross_entropy
    return ce(tl.reshape(-1, tl.shape[-1]), b.targets[:, :t].reshape(-1), ignore_index=-100) + ce(
        vl.reshape(-1, vl.shape[-1]), b.target_ranks[:, :t].reshape(-1), ignore_index=-100)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", default="chair", choices=data.CATEGORIES)
    ap.add_argument("--dreams", type=int, default=400, help="valid dreams per function")
    ap.add_argument("--seconds", type=float, default=60.0, help="training seconds per way")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--scenes", type=int, default=20, help="scenes to sample from")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__} ({args.threads} "
          f"threads), load {os.getloadavg()[0]:.1f}")
    lib = load_library(args.category)
    t0 = time.time()
    d = dream(lib, args.dreams, 42, [s.prims for s in data.load(args.category)[:400]])
    vocab = Vocab.of(lib)
    torch.manual_seed(0)
    init = RecognitionNet(NetConfig(len(vocab), dropout=0.1))
    b = tensorize(d.pairs, vocab, init.cfg.inputs, lib)
    n_val = len(b) // 10
    perm = torch.randperm(len(b), generator=torch.Generator().manual_seed(0))
    val, tr = b.take(perm[:n_val]), b.take(perm[n_val:])
    lengths = tr.cmask.sum(1)
    print(f"# {len(b)} pairs from {args.dreams} dreams per function ({time.time() - t0:.0f} s); scene length "
          f"(conditioning tokens) mean {lengths.float().mean():.1f}, max {int(lengths.max())} of {init.cfg.inputs}")
    rows = []
    for name, loss_fn, bucket in (("padded to 144", _full_loss, False), ("cut, shuffled", batch_loss, False),
                                  ("cut, bucketed (default)", batch_loss, True)):
        model = RecognitionNet(init.cfg)
        model.load_state_dict(init.state_dict())
        opt = torch.optim.Adam(model.parameters(), lr=args.lr)
        g = torch.Generator().manual_seed(1)
        seen, t0 = 0, time.perf_counter()
        model.train()
        while time.perf_counter() - t0 < args.seconds:
            for idx in batches(lengths, TrainConfig().batch, g, bucket):
                loss = loss_fn(model, tr.take(idx))
                opt.zero_grad()
                loss.backward()
                opt.step()
                seen += len(idx)
                if time.perf_counter() - t0 >= args.seconds:
                    break
        secs = time.perf_counter() - t0
        model.eval()
        with torch.no_grad():
            vl = sum(float(batch_loss(model, val.take(slice(s, s + 256)))) * len(val.take(slice(s, s + 256)))
                     for s in range(0, n_val, 256)) / n_val
        rows.append((name, seen / secs, seen / len(tr), vl))
        print(f"# {name}: {seen / secs:.0f} pairs/s, {seen / len(tr):.2f} epochs, held-out loss {vl:.3f}", flush=True)
    print("\n| batches | pairs / s | ratio | epochs in the budget | held-out loss |\n|---|---:|---:|---:|---:|")
    for name, rate, ep, vl in rows:
        print(f"| {name} | {rate:.0f} | {rate / rows[0][1]:.2f} | {ep:.2f} | {vl:.3f} |")
    shapes = [s.prims for s in data.load(args.category)[:args.scenes] if len(s.prims) <= model.cfg.max_prims]
    got, secs = {}, {}
    for incremental in (False, True):
        t0 = time.perf_counter()
        got[incremental] = [to_text(e) for k, p in enumerate(shapes)
                            for e in sample(model, vocab, p, 64, torch.Generator().manual_seed(k),
                                            incremental=incremental)]
        secs[incremental] = time.perf_counter() - t0
    same = sum(a == b for a, b in zip(got[False], got[True]))
    print(f"\n| sampling ({len(shapes)} scenes x 64) | samples / s | ratio |\n|---|---:|---:|")
    print(f"| whole sequence every step | {len(got[False]) / secs[False]:.0f} | 1.00 |")
    print(f"| incremental (default) | {len(got[True]) / secs[True]:.0f} | {secs[False] / secs[True]:.2f} |")
    print(f"\n# identical samples: {same} of {len(got[True])}")


if __name__ == "__main__":
    main()
