"""Pictures of a ShapeCoder run's abstractions (as the paper's Fig. 6, usages only: dreams are not built):
one PNG per abstraction of ``RUN_DIR/library.txt`` with up to ``--count`` of the run's programs that call it,
the parts its calls make in a second colour.

Usage::

    python bench/shapecoder_figures.py RUN_DIR --out FIG_DIR [--count 4]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from shapeprog.coder.lang import Library, parse
from shapeprog.coder.picture import usage_sheet


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--out", required=True)
    ap.add_argument("--count", type=int, default=4)
    args = ap.parse_args(argv)
    print(f"# command: python {' '.join(sys.argv)}")
    run = Path(args.run)
    lib = Library.from_text((run / "library.txt").read_text(), file=str(run / "library.txt"))
    progs = [parse(ln.partition(":")[2], lib) for ln in (run / "programs.txt").read_text().splitlines()]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for ab in lib.abstractions:
        try:
            usage_sheet(progs, lib, ab.name, out / f"{ab.name}.png", count=args.count)
            print(f"{out / (ab.name + '.png')}: {ab.to_text()}")
        except ValueError as e:
            print(f"{ab.name}: {e}")


if __name__ == "__main__":
    main()
