"""Programs per second: the batched CSG renderer against a plain per-program baseline.

Baselines (written here, as the original code works):
* 2D: every primitive drawn with scikit-image (``disk``, ``polygon`` + ``polygon_perimeter``) into a
  fresh 64x64 bool array, booleans with NumPy, a Python list as the stack.
* 3D: a dictionary of pre-rendered primitive volumes keyed by vocabulary token (the original training
  path), booleans with NumPy.

Both sides render the same random valid programs (2D length 13, 3D length 7) from vocabulary tokens, in
one run on the same machine. The batched renderer is timed to bool output (what ``csgnet.render`` returns)
and, separately, to its packed output (what the training path consumes before one unpack per batch).

Usage::

    python bench/bench_csg_render.py [--n2d 4096] [--n3d 512] [--device cpu]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np
import torch

from csgnet.lang import Draw, Program
from csgnet.renderer import encode_programs, encode_tokens, execute, unpack
from csgnet.vocab import vocabulary


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

def _baseline_2d_draw(d: Draw) -> np.ndarray:
    from skimage import draw

    img = np.zeros((64, 64), bool)
    x, y, r = d.params
    if d.kind == "c":
        rr, cc = draw.disk((y, x), r, shape=(64, 64))
        img[rr, cc] = True
        return img
    if d.kind == "s":
        L = r * 1.412
        rows = [int(y - L / 2.0), int(y - L / 2.0), int(y + L / 2.0), int(y + L / 2.0)]
        cols = [int(x - L / 2.0), int(x + L / 2.0), int(x + L / 2.0), int(x - L / 2.0)]
    else:
        L = 1.732 * r
        rows = [int(y + L / (2 * 1.732)), int(y + L / (2 * 1.732)), int(y - L / 1.732)]
        cols = [int(x - L / 2.0), int(x + L / 2.0), x]
    rr, cc = draw.polygon(rows, cols, shape=(64, 64))
    img[rr, cc] = True
    rr, cc = draw.polygon_perimeter(rows, cols, shape=(64, 64))
    img[rr, cc] = True
    return img


def _run_stack(tokens, get_prim):
    stack = []
    for t in tokens:
        if isinstance(t, Draw):
            stack.append(get_prim(t))
        else:
            b, a = stack.pop(), stack.pop()
            stack.append(np.logical_or(a, b) if t.op == "+" else
                         np.logical_and(a, b) if t.op == "*" else np.logical_and(a, np.logical_not(b)))
    return stack[-1]


def baseline_2d(programs: list[Program]) -> list[np.ndarray]:
    return [_run_stack(p.tokens, _baseline_2d_draw) for p in programs]


def baseline_3d(programs: list[Program], table: dict) -> list[np.ndarray]:
    return [_run_stack(p.tokens, lambda d: table[d.text(long=False)]) for p in programs]


def timed(fn, repeat=3):
    best = float("inf")
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n2d", type=int, default=4096, help="2D programs (length 13), batch 1024")
    ap.add_argument("--n3d", type=int, default=512, help="3D programs (length 7), batch 256")
    ap.add_argument("--baseline-n2d", type=int, default=500)
    ap.add_argument("--baseline-n3d", type=int, default=500)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    dev = torch.device(args.device)
    rng = np.random.default_rng(args.seed)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}, device {dev}"
          + (f" ({torch.cuda.get_device_name(dev)})" if dev.type == "cuda" else ""))

    for dim, n, bn, length, batch in ((2, args.n2d, args.baseline_n2d, 13, 1024), (3, args.n3d, args.baseline_n3d, 7, 256)):
        vocab = vocabulary(dim)
        toks = random_programs(dim, max(n, bn), length, rng)
        progs = [vocab.decode(t) for t in toks[:bn]]
        if dim == 2:
            t_base, base_out = timed(lambda: baseline_2d(progs), repeat=1)
        else:
            from csgnet.render_np import draw_np

            needed = {d.text(long=False) for p in progs for d in p.draws}
            table = {k: draw_np(vocab.decode([vocab.index(k)]).tokens[0]) for k in needed}
            t_base, base_out = timed(lambda: baseline_3d(progs, table), repeat=1)
        base_rate = bn / t_base

        tt = torch.from_numpy(toks[:n]).to(dev)

        def batched(to_bool=True):
            outs = []
            for i in range(0, n, batch):
                kinds, params = encode_tokens(tt[i:i + batch], dim)
                words = execute(kinds, params, dim, token_ids=tt[i:i + batch]).canvas
                outs.append(unpack(words, dim) if to_bool else words)
            return outs

        batched()  # warm-up
        t_ours, ours = timed(batched)
        t_packed, _ = timed(lambda: batched(False))
        # exactness on the baseline's programs
        check = ours[0][: min(bn, batch)].cpu().numpy()
        same = all((check[i] == base_out[i]).all() for i in range(len(check)))

        # off-grid parameters: every primitive shifted off the 8-pixel grid (generic path)
        off = [Program(tuple(Draw(t.kind, tuple(v + 3 if j < dim else v + 1 for j, v in enumerate(t.params)))
                             if isinstance(t, Draw) else t for t in vocab.decode(r).tokens), dim)
               for r in toks[:batch]]
        kinds_off, params_off = encode_programs(off, dim, dev)
        t_off, _ = timed(lambda: unpack(execute(kinds_off, params_off, dim).canvas, dim))

        rate, rate_packed, rate_off = n / t_ours, n / t_packed, batch / t_off
        print(f"{dim}D length {length}, batch {batch}:")
        print(f"  baseline (per program, {'scikit-image draws' if dim == 2 else 'pre-rendered primitives'}): "
              f"{base_rate:10.0f} programs/s  ({bn} programs)")
        print(f"  batched renderer -> bool:        {rate:10.0f} programs/s  ({rate / base_rate:.1f}x)")
        print(f"  batched renderer -> packed bits: {rate_packed:10.0f} programs/s  ({rate_packed / base_rate:.1f}x)")
        print(f"  batched, off-grid params -> bool:{rate_off:10.0f} programs/s  ({rate_off / base_rate:.1f}x)")
        print(f"  identical to the baseline on {len(check)} programs: {same}")


if __name__ == "__main__":
    main()
