"""REINFORCE speed: episodes per second of a full update step (sampling, rendering, reward, backward).

    python bench/bench_rl.py --threads 1
    python bench/bench_rl.py --threads 1 --batch 300 --weights runs/rl_csgnet2d_small/checkpoints/last.ckpt

Models: the shipped ``csgnet/weights/csgnet2d.pt`` and ``csgnetstack2d.pt`` (random small-preset weights
where a file is missing), or ``--weights`` / ``--stack-weights``.

One step is what :class:`csgnet.train.reinforce.ReinforceModule` does per batch: jitter the targets, sample
one program per target in train mode (:func:`csgnet.decode.sample`; CSGNetStack executes each sampled
prefix), render the programs, score them against the targets, update the baseline, form the loss and
run backward plus an SGD step. Targets are the validation silhouettes. Two ways of computing the
reward are timed in the same run: batched (one :func:`csgnet.train.reinforce.episode_rewards` call per batch,
what training uses) and, as the baseline, one :func:`csgnet.metrics.reward` call per episode (the
reference's per-image loop), on the same samples in each step, so the two step rates share the
sampling, rendering and backward times. The two give identical rewards (checked every step).
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
import warnings

import numpy as np
import torch

from csgnet import metrics
from csgnet.train.augment import jitter
from csgnet.decode import sample
from csgnet.inference import WEIGHTS
from csgnet.models import CSGNet, preset
from csgnet.renderer import render_tokens
from csgnet.shapes2d import load_silhouettes
from csgnet.train.reinforce import episode_rewards, load_initial, policy_loss, update_baseline


def _model(weights, stack: bool):
    if weights:
        return load_initial(weights)[0], os.path.basename(weights)
    shipped = WEIGHTS / ("csgnetstack2d.pt" if stack else "csgnet2d.pt")
    if shipped.is_file():
        return load_initial(shipped)[0], f"shipped {shipped.name}"
    torch.manual_seed(0)
    return CSGNet(preset("small", 2, stack)).train(), "random init, small preset"


def bench(model, targets: torch.Tensor, batch: int, steps: int, device) -> dict:
    """Time ``steps`` update steps; each step scores the same samples both ways (batched and per episode),
    so the two step times share the sampling, rendering and backward measurements."""
    torch.manual_seed(0)
    model = model.to(device).train()
    opt = torch.optim.SGD(model.parameters(), lr=0.0, momentum=0.9)  # lr 0: every step sees the same policy
    rng = np.random.default_rng(0)
    gen = torch.Generator(device=device).manual_seed(0)
    b = torch.zeros((), dtype=torch.float64)
    parts = {"sample": 0.0, "render": 0.0, "reward": 0.0, "reward_loop": 0.0, "backward": 0.0}
    stats = {"reward": [], "valid": [], "length": []}

    def sync():
        if device != "cpu":
            torch.cuda.synchronize()

    for i in range(steps + 1):  # the first step warms up caches and is not timed
        lo = (i * batch) % max(1, len(targets) - batch)
        t0 = time.perf_counter()
        x = jitter(targets[lo: lo + batch], rng).to(device)
        s = sample(model, x, 13, generator=gen)
        sync()
        t1 = time.perf_counter()
        pred = render_tokens(s.tokens, 2, s.lengths)
        sync()
        t2 = time.perf_counter()
        r, _ = episode_rewards(pred, x, s.valid)
        t3 = time.perf_counter()
        p, tg, v = pred.cpu().numpy(), x.cpu().numpy(), s.valid.cpu().numpy()
        r_loop = np.array([metrics.reward(p[j], tg[j], valid=v[j:j + 1]) for j in range(len(p))])
        t4 = time.perf_counter()
        if not np.array_equal(r, r_loop):
            raise AssertionError("batched and per-episode rewards differ")
        rt = torch.as_tensor(r, dtype=torch.float64)
        b = update_baseline(b, rt)
        loss = policy_loss(s.log_probs, s.counted, (rt - b).float().to(device))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sync()
        t5 = time.perf_counter()
        if i:
            for k, dt in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)):
                parts[k] += dt
            stats["reward"].append(float(np.mean(r)))
            stats["valid"].append(float(s.valid.float().mean()))
            stats["length"].append(float(s.lengths.float().mean()))
    common = parts["sample"] + parts["render"] + parts["backward"]
    n = steps * batch
    return {"batched": n / (common + parts["reward"]), "loop": n / (common + parts["reward_loop"]),
            "rewards_batched": n / parts["reward"], "rewards_loop": n / parts["reward_loop"],
            "parts": {k: v / (common + parts["reward"]) for k, v in parts.items() if k != "reward_loop"},
            **{k: float(np.mean(v)) for k, v in stats.items()}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=100)
    ap.add_argument("--steps", type=int, default=5, help="timed update steps per configuration")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--weights", default=None, help="CSGNet weights (default: the shipped model)")
    ap.add_argument("--stack-weights", default=None, help="CSGNetStack weights (default: the shipped model)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    warnings.filterwarnings("ignore")
    targets = torch.from_numpy(load_silhouettes("val"))
    print(f"command: python bench/bench_rl.py {' '.join(sys.argv[1:] if argv is None else argv)}")
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, torch "
          f"{torch.__version__}, {args.threads} torch thread(s), device {args.device}, load average "
          f"{os.getloadavg()[0]:.1f}")
    print(f"{args.batch} silhouette targets per step, {args.steps} timed steps, max length 13")
    for name, weights, stack in (("CSGNet", args.weights, False), ("CSGNetStack", args.stack_weights, True)):
        model, source = _model(weights, stack)
        res = bench(model, targets, args.batch, args.steps, args.device)
        print(f"\n{name} ({source}; {model.num_parameters():,} parameters): mean reward {res['reward']:.3f}, "
              f"valid {100 * res['valid']:.0f}%, mean length {res['length']:.1f}")
        print(f"  step with per-episode reward calls (baseline): {res['loop']:8.1f} episodes/s")
        print(f"  step with the batched reward:                  {res['batched']:8.1f} episodes/s   "
              f"({res['batched'] / res['loop']:.2f}x)")
        print(f"  reward alone: {res['rewards_loop']:.0f} rewards/s per episode, {res['rewards_batched']:.0f} batched "
              f"({res['rewards_batched'] / res['rewards_loop']:.2f}x; identical values)")
        print("  share of the batched step: " + ", ".join(f"{k} {100 * v:.0f}%" for k, v in res["parts"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
