"""Command line: execute or fit ShapeAssembly programs.

    python -m shapeprog run chair/173 -o chair.obj --png chair.png
    python -m shapeprog run my_program.txt -o shape.ply
    python -m shapeprog fit table/33075 --points cloud.obj --steps 400 -o fitted.txt
    python -m shapeprog silhouettes --out silhouettes.npz

A program is named by a corpus id (``chair/173``, ``table/33075``, ``storage/46436``) or a
file path. The mesh format follows the ``-o`` suffix: .obj (the reference layout), .ply or
.glb (parts coloured by the program line that created them).
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import torch

from shapeio import atomic_write, refuse_overwrite

from . import corpus, io
from .execute import execute
from .fit import fit
from .lang import ParseError, parse
from .metrics import adaptive_threshold, chamfer, fscore
from .picture import render_png
from .sampling import sample_surface
from .silhouettes import build, write


def _load_program(spec: str):
    path = Path(spec)
    if path.is_file():
        return parse(path.read_text(), file=str(path)), str(path)
    cat, _, ident = spec.partition("/")
    if cat in corpus.CATEGORIES and ident.isdigit():
        return parse(corpus.read(cat, int(ident)), file=f"{cat}/{ident}.txt"), spec
    raise SystemExit(f"error: {spec!r} is neither a file nor a corpus id like 'chair/173'")


def _refuse_overwrite(outputs, inputs) -> None:
    """Stop before writing an output over an input file (a corpus id is no file: never matches)."""
    try:
        refuse_overwrite(outputs, [p for p in inputs if p is not None and Path(p).is_file()])
    except FileExistsError as e:
        raise SystemExit(f"error: {e}") from None


def _write_mesh(path: str, shape) -> None:
    suffix = Path(path).suffix.lower()
    if suffix == ".obj":
        io.write_obj(path, shape.corners)
    elif suffix == ".ply":
        io.write_ply(path, shape.corners, labels=shape.line.numpy())
    elif suffix == ".glb":
        io.write_glb(path, shape.corners, labels=shape.line.numpy())
    else:
        raise SystemExit(f"error: unknown mesh format {suffix!r} (use .obj, .ply or .glb)")


def _png(path: str, shape, size: int) -> None:
    render_png(shape.corners, path, labels=shape.line.numpy(), size=size)


def _cmd_run(args) -> int:
    prog, name = _load_program(args.program)
    _refuse_overwrite([args.output, args.png], [args.program])
    with torch.no_grad():
        shape = execute(prog, dtype=torch.float64 if args.float64 else torch.float32)
    print(f"{name}: {len(prog.blocks)} blocks, {len(shape)} leaf cuboids")
    if args.output:
        _write_mesh(args.output, shape)
        print(f"wrote {args.output}")
    if args.png:
        _png(args.png, shape, args.size)
        print(f"wrote {args.png}")
    return 0


def _cmd_fit(args) -> int:
    prog, name = _load_program(args.program)
    _refuse_overwrite([args.output, args.mesh], [args.program, None if args.points == "example" else args.points])
    if args.points == "example":
        pts = torch.as_tensor(corpus.example_points())
    else:
        pts = io.read_points(args.points)  # (N, 3) float32
    g = torch.Generator().manual_seed(args.seed)
    thr = float(adaptive_threshold(pts))  # the target's F-score threshold, the same before and after

    def score(p):
        with torch.no_grad():
            x, _ = sample_surface(execute(p).corners, 10000, generator=torch.Generator().manual_seed(args.seed))
            return float(chamfer(x, pts)), fscore(x, pts, threshold=thr)

    cd0, f0 = score(prog)
    res = fit(prog, pts, steps=args.steps, lr=args.lr, reg=args.reg, decimals=args.decimals, generator=g)
    cd1, f1 = score(res.program)
    print(f"{name}: chamfer {cd0:.4f} -> {cd1:.4f}, F-score {f0:.1f} -> {f1:.1f}, "
          f"{args.steps} steps in {res.seconds:.1f} s")
    if args.output:
        atomic_write(args.output, res.text)
        print(f"wrote {args.output}")
    else:
        sys.stdout.write(res.text)
    if args.mesh:
        with torch.no_grad():
            _write_mesh(args.mesh, execute(res.program))
    return 0


def _cmd_silhouettes(args) -> int:
    t0 = time.perf_counter()
    try:
        data = build(size=args.size, margin=args.margin, limit=args.limit, progress=not args.quiet)
    except ValueError as e:  # --size / --margin, checked before any program runs
        raise SystemExit(f"error: {e}") from None
    write(args.out, data, margin=args.margin)
    counts = ", ".join(f"{split} {len(s.images)}" for split, s in data.items())
    print(f"wrote {args.out}: {counts} images in {time.perf_counter() - t0:.1f} s")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="shapeprog", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="execute a program and export its cuboids")
    r.add_argument("program", help="corpus id (chair/173) or program file")
    r.add_argument("-o", "--output", help="mesh file (.obj, .ply, .glb)")
    r.add_argument("--png", help="picture file (.png)")
    r.add_argument("--size", type=int, default=512, help="picture size in pixels")
    r.add_argument("--float64", action="store_true", help="execute in float64 (default float32)")
    r.set_defaults(func=_cmd_run)
    f = sub.add_parser("fit", help="fit a program's parameters to a point cloud")
    f.add_argument("program", help="corpus id (table/33075) or program file")
    f.add_argument("--points", default="example",
                   help="point cloud file (.obj 'v' lines or .ply) or 'example' (comp_pc.obj)")
    f.add_argument("--steps", type=int, default=400)
    f.add_argument("--lr", type=float, default=1e-3)
    f.add_argument("--reg", type=float, default=1e-3)
    f.add_argument("--decimals", type=int, default=3)
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("-o", "--output", help="fitted program file (default: print)")
    f.add_argument("--mesh", help="also write the fitted shape (.obj, .ply, .glb)")
    f.set_defaults(func=_cmd_fit)
    s = sub.add_parser("silhouettes", help="render front and side silhouettes of the corpus to an .npz")
    s.add_argument("--out", required=True, help="output file (.npz)")
    s.add_argument("--size", type=int, default=64, help="image side in pixels")
    s.add_argument("--margin", type=int, default=4, help="free pixels on each side of the longer extent")
    s.add_argument("--limit", type=int, help="only the first N shapes per category and split")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=_cmd_silhouettes)
    args = ap.parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            return args.func(args)
    except ParseError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
