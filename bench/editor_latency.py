"""Latency of the program editors: from a control change to the new geometry.

For each ShapeAssembly program (``--programs``, corpus ids; by default chair/173, chair/42220 and
chair/42974, the longest corpus chair: 72 lines) it times, over ``--edits`` edits of float
controls drawn at random (seed ``--seed``) within their ranges, after one warm-up edit:

* ``core``: :meth:`shapeprog.editor.EditSession.set` (the edit through the language's printer and parser,
  then execution with the compiled plan reused), i.e. change -> new cuboids;
* ``page``: setting the control's value on a running :class:`shapeprog.editor.server.EditorApp` (what a
  slider move in the browser runs on the server: the core step, then the meshes and the highlight sent
  to the page's scene), when viser is installed;
* ``structural``: a drop-down / checkbox edit on the page, which compiles the new structure; timed to the new
  geometry sent (``EditorApp.state["update_ms"]``) and to the end of the change, when the cuboids each
  control moves have been found again (one backward pass per leaf) and the moved parts outlined.

and for the CSG editor ``page`` on ``c(32,32,28)s(32,32,20)-`` (a slider: re-render and new image).
Figures are medians (and 90th percentiles) in milliseconds, wall clock. ``--roundtrip-corpus`` also
checks that every corpus program's controls, set to their current values, give its text back, and
prints the count and the time.

Usage::

    OMP_NUM_THREADS=1 python bench/editor_latency.py [--programs chair/173 chair/42220 chair/42974] [--edits 200]
        [--seed 0] [--roundtrip-corpus]
"""
from __future__ import annotations

import argparse
import os
import platform
import random
import socket
import statistics
import sys
import time
from datetime import date

import torch

from shapeprog import corpus
from shapeprog.editor import FLOAT, EditSession, apply, controls
from shapeprog.editor.controls import BOOL, CHOICE


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stats(ms: list[float]) -> str:
    q = statistics.quantiles(ms, n=10)[-1] if len(ms) >= 10 else max(ms)
    return f"median {statistics.median(ms):6.2f} ms, p90 {q:6.2f} ms (n={len(ms)})"


def _edits(session: EditSession, n: int, rng: random.Random):
    floats = [c for c in session.controls() if c.kind == FLOAT]
    for _ in range(n):
        c = rng.choice(floats)
        yield c.name, round(rng.uniform(c.low, c.high), 3)


def bench_program(spec: str, edits: int, seed: int, page: bool) -> None:
    cat, _, ident = spec.partition("/")
    text = corpus.read(cat, int(ident))
    s = EditSession(text, f"{cat}/{ident}.txt")
    print(f"{spec}: {len(s.shape)} cuboids, {len(s.controls())} controls")
    rng = random.Random(seed)
    times = []
    for i, (name, v) in enumerate(_edits(s, edits + 1, rng)):
        t0 = time.perf_counter()
        s.set({name: v})
        assert s.shape is not None
        if i:
            times.append(1000 * (time.perf_counter() - t0))
    print(f"  core       (set -> new cuboids):            {_stats(times)}")
    if not page:
        return
    from shapeprog.editor.server import EditorApp

    app = EditorApp(EditSession(text, f"{cat}/{ident}.txt"), port=_free_port())
    try:
        rng = random.Random(seed)
        times = []
        for i, (name, v) in enumerate(_edits(app.session, edits + 1, rng)):
            version = app.state["version"]
            t0 = time.perf_counter()
            app.handle(name).value = v
            dt = 1000 * (time.perf_counter() - t0)
            if app.state["version"] != version + 1:
                continue  # a value equal to the current one: nothing to do
            if i:
                times.append(dt)
        print(f"  page       (slider -> meshes sent):         {_stats(times)}")
        discrete = [c for c in app.session.controls() if c.kind in (BOOL, CHOICE)]
        times, geometry = [], []
        for i in range(min(edits, 40) + 1):
            c = {c.name: c for c in app.session.controls()}[rng.choice(discrete).name]
            v = (not c.value) if c.kind == BOOL else rng.choice([x for x in c.choices if x != c.value] or [c.value])
            t0 = time.perf_counter()
            app.handle(c.name).value = v
            dt = 1000 * (time.perf_counter() - t0)
            if app.state["error"] is None and i:
                times.append(dt)
                geometry.append(app.state["update_ms"])
            app.undo()
        if times:
            print(f"  structural (drop-down -> new geometry):     {_stats(geometry)}")
            print(f"  structural (drop-down -> moved parts shown): {_stats(times)}")
    finally:
        app.stop()


def bench_csg(edits: int, seed: int) -> None:
    from csgnet.editor import CSGEditSession
    from csgnet.editor.server import CSGEditorApp

    app = CSGEditorApp(CSGEditSession("c(32,32,28)s(32,32,20)-"), port=_free_port())
    try:
        rng = random.Random(seed)
        ints = [c for c in app.session.controls() if c.kind == "int"]
        times = []
        for i in range(edits + 1):
            c = rng.choice(ints)
            v = rng.randint(max(c.low, 4), min(c.high, 60))
            version = app.state["version"]
            t0 = time.perf_counter()
            app.handle(c.name).value = v
            dt = 1000 * (time.perf_counter() - t0)
            if app.state["version"] == version + 1 and i:
                times.append(dt)
        print(f"csg c(32,32,28)s(32,32,20)-: page (slider -> new image): {_stats(times)}")
    finally:
        app.stop()


def roundtrip_corpus() -> None:
    from shapeprog.lang import to_text

    t0 = time.perf_counter()
    n = bad = 0
    for cat in corpus.CATEGORIES:
        for _, p in corpus.load(cat, "all"):
            cs = controls(p, cuboids=False)
            n += 1
            if to_text(apply(p, {c.name: c.value for c in cs})) != to_text(p) or len({c.name for c in cs}) != len(cs):
                bad += 1
    print(f"corpus round trip: {n} programs, {bad} differ, {time.perf_counter() - t0:.1f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--programs", nargs="+", default=["chair/173", "chair/42220", "chair/42974"])
    ap.add_argument("--edits", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--roundtrip-corpus", action="store_true")
    args = ap.parse_args()
    print(f"$ OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '')} python {' '.join(sys.argv)}")
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads, {date.today()}")
    try:
        import viser  # noqa: F401
        page = True
    except ImportError:
        page = False
        print("viser is not installed: the page figures are left out (pip install -e '.[editor]')")
    for spec in args.programs:
        bench_program(spec, args.edits, args.seed, page)
    if page:
        bench_csg(args.edits, args.seed)
    if args.roundtrip_corpus:
        roundtrip_corpus()


if __name__ == "__main__":
    main()
