"""Controls of corpus programs with and without macros, and how closely the macro programs reproduce them.

It refactors corpus programs with a ShapeMOD library (``--library``, :func:`shapeprog.macros.refactor`) and
counts the editor controls (:func:`shapeprog.editor.controls`) of each base program and of its hierarchical
macro program, with the largest distance from a leaf of one executed shape to the nearest leaf of the other
(max corner offset): one row per program of ``--programs`` (by default the chairs of docs/editor.md), and one
row of totals over the first ``--first`` ids of ``--category`` (0: none), with the share of those programs
that have a leaf farther than the fit tolerance. Programs that the modified grammar cannot hold are counted
and skipped. ``--out FILE.json`` writes the table as a result file (:mod:`shapeio.results`).

Usage::

    OMP_NUM_THREADS=1 python bench/editor_macro_controls.py [--programs chair/173 chair/42220 ...]
        [--first 400] [--category chair] [--library chair] [--out FILE.json]
"""
from __future__ import annotations

import argparse
import shlex
import sys

from shapeio.results import column, make_result, markdown, write_result
from shapeprog import corpus, parse
from shapeprog.editor import controls
from shapeprog.execute import execute
from shapeprog.macros import hierarchy, load_library, refactor
from shapeprog.macros.execute import execute_hierarchy
from shapeprog.macros.objective import ABS_MAX_ERROR

DEFAULT = ("chair/173", "chair/42220", "chair/44017", "chair/36880", "chair/42974")


def measure(spec: str, lib) -> tuple[int, int, float] | None:
    """``(base controls, macro controls, largest leaf distance)`` of corpus program ``spec``; None when the
    refactoring cannot hold it."""
    cat, _, ident = spec.partition("/")
    p = parse(corpus.read(cat, int(ident)), f"{spec}.txt")
    try:
        r = refactor(p, lib, category=cat, shape_id=int(ident))
    except ValueError:
        return None
    h = hierarchy.parse(r.text, f"{spec}_macros.txt", lib)
    a, b = execute_hierarchy(h, lib).corners, execute(p).corners
    d = (a[:, None] - b[None]).abs().amax((2, 3))
    dist = float(max(d.amin(1).max(), d.amin(0).max())) if a.shape == b.shape else float("inf")
    return len(controls(p, cuboids=False)), len(controls(h, lib, cuboids=False)), dist


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--programs", nargs="*", default=list(DEFAULT), help="one row each (default: docs/editor.md's)")
    ap.add_argument("--first", type=int, default=400, help="a row of totals over the first N ids of --category")
    ap.add_argument("--category", default="chair")
    ap.add_argument("--library", default="chair", help="a shipped library's category or a library file")
    ap.add_argument("--out", help="also write the table to this result file (JSON)")
    args = ap.parse_args(argv)
    lib = load_library(args.library)
    rows = []
    for spec in args.programs:
        m = measure(spec, lib)
        rows.append({"program": spec, "base": m and m[0], "macros": m and m[1], "distance": m and m[2],
                     "note": "" if m else "skipped: the modified grammar cannot hold it"})
    if args.first:
        base, macro, skipped, worst, worst_id, far = 0, 0, 0, 0.0, "", 0
        ids = corpus.ids(args.category)[: args.first]
        for i in ids:
            m = measure(f"{args.category}/{i}", lib)
            if m is None:
                skipped += 1
                continue
            base, macro = base + m[0], macro + m[1]
            if m[2] > worst:
                worst, worst_id = m[2], f"{args.category}/{i}"
            far += m[2] > ABS_MAX_ERROR
        rows.append({"program": f"the first {len(ids)} corpus {args.category}s", "base": base, "macros": macro,
                     "distance": worst,
                     "note": f"{macro / max(base, 1):.2f} of the controls; largest distance {worst_id}; {far} with a "
                             f"leaf more than {ABS_MAX_ERROR} away; {skipped} skipped"})
    cols = [column("program", "program"), column("base", "controls (ShapeAssembly)"),
            column("macros", f"controls (macros of {args.library})"), column("distance", "largest leaf distance", 3),
            column("note", "notes")]
    notes = [f"Largest leaf distance: the largest distance from a leaf of one executed shape to the nearest leaf of "
             f"the other (max corner offset). The refactor accepts a fit when every parameter's residual is at most "
             f"{ABS_MAX_ERROR} (shapeprog.macros.objective.ABS_MAX_ERROR); lever arms (a second attach, a child "
             "scaled into its cuboid) can move a leaf further."]
    command = shlex.join(["python", "bench/editor_macro_controls.py", *(sys.argv[1:] if argv is None else argv)])
    result = make_result("Editor controls with and without macros", cols, rows, notes=notes, command=command)
    if args.out:
        write_result(args.out, result)
    print(markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
