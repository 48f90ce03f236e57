"""Controls of corpus programs with and without macros, and how closely the macro programs reproduce them.

For each corpus program (``--programs``; by default the chairs of docs/editor.md, or ``--first N`` of a
category's ids) it refactors the program with a shipped ShapeMOD library (``--library``,
:func:`shapeprog.macros.refactor`), then prints the number of editor controls of the base program
(:func:`shapeprog.editor.controls`) and of the hierarchical macro program, and the largest distance from
a leaf of one executed shape to the nearest leaf of the other (max corner offset). Programs that the
modified grammar cannot hold are counted and skipped.

Usage::

    OMP_NUM_THREADS=1 python bench/editor_macro_controls.py [--programs chair/173 chair/42220 ...]
        [--first N --category chair] [--library chair]
"""
from __future__ import annotations

import argparse
import sys
import time

from shapeprog import corpus, parse
from shapeprog.editor import controls
from shapeprog.execute import execute
from shapeprog.macros import hierarchy, load_library, refactor
from shapeprog.macros.execute import execute_hierarchy

DEFAULT = ("chair/173", "chair/42220", "chair/44017", "chair/36880", "chair/42974")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--programs", nargs="*", default=list(DEFAULT))
    ap.add_argument("--first", type=int, help="use the first N ids of --category instead")
    ap.add_argument("--category", default="chair")
    ap.add_argument("--library", default="chair")
    args = ap.parse_args(argv)
    lib = load_library(args.library)
    ids = ([f"{args.category}/{i}" for i in corpus.ids(args.category)[:args.first]] if args.first
           else args.programs)
    print(f"command: python bench/{__file__.rsplit('/', 1)[-1]} {' '.join(sys.argv[1:] if argv is None else argv)}")
    print("| program | controls (ShapeAssembly) | controls (macros) | largest leaf distance |")
    print("|---|---|---|---|")
    t0, tot_base, tot_macro, skipped, worst = time.time(), 0, 0, 0, 0.0
    for spec in ids:
        cat, _, ident = spec.partition("/")
        p = parse(corpus.read(cat, int(ident)), f"{spec}.txt")
        try:
            r = refactor(p, lib, category=cat, shape_id=int(ident))
        except ValueError:
            skipped += 1
            continue
        h = hierarchy.parse(r.text, f"{spec}_macros.txt", lib)
        nb, nm = len(controls(p, cuboids=False)), len(controls(h, lib, cuboids=False))
        a, b = execute_hierarchy(h, lib).corners, execute(p).corners
        d = (a[:, None] - b[None]).abs().amax((2, 3))
        dist = float(max(d.amin(1).max(), d.amin(0).max())) if a.shape == b.shape else float("inf")
        worst = max(worst, dist)
        tot_base, tot_macro = tot_base + nb, tot_macro + nm
        if not args.first:
            print(f"| {spec} | {nb} | {nm} | {dist:.3f} |")
    n = len(ids) - skipped
    print(f"{n} programs ({skipped} skipped): controls {tot_base} -> {tot_macro} "
          f"({tot_macro / max(tot_base, 1):.2f}); largest leaf distance {worst:.3f}; {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
