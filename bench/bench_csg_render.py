"""Programs per second: the batched CSG renderer against a plain per-program baseline.

Baselines (as the original code works):
* 2D: every primitive drawn with scikit-image (``disk``, ``polygon`` + ``polygon_perimeter``) into a
  fresh 64x64 bool array (``skimage_2d`` of ``tests/csg_testutil.py``, the renderer tests' oracle),
  booleans with NumPy, a Python list as the stack.
* 3D: a dictionary of pre-rendered primitive volumes keyed by vocabulary token (the original training
  path), booleans with NumPy.
Each comes in two forms:
* A, final shape: the stack is run and only its last top is kept (the least work that yields the
  target; faster than the original code).
* B, reference path: what the reference data generator yields for every program and the reference
  training scripts read the target from (spec section b, "Stack trace"): the stack trace of all T+1
  states with S = length // 2 + 1 slots (slot 0 the top, empty slots zero), of which plain CSGNet uses
  state T's slot 0.

Both sides render the same random valid programs (2D length 13, 3D length 7) from vocabulary tokens, in
one run on the same machine. The batched renderer is timed to bool output (what ``csgnet.render`` returns)
and, separately, to its packed output (what the training path consumes before one unpack per batch).
It also times the same programs given as text (``render_programs`` on program strings: parsing,
encoding and rendering), programs with every primitive moved off the 8-pixel grid (drawn, not looked up)
and the stack trace of the same S slots that CSGNetStack trains on, packed and as bools (the like-for-like
counterpart of baseline B).

Timing is the same for both sides: one untimed warm-up pass, then the best of ``--repeat`` passes. Each
result is dropped when the next one is made (per program for the baseline, per batch for the batched
renderer), as in a training loop, so both sides allocate their outputs in a steady state. Outputs are
checked identical outside the timed passes. Rates are given by wall time and by process CPU time: with
one thread (``--threads 1``) CPU time counts only this process's work, the steadier figure on a machine
shared with other jobs.

Usage::

    python bench/bench_csg_render.py [--n2d 4096] [--n3d 512] [--device cpu] [--threads 1] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

from csgnet.lang import Draw, Program
from csgnet.renderer import (SIZE, encode_programs, encode_tokens, execute, render_programs, render_tokens, stack_trace,
                             unpack)
from csgnet.vocab import vocabulary

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from csg_testutil import skimage_2d  # noqa: E402  (the reference's scikit-image drawing calls)


def random_programs(dim: int, n: int, length: int, rng: np.random.Generator) -> np.ndarray:
    """(n, length) token indices of random valid programs of exactly ``length`` tokens."""
    vocab = vocabulary(dim)
    n_prim = (length + 1) // 2
    ops = [vocab.op_index(o) for o in "+*-"]
    out = np.empty((n, length), dtype=np.int64)
    for b in range(n):
        toks, depth, placed = [], 0, 0
        while len(toks) < length:
            if placed < n_prim and (depth < 2 or rng.random() < 0.5):
                toks.append(int(rng.integers(vocab.num_primitives)))
                depth += 1
                placed += 1
            else:
                toks.append(ops[int(rng.integers(3))])
                depth -= 1
        out[b] = toks
    return out


# ---------------------------------------------------------------------------------------------
# baselines

def _run_stack(tokens, get_prim):
    stack = []
    for t in tokens:
        if isinstance(t, Draw):
            stack.append(get_prim(t))
        else:
            b, a = stack.pop(), stack.pop()
            stack.append(_bool_op(t.op, a, b))
    return stack[-1]


def _bool_op(op, a, b):
    return (np.logical_or(a, b) if op == "+" else
            np.logical_and(a, b) if op == "*" else np.logical_and(a, np.logical_not(b)))


def _run_trace(tokens, get_prim, slots, shape):
    """The reference training path: the stack trace ``(T+1, slots, *shape)`` (state 0 empty, slot 0 the
    top, empty slots zero), as the reference data generator yields it for every program; plain CSGNet
    then trains on state T's slot 0 (spec section b, "Stack trace")."""
    trace = np.zeros((len(tokens) + 1, slots) + shape, dtype=bool)
    stack = []
    for t, tok in enumerate(tokens):
        if isinstance(tok, Draw):
            stack.append(get_prim(tok))
        else:
            b, a = stack.pop(), stack.pop()
            stack.append(_bool_op(tok.op, a, b))
        for j, item in enumerate(reversed(stack[-slots:])):
            trace[t + 1, j] = item
    return trace


def timed(fn, repeat=3, sync=False):
    """Best wall time and best process CPU time of ``repeat`` calls of ``fn`` after one untimed warm-up.

    With one thread, CPU time is the work done by this process alone; on a machine shared with other
    jobs it is the steadier of the two (wall time also counts the time the process waited for a core).
    """
    fn()
    wall = cpu = float("inf")
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        if sync:
            torch.cuda.synchronize()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n2d", type=int, default=4096, help="2D programs (length 13), batch 1024")
    ap.add_argument("--n3d", type=int, default=512, help="3D programs (length 7), batch 256")
    ap.add_argument("--baseline-n2d", type=int, default=500)
    ap.add_argument("--baseline-n3d", type=int, default=500)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    ap.add_argument("--repeat", type=int, default=3, help="timed passes per measurement (best is kept)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    dev = torch.device(args.device)
    rng = np.random.default_rng(args.seed)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}, device {dev}"
          + (f" ({torch.cuda.get_device_name(dev)})" if dev.type == "cuda" else ""))

    sync = dev.type == "cuda"
    for dim, n, bn, length, batch in ((2, args.n2d, args.baseline_n2d, 13, 1024), (3, args.n3d, args.baseline_n3d, 7, 256)):
        vocab = vocabulary(dim)
        toks = random_programs(dim, max(n, bn), length, rng)
        progs = [vocab.decode(t) for t in toks[:bn]]
        if dim == 2:
            def get_prim(d):
                return skimage_2d(d.kind, *d.params)
        else:
            from csgnet.renderer.reference import draw_np

            needed = {d.text(long=False) for p in progs for d in p.draws}
            table = {k: draw_np(vocab.decode([vocab.index(k)]).tokens[0]) for k in needed}

            def get_prim(d):
                return table[d.text(long=False)]

        def run_one(p):
            return _run_stack(p.tokens, get_prim)

        def baseline():
            for p in progs:
                run_one(p)

        slots = length // 2 + 1  # the reference generator's S (4 in 3D, 7 in 2D)

        def baseline_trace():
            for p in progs:
                _run_trace(p.tokens, get_prim, slots, (SIZE,) * dim)[-1, 0]

        t_base = timed(baseline, args.repeat)
        t_ref = timed(baseline_trace, args.repeat)

        tt = torch.from_numpy(toks[:n]).to(dev)

        def batched():
            for i in range(0, n, batch):
                render_tokens(tt[i:i + batch], dim)

        def batched_packed():
            for i in range(0, n, batch):
                kinds, params = encode_tokens(tt[i:i + batch], dim)
                execute(kinds, params, dim, token_ids=tt[i:i + batch])

        def batched_trace(packed=True):
            for i in range(0, n, batch):
                stack_trace(tt[i:i + batch], dim, k=slots, packed=packed)

        texts = [vocab.text(t) for t in toks[:n]]

        def batched_text():
            for i in range(0, n, batch):
                render_programs(texts[i:i + batch], dim, dev)

        t_ours = timed(batched, args.repeat, sync)
        t_text = timed(batched_text, args.repeat, sync)
        t_packed = timed(batched_packed, args.repeat, sync)
        t_trace = timed(batched_trace, args.repeat, sync)
        t_trace_bool = timed(lambda: batched_trace(False), args.repeat, sync)
        # exactness on the baseline's programs, both outputs
        check = render_tokens(tt[:batch], dim).cpu().numpy()[: min(bn, batch)]
        same = all((check[i] == run_one(progs[i])).all() for i in range(len(check)))
        packed = execute(*encode_tokens(tt[:batch], dim), dim, token_ids=tt[:batch]).canvas
        same &= bool((unpack(packed, dim).cpu().numpy()[: len(check)] == check).all())
        tr = stack_trace(tt[:8], dim, k=slots).cpu().numpy()
        same &= bool((render_programs(texts[:batch], dim, dev).cpu().numpy()[: len(check)] == check).all())
        same &= all((tr[:, i] == _run_trace(progs[i].tokens, get_prim, slots, (SIZE,) * dim)).all()
                    for i in range(min(8, bn)))

        # off-grid parameters: every primitive shifted off the 8-pixel grid (generic path)
        off = [Program(tuple(Draw(t.kind, tuple(v + 3 if j < dim else v + 1 for j, v in enumerate(t.params)))
                             if isinstance(t, Draw) else t for t in vocab.decode(r).tokens), dim)
               for r in toks[:batch]]
        kinds_off, params_off = encode_programs(off, dim, dev)
        t_off = timed(lambda: unpack(execute(kinds_off, params_off, dim).canvas, dim), args.repeat, sync)

        print(f"{dim}D length {length}, batch {batch}: programs/s and ratios to baseline A | B, "
              f"by wall time || by CPU time")

        def row(name, count, t):
            rw, rc = count / t[0], count / t[1]
            print(f"  {name:50s} {rw:8.0f} {rw * t_base[0] / bn:6.1f}x {rw * t_ref[0] / bn:6.1f}x || "
                  f"{rc:8.0f} {rc * t_base[1] / bn:6.1f}x {rc * t_ref[1] / bn:6.1f}x")

        prim = "scikit-image draws" if dim == 2 else "pre-rendered primitives"
        row(f"A: baseline, final shape ({prim})", bn, t_base)
        row(f"B: baseline, reference path (trace of {slots} slots)", bn, t_ref)
        row("batched renderer -> bool (render_tokens)", n, t_ours)
        row("batched renderer -> packed bits (execute)", n, t_packed)
        row("batched, from text -> bool (render_programs)", n, t_text)
        row("batched, off-grid params -> bool", batch, t_off)
        row(f"batched stack trace ({slots} slots) -> packed", n, t_trace)
        row(f"batched stack trace ({slots} slots) -> bool", n, t_trace_bool)
        print(f"  identical to the baselines on {len(check)} programs (traces on {min(8, bn)}): {same}")
        if dim == 3:
            print(f"  (the baseline's dictionary: {len(table)} pre-rendered volumes, "
                  f"{sum(v.nbytes for v in table.values()) / 2**20:.0f} MiB)")
    print(f"# load average after the run: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
