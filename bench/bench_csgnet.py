"""Speed of the neural parsers: beam-search images per second and supervised training samples per second.

    python bench/bench_csgnet.py --threads 2
    python bench/bench_csgnet.py --threads 2 --weights runs/csgnetstack2d_small/checkpoints/last.ckpt
    python bench/bench_csgnet.py --threads 2 --skip-train --precision float32 bfloat16 --rounds 3

Beam search: the shipped 2D model (or ``--weights``) decodes synthetic targets with k = 10, ``--batch``
images at a time, including rendering every beam's program (what ``infer`` does before scoring). The
targets are programs of ``--lengths`` in equal counts (default: 3 to 13, the test split's mix; ``--lengths
13`` is the slowest case, every beam decoding to the last step). ``--precision`` lists the decoders'
arithmetic to time (``csgnet.decode.PRECISIONS``): one row per model and precision; ``--rounds`` repeats the
timing, the precisions alternating within each round so that a load from other jobs falls on all of them, and
reports the median round (and, beside float32, the median per-round speed-up over it). Training: one optimiser step (teacher-forced forward, backward, Adam) on a mixed-length
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
from csgnet.decode import PRECISIONS, beam_search, native_bf16, resolve_precision
from csgnet.inference import load_model, load_pretrained
from csgnet.renderer import render_programs, render_tokens
from csgnet.vocab import vocabulary


def _device(name):
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


def beam_targets(n: int, device, lengths=(13,)) -> torch.Tensor:
    """``n`` rendered targets of programs of ``lengths``, equal counts, interleaved so that every batch mixes them."""
    rng = np.random.default_rng(0)
    vocab = vocabulary(2)
    progs = []
    for i, length in enumerate(lengths):  # equal counts, interleaved so that every batch mixes them
        progs += [vocab.text(r) for r in sample_programs(2, length, n // len(lengths) + (i < n % len(lengths)), rng)]
    order = np.argsort(np.arange(len(progs)) % (n // len(lengths) + 1), kind="stable")
    progs = [progs[i] for i in order]
    return render_programs(progs, 2).to(device)


def bench_beam(model, targets: torch.Tensor, batch: int, width: int, constrained: bool, device,
               precision: str = "float32", warm_up: bool = True) -> float:
    """Images per second of beam search over ``targets``, ``batch`` at a time, every beam rendered."""
    n = targets.shape[0]
    if warm_up:
        beam_search(model, targets[:batch], width, constrained=constrained, precision=precision)
    if device == "cuda":
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    for lo in range(0, n, batch):
        d = beam_search(model, targets[lo: lo + batch], width, constrained=constrained, precision=precision)
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


def _wait_policy() -> str:
    """``"; OMP_WAIT_POLICY=PASSIVE"`` when that variable is set (threads that sleep at barriers instead of
    spinning keep two threads usable on a CPU shared with other jobs), else ``""``."""
    policy = os.environ.get("OMP_WAIT_POLICY")
    return f"; OMP_WAIT_POLICY={policy}" if policy else ""


def _precision_label(precision: str, resolved: str) -> str:
    """``"bfloat16"``, or ``"auto (bfloat16)"`` for a choice the machine resolves."""
    return resolved if precision == resolved else f"{precision} ({resolved})"


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
    ap.add_argument("--precision", nargs="+", choices=PRECISIONS, default=["float32"],
                    help="decoding precisions to time, one row each per model (default float32; "
                    "csgnet.decode.PRECISIONS)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="timings per model and precision, the precisions alternating; the median is reported")
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
          f"load average {os.getloadavg()[0]:.2f}{_wait_policy()}")
    if args.rounds < 1:
        ap.error(f"--rounds must be at least 1, got {args.rounds}")
    precisions = list(dict.fromkeys(args.precision))  # each once, in the order given
    resolved = {p: resolve_precision(p, device) for p in precisions}
    targets = beam_targets(args.images, device, args.lengths)
    rows = []
    for spec in args.weights or [None]:
        label, _, path = (spec or "").rpartition("=")
        model = (load_model(path) if path else load_pretrained(2)).to(device)
        name = label or (("CSGNetStack" if model.config.stack else "CSGNet") + f" hidden {model.config.hidden}")
        times: dict[str, list[float]] = {p: [] for p in precisions}
        for r in range(args.rounds):
            for p in precisions:
                times[p].append(bench_beam(model, targets, args.batch, args.width, args.constrained, device, p,
                                           warm_up=r == 0))
        for p in precisions:
            ips = float(np.median(times[p]))
            row = {"model": name, "precision": _precision_label(p, resolved[p]), "beam": args.width,
                   "batch": args.batch, "threads": torch.get_num_threads(), "images_per_s": ips}
            line = (f"beam search k={args.width} ({name}, {row['precision']}, batch {args.batch}, targets of lengths "
                    f"{', '.join(map(str, args.lengths))}{', constrained' if args.constrained else ''}): "
                    f"{ips:.1f} images/s")
            if "float32" in times and len(precisions) > 1:  # per round: float32 timed beside it
                row["speedup"] = float(np.median(np.array(times[p]) / np.array(times["float32"])))
                line += f", {row['speedup']:.2f}x float32"
            print(line + (f" (median of {args.rounds}: {', '.join(f'{t:.1f}' for t in times[p])})"
                          if args.rounds > 1 else ""))
            rows.append(row)
    if args.out:
        from shapeio.results import column, make_result, write_result

        cols = [column("model", "model"), column("precision", "precision"), column("beam", "beam width"),
                column("batch", "images per batch"), column("threads", "threads"), column("images_per_s", "images/s", 1)]
        if any("speedup" in r for r in rows):
            cols.append(column("speedup", "× float32", 2))
        note = (f"{args.images} synthetic targets, lengths {', '.join(map(str, args.lengths))} in equal counts; every "
                f"beam's program rendered (what infer does before scoring); device {device}; precision "
                f"{', '.join(_precision_label(p, resolved[p]) for p in precisions)} (bfloat16: the model's layers "
                f"under bfloat16 autocast, scores in float32; native bfloat16 on this CPU: "
                f"{'yes' if native_bf16() else 'no'}); median of {args.rounds} round{'s' * (args.rounds > 1)}, "
                f"the precisions alternating{_wait_policy()}.")
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
