"""The ShapeMOD paper's Table 1: No Macros, Baseline macros and ShapeMOD rows per category.

Every sub-program of the chosen shapes is written as its best program P* (beam search over its first
``max_orders`` orderings) under each library: the base functions alone (No Macros), the baseline macros of
:mod:`shapeprog.macros.baseline` built from the same sub-programs, and the ShapeMOD library (the shipped one
or a file). Columns, per shape (summed over its sub-programs), with the definitions of the spec that match
the paper's No-Macros row best (spec (c)):

* **f**: the sum over sub-programs of f(p) without the ``|L|`` term, plus the library's macro count once;
  also **f/sub**: ShapeMOD.py's own scale, the mean over sub-programs of f(p) (``|L|`` term included).
* **|L|**: 5 base functions plus the macros.
* **fn**: program lines including each sub-program's bbox line plus 2 (its START/STOP tokens).
* **d**: cuboid-id plus categorical parameters.
* **f** (floats): float parameters including each sub-program's 3 bbox dims.
* **b**: boolean parameters including each bbox line's.

The alternative definitions (lines without bbox/START/STOP, floats and bools without the bbox line's) are
kept in the rows (``fn_calls``, ``i``, ``c``, ``floats_no_bbox``, ``b_no_bbox``). Beside the absolute f, its
ratio to the same run's No Macros f is compared with the paper's ratio: the paper's absolute f is on another
scale (spec (c): its No Macros rows are 12-17 % above these definitions'), so only the ratio is like for like.
"""
from __future__ import annotations

import math
import time
from concurrent.futures import Executor
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from .api import collection, load_library
from .baseline import baseline_library
from .lang import BOOL, CUBE, FLOAT
from .library import Library
from .objective import beam_search, exact_search, fit_options, templates

__all__ = ["PAPER", "library_rows", "table1", "table1_result", "table1_rows"]

#: The paper's Table 1 (f, |L|, fn, d, f, b) per category and method.
PAPER = {
    "chair": {"No Macros": (411, 5, 29.8, 17.8, 84.4, 11.3), "Baseline": (312, 36, 21.7, 7.0, 80.2, 4.2),
              "ShapeMOD": (260, 17, 21.0, 6.4, 58.1, 8.6)},
    "table": {"No Macros": (356, 5, 25.6, 16.3, 70.7, 9.6), "Baseline": (263, 36, 18.0, 6.4, 65.8, 3.2),
              "ShapeMOD": (214, 15, 17.4, 5.1, 48.7, 5.6)},
    "storage": {"No Macros": (453, 5, 30.4, 21.6, 92.2, 11.7), "Baseline": (314, 48, 18.4, 7.6, 88.45, 2.65),
                "ShapeMOD": (283, 17, 21.1, 7.6, 68.9, 4.0)},
}


def _stats_chunk(lib_text: str, items, mode: str):
    """Worker: per sub-program (f, calls, floats, cube ids, categoricals, bools) of its best program."""
    lib = Library.from_text(lib_text) if lib_text else Library()
    tpls = templates(lib)
    nm = len(lib.macros)
    out = []
    for orders in items:
        best, best_f = (), math.inf
        for lines in orders:
            opts = fit_options(lines, tpls)
            calls, f = beam_search(opts, nm) if mode == "beam" else exact_search(opts, nm)
            if f < best_f:
                best, best_f = calls, f
        row = [best_f, len(best), 0, 0, 0, 0]
        for o in best:
            for p in lib[o.func].params:
                row[{FLOAT: 2, CUBE: 3, BOOL: 5}.get(p.type, 4)] += 1
        out.append(row)
    return out


def library_rows(library: Library, items: Sequence[Sequence], shapes: Sequence[str], mode: str = "beam",
                 executor: Executor | None = None, chunk: int = 50) -> dict:
    """Table 1 figures of ``library`` over sub-programs ``items`` (orderings' lines) of ``shapes`` (the
    shape key of each item)."""
    text = library.to_text()
    chunks = [(text, list(items[i:i + chunk]), mode) for i in range(0, len(items), chunk)]
    if executor is None:
        parts = [_stats_chunk(*c) for c in chunks]
    else:
        parts = [f.result() for f in [executor.submit(_stats_chunk, *c) for c in chunks]]
    rows = np.array([r for p in parts for r in p], dtype=float).reshape(-1, 6)
    nm = len(library.macros)
    uniq = sorted(set(shapes))
    n_shapes = len(uniq)
    n_sub = len(items)
    f_sub = rows[:, 0]
    per_shape = lambda col: float(col.sum()) / n_shapes  # noqa: E731
    return {
        "f": per_shape(f_sub - nm) + nm, "f_sub": float(f_sub.mean()), "L": len(library),
        "fn": per_shape(rows[:, 1] + 3), "d": per_shape(rows[:, 3] + rows[:, 4]), "floats": per_shape(rows[:, 2] + 3),
        "b": per_shape(rows[:, 5] + 1),
        "fn_calls": per_shape(rows[:, 1]), "i": per_shape(rows[:, 3]), "c": per_shape(rows[:, 4]),
        "floats_no_bbox": per_shape(rows[:, 2]), "b_no_bbox": per_shape(rows[:, 5]),
        "shapes": n_shapes, "subprograms": n_sub,
    }


def table1_rows(categories: Sequence[str] = ("chair",), limit: int | None = None, seed: int = 0,
                executor: Executor | None = None, mode: str = "beam",
                library_files: Mapping[str, str] | None = None, extra: Mapping[str, Library] | None = None,
                max_orders: int = 1000, log: Callable[[str], None] | None = None) -> list[dict]:
    """Table 1 as rows, one per category and method (see the module docstring): the :func:`library_rows`
    figures, ``category`` and ``method``, ``f_ratio`` (f over the same run's No Macros f) and the paper's
    ``paper_f_ratio`` and ``paper_L`` (None where the paper has no such row). A category without a shipped
    library and without a file in ``library_files`` gets no ShapeMOD row; every library of ``extra`` (a
    row name to a library) is applied to every category after it."""
    rows = []
    for cat in categories:
        t0 = time.time()
        nodes, ids = collection(cat, "all", limit, seed, max_orders=max_orders)
        shapes = [k.rsplit("/", 1)[0] for k in nodes.keys]
        libs = {"No Macros": Library(), "Baseline": baseline_library([ls[0] for ls in nodes.lines])}
        files = dict(library_files or {})
        if cat in files:
            libs["ShapeMOD"] = Library.from_text(Path(files[cat]).read_text(encoding="utf-8"), files[cat])
        else:
            try:
                libs["ShapeMOD"] = load_library(cat)
            except ValueError:
                pass
        for name, lib in (extra or {}).items():
            if name in libs:
                raise ValueError(f"an extra library may not be named {name!r} (a row of Table 1 already)")
            libs[name] = lib
        base_f = None
        for name, lib in libs.items():
            r = library_rows(lib, nodes.lines, shapes, mode, executor)
            base_f = r["f"] if base_f is None else base_f
            p = PAPER[cat].get(name)
            rows.append({"category": cat, "method": name, **r, "f_ratio": r["f"] / base_f,
                         "paper_f_ratio": None if p is None else p[0] / PAPER[cat]["No Macros"][0],
                         "paper_L": None if p is None else p[1]})
            if log:
                log(f"{cat} {name}: done ({time.time() - t0:.0f} s)")
    return rows


def table1_result(rows: Sequence[dict], command: str, limit: int | None = None, seed: int = 0,
                  notes: Sequence[str] = ()) -> dict:
    """``rows`` (:func:`table1_rows`) as a result file's content (:mod:`shapeio.results`): f absolute and as a
    ratio to the same run's No Macros, beside the paper's ratio; the paper's absolute rows are on another
    scale (its No Macros f is 12-17 % above ours) and are given in a note only; ``notes`` are added."""
    from shapeio.results import column, make_result  # lazy: loaded when a result is written

    cols = [column("category", "category"), column("method", "method"), column("f", "f", 1),
            column("f_ratio", "f / No Macros", 3), column("paper_f_ratio", "paper: f / No Macros", 3),
            column("L", "\\|L\\|"), column("paper_L", "paper \\|L\\|"), column("fn", "fn", 1),
            column("d", "d", 1), column("floats", "f (floats)", 1), column("b", "b", 1),
            column("f_sub", "f per sub-program", 2), column("shapes", "shapes"),
            column("subprograms", "sub-programs")]
    scale = "all shapes" if limit is None else f"a random subset of {limit} shapes per category (seed {seed})"
    notes = [f"Per shape, summed over its sub-programs; {scale}. The column definitions: "
             "docs/shapemod.md, 'Table 1'.",
             "Compare the ratios: the paper's absolute rows are on another scale (its No Macros f is "
             + ", ".join(f"{PAPER[c]['No Macros'][0]} for {c}" for c in PAPER) + "; ours "
             + ", ".join(f"{r['f']:.1f}" + f" for {r['category']}" for r in rows if r["method"] == "No Macros")
             + "), so only f over the same run's No Macros f is like for like.", *notes]
    return make_result("ShapeMOD Table 1: the objective f per shape, absolute and as a ratio to No Macros",
                       cols, rows, notes, command)


def table1(categories: Sequence[str] = ("chair",), limit: int | None = None, seed: int = 0,
           executor: Executor | None = None, mode: str = "beam", library_files: Mapping[str, str] | None = None,
           max_orders: int = 1000, log: Callable[[str], None] | None = None) -> str:
    """Table 1 as markdown (the result of :func:`table1_result`)."""
    from shapeio.results import markdown  # lazy: as above

    rows = table1_rows(categories, limit, seed, executor, mode, library_files, max_orders=max_orders, log=log)
    return markdown(table1_result(rows, "shapeprog.macros.table1.table1", limit, seed))
