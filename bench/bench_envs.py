"""RL episodes per second in the environments: one CSG episode at a time against the batched vector env.

Measured in one run on the same machine, with the same random policy and the same synthetic targets:

* ``single``: one :class:`envs.csg.CSGEnv`, episode after episode (what a per-episode RL loop does).
* ``sync``: ``gymnasium.vector.SyncVectorEnv`` over ``N`` single environments (Gymnasium's generic
  vectorisation: the same per-episode work, plus batching of the outputs).
* ``vector``: :class:`envs.csg.CSGVectorEnv` with ``N`` episodes: one stack machine steps every episode
  and one reward call scores every episode that ends at a step.

The policy samples a token kind uniformly among those the action mask allows (draw, operator, stop),
then a token of that kind uniformly, and with probability ``--eps`` (default 0.05) any token at all (so
some episodes end early on an invalid token). Only the environment and policy steps are timed; the
synthetic target pool is drawn before timing (its drawing time per length is printed first).

Also timed: the end-of-episode reward alone (2D: :func:`csgnet.metrics.reward` called once per episode
against one batched call over the same ``N`` pairs), and ``ShapeAssembly-v0`` steps with random lines.

Usage::

    python bench/bench_envs.py --threads 1 [--dims 2 3] [--num-envs 256 32] [--seconds 5] [--device cpu]
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time

import gymnasium as gym
import numpy as np
import torch

from csgnet import metrics
from envs.assembly import ShapeAssemblyEnv
from envs.csg import CSGEnv, CSGVectorEnv
from envs.targets import SyntheticTargets


def policy(masks: np.ndarray, rng: np.random.Generator, eps: float, stop: int) -> np.ndarray:
    """One action per row of ``masks (B, V) bool`` (see the module docstring)."""
    B, V = masks.shape
    first_op = stop - 3
    kinds = np.stack([masks[:, :first_op].any(1), masks[:, first_op:stop].any(1), masks[:, stop]], axis=1)
    kinds[~kinds.any(1)] = True  # an ended row: anything
    u = rng.random((B, 3)) * kinds
    kind = u.argmax(1)
    lo = np.array([0, first_op, stop])[kind]
    hi = np.array([first_op, stop, stop + 1])[kind]
    act = lo + (rng.random(B) * (hi - lo)).astype(np.int64)
    wild = rng.random(B) < eps
    act[wild] = rng.integers(V, size=int(wild.sum()))
    return act


def _time_single(env, seconds: float, rng, eps: float) -> tuple[float, int]:
    stop = env.action_space.n - 1
    episodes, t0 = 0, time.perf_counter()
    env.reset(seed=0)
    while True:
        _, _, terminated, _, _ = env.step(int(policy(env.action_masks()[None], rng, eps, stop)[0]))
        if terminated:
            episodes += 1
            if time.perf_counter() - t0 >= seconds:
                break
            env.reset()
    return episodes / (time.perf_counter() - t0), episodes


def _time_vector(vec, masks_of, seconds: float, rng, eps: float) -> tuple[float, int]:
    stop = vec.single_action_space.n - 1
    vec.reset(seed=0)
    episodes, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        _, _, terminated, _, _ = vec.step(policy(masks_of(vec), rng, eps, stop))
        episodes += int(terminated.sum())
    return episodes / (time.perf_counter() - t0), episodes


def bench_csg(dim: int, n: int, seconds: float, eps: float, device: str) -> None:
    src = SyntheticTargets(dim)
    print(f"\n{dim}D synthetic target pool ({src.size} programs per length, drawn before the episodes are timed):")
    for i, length in zip(range(0, len(src), src.size), src.lengths):
        t0 = time.perf_counter()
        src.tokens(i)  # draws and renders the pool of this length
        dt = time.perf_counter() - t0
        print(f"  length {length}: {dt:.1f} s, {1000 * dt / src.size:.1f} ms per program")
    single = CSGEnv(dim=dim, targets=src, device=device)
    sync = gym.vector.SyncVectorEnv([lambda: CSGEnv(dim=dim, targets=src, device=device) for _ in range(n)])
    vec = CSGVectorEnv(n, dim=dim, targets=src, device=device)
    # warm-up (primitive caches, allocator)
    _time_single(single, 0.2, np.random.default_rng(1), eps)
    _time_vector(vec, lambda v: v.action_masks(), 0.2, np.random.default_rng(1), eps)
    rows = []
    r, e = _time_single(single, seconds, np.random.default_rng(2), eps)
    rows.append(("single CSGEnv", 1, r, e))
    r, e = _time_vector(sync, lambda v: np.stack([s.unwrapped.action_masks() for s in v.envs]), seconds,
                        np.random.default_rng(2), eps)
    rows.append(("SyncVectorEnv", n, r, e))
    r, e = _time_vector(vec, lambda v: v.action_masks(), seconds, np.random.default_rng(2), eps)
    rows.append(("CSGVectorEnv", n, r, e))
    base = rows[0][2]
    print(f"\n{dim}D, max length {single.config.max_length}, reward {single.config.reward}, device {device}")
    print("| env | episodes in parallel | episodes/s | ratio to single |")
    print("|---|---|---|---|")
    for name, k, rate, eps_done in rows:
        print(f"| {name} | {k} | {rate:,.0f} | {rate / base:.1f}x |   ({eps_done} episodes)")


def bench_reward(n: int, repeats: int) -> None:
    """2D reward: n per-episode calls against one batched call, same pairs."""
    src = SyntheticTargets(2).prepare()
    rng = np.random.default_rng(3)
    targets = np.stack([src.sample(rng).shape for _ in range(n)])
    preds = np.stack([src.sample(rng).shape for _ in range(n)])
    preds[: n // 4] = targets[: n // 4]  # some perfect programs
    t_loop = t_batch = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        loop = np.array([metrics.reward(p, t) for p, t in zip(preds, targets)])
        t_loop = min(t_loop, time.perf_counter() - t0)
        t0 = time.perf_counter()
        batch = metrics.reward(preds, targets)
        t_batch = min(t_batch, time.perf_counter() - t0)
    assert np.array_equal(loop, batch)
    print(f"\n2D reward of {n} episodes (best of {repeats}): per-episode calls {n / t_loop:,.0f} rewards/s, "
          f"one batched call {n / t_batch:,.0f} rewards/s ({t_loop / t_batch:.1f}x); values identical")


def bench_assembly(seconds: float) -> None:
    env = ShapeAssemblyEnv()
    env.action_space.seed(0)
    env.reset(seed=0)
    steps = episodes = invalid = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        a = env.action_space.sample()
        if a["command"] == 0 and env.np_random.random() < 0.8:  # fewer early stops than uniform
            a["command"] = 1
        _, _, terminated, _, info = env.step(a)
        steps += 1
        invalid += info["invalid"]
        if terminated:
            episodes += 1
            env.reset()
    dt = time.perf_counter() - t0
    print(f"\nShapeAssembly-v0 (corpus targets, 1024 points, random lines): {steps / dt:,.0f} steps/s, "
          f"{episodes / dt:,.1f} episodes/s ({episodes} episodes, {100 * invalid / max(steps, 1):.0f}% invalid lines)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dims", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--num-envs", type=int, nargs="+", default=None,
                    help="episodes in parallel per dim (default 256 in 2D, 32 in 3D)")
    ap.add_argument("--seconds", type=float, default=5.0, help="timing per measurement")
    ap.add_argument("--eps", type=float, default=0.05)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--skip-assembly", action="store_true")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    print("command:", shlex.join([sys.executable, *sys.argv]))
    print(f"machine: {platform.machine()} {platform.system()}, {os.cpu_count()} CPUs, Python "
          f"{platform.python_version()}, torch {torch.__version__}, numpy {np.__version__}, "
          f"{args.threads} torch thread(s), load average {os.getloadavg()[0]:.1f}")
    if args.device != "cpu" and torch.cuda.is_available():
        print("GPU:", torch.cuda.get_device_name(0))
    nums = args.num_envs or [256 if d == 2 else 32 for d in args.dims]
    if len(nums) != len(args.dims):
        ap.error("--num-envs needs one value per --dims entry")
    for dim, n in zip(args.dims, nums):
        bench_csg(dim, n, args.seconds, args.eps, args.device)
    if 2 in args.dims:
        bench_reward(256, 3)
    if not args.skip_assembly:
        bench_assembly(args.seconds)


if __name__ == "__main__":
    main()
