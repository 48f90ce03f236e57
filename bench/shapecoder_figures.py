"""Pictures of a ShapeCoder run's abstractions (as the paper's Fig. 6): one PNG per abstraction of
``RUN_DIR/library.txt`` with up to ``--count`` of the run's programs that call it, the parts its calls make in
a second colour; with ``--dreams N``, a second PNG (``..._dreams.png``) with N random valid dreams of it.

Usage::

    python bench/shapecoder_figures.py RUN_DIR --out FIG_DIR [--count 4] [--dreams 4]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from shapeprog.coder.lang import Call, Library, parse, walk
from shapeprog.coder.picture import dream_sheet, usage_sheet


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--out", required=True)
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument("--size", type=int, default=192, help="cell side in pixels")
    ap.add_argument("--top", type=int, help="only the TOP most used abstractions (file names <rank>_<name>.png)")
    ap.add_argument("--prefix", default="", help="prefix of the file names")
    ap.add_argument("--dreams", type=int, default=0, help="also draw this many random dreams per abstraction")
    ap.add_argument("--seed", type=int, default=0, help="seed of the dreams")
    args = ap.parse_args(argv)
    print(f"# command: python {' '.join(sys.argv)}")
    run = Path(args.run)
    lib = Library.from_text((run / "library.txt").read_text(), file=str(run / "library.txt"))
    progs = [parse(ln.partition(":")[2], lib) for ln in (run / "programs.txt").read_text().splitlines()]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    uses = {ab.name: sum(1 for p in progs for n in walk(p) if isinstance(n, Call) and n.fn == ab.name)
            for ab in lib.abstractions}
    abs_ = list(lib.abstractions)
    if args.top:
        abs_ = sorted(abs_, key=lambda a: -uses[a.name])[:args.top]
    for rank, ab in enumerate(abs_):
        name = f"{args.prefix}{rank + 1}_{ab.name}.png" if args.top else f"{args.prefix}{ab.name}.png"
        try:
            usage_sheet(progs, lib, ab.name, out / name, count=args.count, size=args.size)
            print(f"{out / name}: {uses[ab.name]} calls: {ab.to_text()}")
        except ValueError as e:
            print(f"{ab.name}: {e}")
        if args.dreams:
            dname = name[:-4] + "_dreams.png"
            try:
                dream_sheet(ab.name, lib, out / dname, count=args.dreams, size=args.size, seed=args.seed)
                print(f"{out / dname}: {args.dreams} dreams")
            except ValueError as e:
                print(f"{ab.name}: {e}")


if __name__ == "__main__":
    main()
