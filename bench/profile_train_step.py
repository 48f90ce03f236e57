"""Where one supervised training step's time goes, per model: data, target render, jitter, stack trace,
forward, backward, optimiser.

    python bench/profile_train_step.py --threads 1
    python bench/profile_train_step.py --threads 2 --models csgnet2d_small csgnetstack2d_small
    python bench/profile_train_step.py --device cuda --models csgnetstack3d_small --batch 128 --precision bf16

Each phase of a supervised step (the pieces of :meth:`csgnet.train.supervised.CSGNetModule._loss`: the
target render, jitter, stack trace, then :func:`~csgnet.train.supervised.teacher_forced_loss`) plus the
optimiser step is timed on its own
(median over ``--steps`` steps after one warm-up), on one mixed-length batch drawn from the training stream
(``MixedLengthBatches``, programs sampled on the fly). "data" is the time to draw that batch. The table shows
milliseconds per phase, the model's share (forward + backward + optimiser) of the step, samples/s, and
samples/s without the data phase (what a training run reading a dataset folder with DataLoader workers steps at;
on a GPU, the GPU side of the step). The last column, outside the step, is what one DataLoader worker spends
per batch with ``render_in_workers`` (:func:`~csgnet.train.supervised.packed_inputs`: the target and stack
trace rendered and bit-packed on the CPU, on ``--threads`` threads); with it the render and stack phases leave
the step; the column after it is the size of what that worker hands the training process per batch (the
packed target and stack trace), which a DataLoader moves through shared memory. ``--precision bf16`` runs the
forward and backward passes under bfloat16 autocast (as ``--trainer.precision bf16-mixed``); ``--batch``
replaces each model's batch size.
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

from csgnet.renderer import render_tokens, stack_trace
from csgnet.train.augment import jitter
from csgnet.train.streams import MixedLengthBatches
from csgnet.train.supervised import DEFAULT_LENGTHS, CSGNetModule, packed_inputs, teacher_forced_loss

# name -> (dim, stack, size, model overrides, batch): the shipped small configs and the paper sizes
MODELS = {
    "csgnet2d_small": (2, False, "small", {}, 96),
    "csgnetstack2d_small": (2, True, "small", {"input_pool": 2, "channels": [8, 16, 32]}, 96),
    "csgnet2d_paper": (2, False, "paper", {}, 100),
    "csgnetstack2d_paper": (2, True, "paper", {}, 100),
    "csgnetstack2d_medium": (2, True, "small", {"hidden": 384, "channels": [8, 16, 32]}, 300),
    "csgnet3d_small": (3, False, "small", {}, 48),
    "csgnetstack3d_small": (3, True, "small", {}, 48),
    "csgnet3d_lite": (3, False, "lite", {}, 48),
    "csgnet3d_lite_fullhead": (3, False, "lite", {"head": "full"}, 48),
    "csgnet3d_lite_gru512": (3, False, "lite", {"hidden": 512}, 48),
    "csgnet3d_lite_wide": (3, False, "lite", {"hidden": 512, "channels": [16, 32, 64, 128]}, 48),
    "csgnet3d_lite_64": (3, False, "lite", {"input_pool": 1, "channels": [8, 16, 32, 64, 64]}, 48),
    "csgnet3d_paper": (3, False, "paper", {}, 48),
    "csgnetstack3d_paper": (3, True, "paper", {}, 48),
}
PHASES = ("data", "render", "jitter", "stack", "forward", "backward", "optimiser")


def profile(name: str, steps: int, device: str, batch: int | None = None, precision: str = "32") -> dict[str, float]:
    """Median seconds per phase of one training step of model ``name`` (``batch``: instead of the model's;
    ``precision``: ``"32"`` or ``"bf16"`` autocast of the forward and backward passes)."""
    dim, stack, size, over, default_batch = MODELS[name]
    batch = batch or default_batch
    autocast = torch.autocast(device_type=torch.device(device).type, dtype=torch.bfloat16,
                              enabled=precision == "bf16")
    m = CSGNetModule(dim=dim, stack=stack, size=size, model=over).to(device)
    opt = torch.optim.Adam(m.parameters(), lr=1e-3)
    lengths = DEFAULT_LENGTHS[dim]
    stream = iter(MixedLengthBatches(dim, lengths, batch, steps + 1, max(lengths), tables=None, seed=0))
    rng = np.random.default_rng(0)

    def sync():  # CUDA runs asynchronously: each phase is timed to its end
        if device == "cuda":
            torch.cuda.synchronize()

    cfg = m.config
    times = {p: [] for p in PHASES}
    worker, packed_mb = [], 0.0
    for i in range(steps + 1):
        t = {}
        t0 = time.perf_counter()
        tok, lens = next(stream)
        w0 = time.perf_counter()
        packed = packed_inputs(tok, lens, dim, cfg.stack_k if stack else None)
        worker.append(time.perf_counter() - w0)
        packed_mb = max(packed_mb, sum(x.numel() * x.element_size() for x in packed if x is not None) / 2**20)
        t0 += worker[-1]  # outside the step: the data phase is the draw alone
        tok, lens = tok.to(device), lens.to(device)
        sync()
        t["data"] = time.perf_counter()
        T = int(lens.max()) + 1
        tok = tok[:, :T]
        target = render_tokens(tok, dim, lens)
        sync()
        t["render"] = time.perf_counter()
        if m.augment:
            target = jitter(target, rng)
        sync()
        t["jitter"] = time.perf_counter()
        st = stack_trace(tok[:, :-1], dim, k=cfg.stack_k, lengths=lens) if stack else None
        sync()
        t["stack"] = time.perf_counter()
        tokens_in = torch.cat([torch.full_like(tok[:, :1], m.model.start), tok[:, :-1]], dim=1)
        with autocast:
            loss, _ = teacher_forced_loss(m.model, target, tok, tokens_in, st, lens, m.loss_norm)
        sync()
        t["forward"] = time.perf_counter()
        opt.zero_grad()
        loss.backward()
        sync()
        t["backward"] = time.perf_counter()
        opt.step()
        sync()
        t["optimiser"] = time.perf_counter()
        if i:
            prev = t0
            for p in PHASES:
                times[p].append(t[p] - prev)
                prev = t[p]
    out = {p: float(np.median(v)) for p, v in times.items()}
    out["worker"] = float(np.median(worker[1:]))
    out["batch"] = batch
    out["packed_mb"] = packed_mb
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--models", nargs="*", default=[n for n in MODELS if "paper" not in n or n == "csgnet2d_paper"],
                    choices=sorted(MODELS))
    ap.add_argument("--batch", type=int, default=None, help="batch size for every model (default: each model's)")
    ap.add_argument("--precision", choices=("32", "bf16"), default="32",
                    help="bf16: forward and backward under bfloat16 autocast")
    ap.add_argument("--out", default=None, help="also write the table as a result file (JSON, shapeio.results)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch "
          f"{torch.__version__}, threads {torch.get_num_threads()}, device {args.device}, "
          f"precision {args.precision}, load average {os.getloadavg()[0]:.2f}")
    print("| model | batch | " + " | ".join(f"{p} ms" for p in PHASES)
          + " | model share | samples/s | samples/s without data | worker render ms (render_in_workers) "
          "| worker hands over MiB |")
    print("|---|---:|" + "---:|" * len(PHASES) + "---:|---:|---:|---:|---:|")
    rows = []
    for name in args.models:
        r = profile(name, args.steps, args.device, args.batch, args.precision)
        total = sum(r[p] for p in PHASES)
        model = r["forward"] + r["backward"] + r["optimiser"]
        dim, stack, size, over, _ = MODELS[name]
        cfg = CSGNetModule(dim=dim, stack=stack, size=size, model=over).config
        rows.append({"model": name, "encoder": f"{cfg.encoder}, {64 // cfg.input_pool}^{dim} input",
                     "head": cfg.head, "batch": r["batch"], "step_ms": 1000 * (total - r["data"]),
                     "model_ms": 1000 * model, "sps": r["batch"] / (total - r["data"]),
                     "sps_fly": r["batch"] / total})
        print(f"| {name} | {r['batch']} | " + " | ".join(f"{1000 * r[p]:.1f}" for p in PHASES)
              + f" | {100 * model / total:.0f}% | {r['batch'] / total:.1f} | {r['batch'] / (total - r['data']):.1f}"
              f" | {1000 * r['worker']:.1f} | {r['packed_mb']:.2f} |",
              flush=True)
    command = "python " + shlex.join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:]))
    print("command: " + command)
    if args.out:
        from shapeio.results import column, make_result, write_result

        cols = [column("model", "model"), column("encoder", "encoder, input"), column("head", "output layer"),
                column("batch", "batch"), column("step_ms", "step ms (data from a dataset)", 0),
                column("model_ms", "forward + backward + optimiser ms", 0),
                column("sps", "samples/s (data from a dataset)", 1),
                column("sps_fly", "samples/s (programs sampled in the step)", 1)]
        note = (f"{torch.get_num_threads()} thread(s), device {args.device}, precision {args.precision}; median of "
                f"{args.steps} steps after one warm-up.")
        print(f"wrote {write_result(args.out, make_result('Supervised training step', cols, rows, [note], command))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
