"""The shipped ShapeMOD refactored corpora (``shapeprog/data/shapemod_<category>_refactored.tar.xz``): per category
the archive's size, the shapes refactored, the library, the refactor's wall time and the per-shape means before
(no macros) and after (the category's shipped library) that the archive's ``summary.json`` records. Each archive is
checked first: its program count against its summary, its library hash against the shipped library's.

Prints the table and its command; ``--json`` writes it as a result file (docs/shapemod.md shows it).

Usage::

    python bench/shapemod_refactored.py [--json docs/results/shapemod/refactored_corpora.json]
"""
from __future__ import annotations

import argparse
import sys
from importlib import resources

from shapeio.results import column, make_result, markdown, write_result
from shapeprog.macros import load_library
from shapeprog.macros.refactored import CHECK_TOL, SHIPPED, library_sha256, read_refactored

MEASURES = [("f", "f (sum over sub-programs)"), ("lines", "calls after the bbox lines"),
            ("float", "float parameters"), ("cube", "cuboid ids"), ("categorical", "categoricals"),
            ("bool", "booleans")]


def row(category: str) -> dict:
    ref = resources.files("shapeprog").joinpath("data", SHIPPED[category])
    with resources.as_file(ref) as path:
        programs, s = read_refactored(path)
        kib = path.stat().st_size / 1024
    if len(programs) != s["refactored"]:
        raise SystemExit(f"{path}: {len(programs)} programs, its summary says {s['refactored']}")
    if s.get("library_sha256") != library_sha256(load_library(category)):
        raise SystemExit(f"{path}: made with another library than the shipped {category} library "
                         f"(regenerate it with the command in its summary)")
    return {"summary": s, "kib": kib}


def rows(found: dict) -> list[dict]:
    """One row per measure, one column per category (as the archives' summaries give them)."""
    def each(fn):
        return {c: fn(v["summary"], v) for c, v in found.items()}
    out = [{"measure": "archive; shapes refactored",
            **each(lambda s, v: f"{v['kib']:.0f} KiB; {s['refactored']:,} of {s['shapes']:,}")},
           {"measure": "library: macros, \\|L\\|", **each(lambda s, v: f"{s['library_macros']}, {s['library_size']}")},
           {"measure": "wall (--workers)", **each(lambda s, v: f"{s['seconds']:,.0f} s ({s['workers']})")}]
    for key, label in MEASURES:
        out.append({"measure": label, **each(lambda s, v: f"{s['mean_per_shape'][key + '_before']:.2f} → "
                                                         f"{s['mean_per_shape'][key + '_after']:.2f}")})
    out.append({"measure": "largest leaf-corner distance; shapes above the check tolerance",
                **each(lambda s, v: f"{s['max_corner_error']:.3f}; {len(s['over_tolerance'])}")})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", help="write the result file here (replaced)")
    args = ap.parse_args(argv)
    found = {c: row(c) for c in SHIPPED}
    notes = ["Means per shape over the refactored shapes, before (no macros) → after (the category's shipped "
             "library); f is the ShapeMOD objective summed over a shape's sub-programs (docs/shapemod.md, "
             "'Table 1'). The leaf-corner distance is the largest, over the corpus, between a refactored shape's "
             "executed leaf cuboids and the original's; the check tolerance is "
             f"shapeprog.macros.refactored.CHECK_TOL ({CHECK_TOL}).",
             "Each archive was written by: " + "; ".join(f"{c}: `{v['summary'].get('command', '?')}`"
                                                         for c, v in found.items()) + "; the wall times are "
             "those runs' own (the 2-core CPU, no GPU), from each archive's summary."]
    columns = [column("measure", "per shape, before → after"), *(column(c, c) for c in found)]
    res = make_result("The shipped refactored corpora", columns, rows(found), notes,
                      command="python bench/shapemod_refactored.py" + (f" --json {args.json}" if args.json else ""))
    print(markdown(res))
    if args.json:
        write_result(args.json, res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
