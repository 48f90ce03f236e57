"""Speed of the neural parsers: beam-search images per second and supervised training samples per second.

    python bench/bench_csgnet.py --threads 2
    python bench/bench_csgnet.py --threads 2 --weights runs/csgnetstack2d_small/checkpoints/last.ckpt

Beam search: the shipped 2D model (or ``--weights``) decodes synthetic targets with k = 10, ``--batch``
images at a time, including rendering every beam's program (what ``infer`` does before scoring). The
targets are programs of ``--lengths`` in equal counts (default: 3 to 13, the test split's mix; ``--lengths
13`` is the slowest case, every beam decoding to the last step). Training: one optimiser step (teacher-forced forward, backward, Adam) on a mixed-length
batch of the configured size, targets and stack traces rendered inside the step as in training.
"""
from __future__ import annotations

import argparse
import shlex
import os
import platform
import sys
import time

import numpy as np
import torch

from csgnet.synth import sample_programs
from csgnet.decode import beam_search
from csgnet.inference import load_model, load_pretrained
from csgnet.renderer import render_programs, render_tokens
from csgnet.vocab import vocabulary


def _device(name):
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


def bench_beam(model, n: int, batch: int, width: int, constrained: bool, device, lengths=(13,)) -> float:
    rng = np.random.default_rng(0)
    vocab = vocabulary(2)
    progs = []
    for i, length in enumerate(lengths):  # equal counts, interleaved so that every batch mixes them
        progs += [vocab.text(r) for r in sample_programs(2, length, n // len(lengths) + (i < n % len(lengths)), rng)]
    order = np.argsort(np.arange(len(progs)) % (n // len(lengths) + 1), kind="stable")
    progs = [progs[i] for i in order]
    targets = render_programs(progs, 2).to(device)
    beam_search(model, targets[:batch], width, constrained=constrained)  # warm-up
    if device == "cuda":
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    for lo in range(0, n, batch):
        d = beam_search(model, targets[lo: lo + batch], width, constrained=constrained)
        render_tokens(d.flat_tokens(), 2, d.lengths.flatten())
    if device == "cuda":
        torch.cuda.synchronize()
    return n / (time.perf_counter() - t0)


def bench_train(dim: int, stack: bool, size: str, overrides: dict, batch: int, steps: int, device) -> float:
    # Lightning (under csgnet.train) is imported only when training is timed: --skip-train runs without it
    from csgnet.train.streams import MixedLengthBatches
    from csgnet.train.supervised import DEFAULT_LENGTHS, CSGNetModule

    m = CSGNetModule(dim=dim, stack=stack, size=size, model=overrides).to(device)
    opt = torch.optim.Adam(m.parameters(), lr=1e-3)
    lengths = DEFAULT_LENGTHS[dim]
    # one batch of the training stream (programs sampled on the fly, equal counts per length)
    tok, lens = next(iter(MixedLengthBatches(dim, lengths, batch, 1, max(lengths), tables=None, seed=0)))
    tok, lens = tok.to(device), lens.to(device)
    times = []
    for i in range(steps + 1):
        t0 = time.perf_counter()
        loss, _, _ = m._loss(tok, lens, m.augment)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if device == "cuda":
            torch.cuda.synchronize()
        if i:
            times.append(time.perf_counter() - t0)
    return tok.shape[0] / float(np.median(times))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--weights", nargs="+", default=None,
                    help="2D weights files for the beam benchmark, optionally LABEL=PATH (default: the shipped default)")
    ap.add_argument("--out", default=None, help="also write the beam-search figures as a result file (JSON)")
    ap.add_argument("--images", type=int, default=200)
    ap.add_argument("--batch", type=int, default=16, help="images decoded together (default 16, infer's)")
    ap.add_argument("--width", type=int, default=10)
    ap.add_argument("--constrained", action="store_true")
    ap.add_argument("--lengths", type=int, nargs="+", default=[3, 5, 7, 9, 11, 13],
                    help="target program lengths, equal counts (default: 3 to 13)")
    ap.add_argument("--train-steps", type=int, default=3)
    ap.add_argument("--skip-train", action="store_true")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = _device(args.device)
    print(f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch "
          f"{torch.__version__}, threads {torch.get_num_threads()}, device {device}, "
          f"load average {os.getloadavg()[0]:.2f}")
    rows = []
    for spec in args.weights or [None]:
        label, _, path = (spec or "").rpartition("=")
        model = (load_model(path) if path else load_pretrained(2)).to(device)
        name = label or (("CSGNetStack" if model.config.stack else "CSGNet") + f" hidden {model.config.hidden}")
        ips = bench_beam(model, args.images, args.batch, args.width, args.constrained, device, args.lengths)
        print(f"beam search k={args.width} ({name}, batch {args.batch}, targets of lengths "
              f"{', '.join(map(str, args.lengths))}"
              f"{', constrained' if args.constrained else ''}): {ips:.1f} images/s")
        rows.append({"model": name, "beam": args.width, "batch": args.batch, "threads": torch.get_num_threads(),
                     "images_per_s": ips})
    if args.out:
        from shapeio.results import column, make_result, write_result

        cols = [column("model", "model"), column("beam", "beam width"), column("batch", "images per batch"),
                column("threads", "threads"), column("images_per_s", "images/s", 1)]
        note = (f"{args.images} synthetic targets, lengths {', '.join(map(str, args.lengths))} in equal counts; every "
                f"beam's program rendered (what infer does before scoring); device {device}.")
        command = "python " + shlex.join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:]))
        print(f"wrote {write_result(args.out, make_result('Beam-search decoding speed', cols, rows, [note], command))}")
    if not args.skip_train:
        for dim, stack, size, over, batch in [
                (2, False, "small", {}, 96), (2, True, "small", {}, 96),
                (2, True, "small", {"input_pool": 2, "channels": [8, 16, 32]}, 96),
                (2, False, "paper", {}, 100), (3, False, "small", {}, 48), (3, True, "small", {}, 48)]:
            sps = bench_train(dim, stack, size, over, batch, args.train_steps, device)
            label = f"{'CSGNetStack' if stack else 'CSGNet'} {dim}D {size}{' ' + str(over) if over else ''}"
            print(f"training {label}, batch {batch}: {sps:.1f} samples/s")
    print("command: python " + " ".join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
