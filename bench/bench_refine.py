"""Seconds per image of Powell refinement (``csgnet.refine``) against a plain Powell loop.

Targets and start programs:

* ``--targets synthetic`` (default): the renderings of random synthetic programs
  (``csgnet.synth.sample_programs``, length ``--length``); each start program is the same program
  with every parameter moved by a uniform integer in ``[-shift, shift]`` (a parser's near miss).
* ``--targets silhouettes``: images of the shipped silhouette test split; each start program is the
  nearest neighbour (lowest chamfer) among ``--pool`` random synthetic programs.

For ``maxiter`` in 1, 2, 4, 10 and unlimited and both modes, the script prints the mean chamfer
before and after (the true score of the returned program; for the reference mode also the mean
score it reports), the wall-clock and CPU (process) seconds per image, and the objective calls and
distinct renders per image. CPU seconds are the steadier figure on a shared, loaded machine. It then
compares drawing a missing primitive together with its axis neighbours (the default) against
drawing one primitive per miss.

Baseline (same run, same images, the first ``--baseline`` of them): the published procedure as a
plain loop, every objective call rendering its program with ``csgnet.renderer.render_programs`` and
scoring it with ``csgnet.metrics.chamfer`` (no cache), under scipy's Powell with the reference's
truncation and clipping. ``csgnet.refine(mode="reference")`` runs the same search, so the two must
return the same programs (checked) and the ratio of their times is the speed-up of the cached,
batched objective.

``--dim 3``: 3D refinement by IoU (``|A∧B| / (|A∨B| + 1)``, the improved mode) on the volumes of
random synthetic 3D programs (``--length``, default 5) with shifted starts as above: IoU before and
after, seconds, calls and renders per volume for each ``maxiter``; then drawing a missing primitive
alone (the 3D default) against drawing it with its axis neighbours; then the same search as a plain
loop (``render_programs`` and ``metrics.iou_3d`` per objective call, no cache), which must return
programs of the same scores.

Usage::

    python bench/bench_refine.py --threads 1 [--images 40] [--baseline 3] [--targets synthetic]
    python bench/bench_refine.py --threads 1 --dim 3 [--images 20] [--length 5] [--baseline 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np
import torch


def _synthetic(n: int, length: int, shift: int, seed: int, dim: int = 2):
    from csgnet.synth import sample_programs
    from csgnet.renderer import render_programs
    from csgnet.vocab import vocabulary

    rng = np.random.default_rng(seed)
    vocab = vocabulary(dim)
    progs = [vocab.decode(t) for t in sample_programs(dim, length, n, rng)]
    targets = render_programs(progs, dim).numpy()
    starts = []
    for p in progs:
        params = np.array([v for d in p.draws for v in d.params])
        starts.append(p.with_params(params + rng.integers(-shift, shift + 1, len(params))))
    return starts, targets


def _silhouettes(n: int, length: int, pool: int, seed: int):
    from csgnet import metrics
    from csgnet.synth import sample_programs
    from csgnet.renderer import render_programs
    from csgnet.shapes2d import load_silhouettes
    from csgnet.vocab import vocabulary

    rng = np.random.default_rng(seed)
    images = load_silhouettes("test")
    targets = images[np.sort(rng.choice(len(images), n, replace=False))]
    vocab = vocabulary(2)
    cand = [vocab.decode(t) for t in sample_programs(2, length, pool, rng)]
    rendered = render_programs(cand, 2).numpy()
    starts = []
    for t in targets:
        cd = metrics.chamfer(rendered, t)
        starts.append(cand[int(np.argmin(cd))])
    return starts, targets


def _plain_powell(program, target, maxiter):
    """The published procedure, one render and one chamfer per objective call (the baseline)."""
    from scipy.optimize import minimize

    from csgnet import metrics
    from csgnet.renderer import render_programs

    build = program.with_params

    def objective(x):
        v = np.clip(x.astype(int), 8, 56)
        return metrics.chamfer(render_programs([build(v)], 2)[0].numpy(), target)

    x0 = np.array([v for d in program.draws for v in d.params], dtype=np.float64)
    res = minimize(objective, x0, method="Powell", tol=1e-4, options={"maxiter": maxiter})
    v = np.trunc(res.x).astype(int)
    v[2::3] = np.clip(v[2::3], 8, 32)
    return build(np.clip(v, 8, 56)), float(res.fun)


def _timed(fn, n: int):
    """``fn()``, with its wall-clock and CPU (process) seconds per image over ``n`` images."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, (time.perf_counter() - w0) / n, (time.process_time() - c0) / n


def _prefetch_run(name: str, value: int, starts, targets) -> tuple[float, float]:
    """Wall and CPU seconds per item of refining every start to convergence with
    ``csgnet.refinement.<name> = value`` (``PREFETCH`` or ``PREFETCH_3D``; restored afterwards)."""
    import csgnet
    from csgnet import refinement

    default = getattr(refinement, name)
    setattr(refinement, name, value)
    try:
        _, wall, cpu = _timed(lambda: [csgnet.refine(s, t) for s, t in zip(starts, targets)], len(targets))
    finally:
        setattr(refinement, name, default)
    return wall, cpu


def _baseline(pairs, metric: str, unit: str, plain, ours, same) -> None:
    """The baseline table (nothing if ``pairs`` is empty): for maxiter 1 and unlimited, the plain loop
    ``plain(start, target, maxiter)`` against ``ours = (label, fn(start, target, maxiter))`` over the
    ``(start, target)`` pairs, seconds per item, the CPU ratio and whether ``same = (label, fn(plain_out,
    our_result))`` holds for every pair."""
    if not pairs:
        return
    print(f"\nBaseline: plain Powell loop (render_programs + {metric} per call), first {len(pairs)} {unit}s")
    print(f"| maxiter | plain loop wall / CPU s/{unit} | {ours[0]} wall / CPU s/{unit} | ratio (CPU) | {same[0]} |")
    print("|---|---|---|---|---|")
    for it in (1, None):
        base, wb, cb = _timed(lambda: [plain(s, t, it) for s, t in pairs], len(pairs))
        res, wo, co = _timed(lambda: [ours[1](s, t, it) for s, t in pairs], len(pairs))
        print(f"| {it if it is not None else 'unlimited'} | {wb:.3f} / {cb:.3f} | {wo:.3f} / {co:.3f} | "
              f"{cb / co:.0f}x | {all(same[1](b, o) for b, o in zip(base, res))} |", flush=True)


def _plain_powell_3d(program, target, maxiter):
    """The improved mode's 3D search as a plain loop: one render and one ``iou_3d`` per objective call."""
    from scipy.optimize import minimize

    from csgnet import metrics, refinement
    from csgnet.renderer import render_programs

    lo, hi = refinement._box(program, "improved", None)

    def objective(x):
        v = np.clip(np.rint(x), lo, hi).astype(np.int64)
        return -metrics.iou_3d(render_programs([program.with_params(v)], 3)[0].numpy(), target)

    x0 = np.array([v for d in program.draws for v in d.params], dtype=np.float64)
    res = minimize(objective, x0, method="Powell", tol=refinement.TOL, options={"maxiter": maxiter})
    return max(-float(res.fun), -objective(x0))


def bench_3d(args, iters) -> None:
    """The ``--dim 3`` tables (see the module docstring)."""
    import csgnet

    starts, targets = _synthetic(args.images, args.length, args.shift, args.seed, dim=3)
    print(f"# targets: {len(targets)} synthetic 3D length-{args.length} programs, starts shifted by "
          f"up to {args.shift} voxels per parameter")
    csgnet.refine(starts[0], targets[0], maxiter=1)  # warm-up
    print("| maxiter | IoU before | IoU after | wall s/volume | CPU s/volume | evaluations/volume | renders/volume |")
    print("|---|---|---|---|---|---|---|")
    for it in iters:
        results, wall, cpu = _timed(lambda: [csgnet.refine(s, t, maxiter=it) for s, t in zip(starts, targets)],
                                    len(targets))
        print(f"| {it if it is not None else 'unlimited'} | {np.mean([r.initial_score for r in results]):.4f} | "
              f"{np.mean([r.score for r in results]):.4f} | {wall:.3f} | {cpu:.3f} | "
              f"{np.mean([r.evaluations for r in results]):.0f} | {np.mean([r.rendered for r in results]):.0f} |",
              flush=True)

    print(f"\nPrimitive drawing, unlimited iterations, all {len(targets)} volumes")
    print("| objective | wall s/volume | CPU s/volume |\n|---|---|---|")
    for label, prefetch in (("one primitive drawn per miss (default)", 0), ("axis neighbours within 2 voxels", 2),
                            ("axis neighbours within 8 voxels (the 2D default)", 8)):
        wall, cpu = _prefetch_run("PREFETCH_3D", prefetch, starts, targets)
        print(f"| {label} | {wall:.3f} | {cpu:.3f} |", flush=True)

    _baseline(list(zip(starts, targets))[:args.baseline], "metrics.iou_3d", "volume", _plain_powell_3d,
              ("csgnet.refine", lambda s, t, it: csgnet.refine(s, t, maxiter=it)),
              ("same scores", lambda b, o: b == o.score))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--baseline", type=int, default=3, help="images for the plain-loop baseline (0: none)")
    ap.add_argument("--targets", choices=("synthetic", "silhouettes"), default="synthetic")
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2, help="2D (chamfer) or 3D (IoU) refinement")
    ap.add_argument("--length", type=int, default=None, help="synthetic program length (default 13 in 2D, 5 in 3D)")
    ap.add_argument("--shift", type=int, default=3, help="synthetic: parameter perturbation of the start")
    ap.add_argument("--pool", type=int, default=2000, help="silhouettes: random programs to pick starts from")
    ap.add_argument("--maxiter", default="1,2,4,10,none", help="comma-separated; 'none' = unlimited")
    ap.add_argument("--threads", type=int, default=1, help="torch and OpenCV threads")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    import cv2

    import csgnet
    from csgnet import metrics
    from csgnet.renderer import render_programs

    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    print(f"# command: python {' '.join(sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"torch {torch.__version__}, OpenCV {cv2.__version__}, threads {args.threads}, "
          f"load average {os.getloadavg()[0]:.1f}")
    iters = [None if s.strip().lower() == "none" else int(s) for s in args.maxiter.split(",")]
    if args.length is None:
        args.length = 13 if args.dim == 2 else 5
    if args.dim == 3:
        return bench_3d(args, iters)
    if args.targets == "synthetic":
        starts, targets = _synthetic(args.images, args.length, args.shift, args.seed)
        print(f"# targets: {len(targets)} synthetic length-{args.length} programs, starts shifted by "
              f"up to {args.shift} px per parameter")
    else:
        starts, targets = _silhouettes(args.images, args.length, args.pool, args.seed)
        print(f"# targets: {len(targets)} silhouette test images, starts = nearest of {args.pool} random "
              f"length-{args.length} programs")
    csgnet.refine(starts[0], targets[0], maxiter=1)  # warm-up (imports, first allocations)

    def true_score(prog, target):
        return metrics.chamfer(render_programs([prog], 2)[0].numpy(), target)


    def timed(fn, n=len(targets)):
        return _timed(fn, n)

    print("| maxiter | mode | chamfer before | chamfer after (program) | reported | wall s/image | "
          "CPU s/image | evaluations/image | renders/image |")
    print("|---|---|---|---|---|---|---|---|---|")
    for it in iters:
        for mode in ("improved", "reference"):
            results, wall, cpu = timed(lambda: [csgnet.refine(s, t, maxiter=it, mode=mode)
                                                for s, t in zip(starts, targets)])
            before = np.mean([r.initial_score for r in results])
            after = np.mean([true_score(r.program, t) for r, t in zip(results, targets)])
            reported = np.mean([r.score for r in results])
            print(f"| {it if it is not None else 'unlimited'} | {mode} | {before:.3f} | {after:.3f} | "
                  f"{reported:.3f} | {wall:.3f} | {cpu:.3f} | {np.mean([r.evaluations for r in results]):.0f} | "
                  f"{np.mean([r.rendered for r in results]):.0f} |", flush=True)

    # batched drawing of a missing primitive's neighbours against drawing one primitive per miss
    from csgnet import refinement

    default = refinement.PREFETCH
    print(f"\nPrimitive drawing, improved mode, unlimited iterations, all {len(targets)} images")
    print("| objective | wall s/image | CPU s/image | ratio (CPU) |")
    print("|---|---|---|---|")
    rows = [(label, *_prefetch_run("PREFETCH", prefetch, starts, targets))
            for label, prefetch in (("cached, one primitive drawn per miss", 0),
                                    (f"cached, axis neighbours within {default} px drawn with a miss (default)",
                                     default))]
    for label, wall, cpu in rows:
        print(f"| {label} | {wall:.3f} | {cpu:.3f} | {rows[0][2] / cpu:.2f}x |", flush=True)

    _baseline(list(zip(starts, targets))[:args.baseline], "metrics.chamfer", "image", _plain_powell,
              ("csgnet.refine(mode='reference')", lambda s, t, it: csgnet.refine(s, t, maxiter=it, mode="reference")),
              ("same programs and scores", lambda b, o: b[0] == o.program and b[1] == o.score))


if __name__ == "__main__":
    main()
