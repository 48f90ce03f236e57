"""Command line of csgnet: a thin layer over the library.

    python -m csgnet render "c(32,32,28)s(32,32,20)-" -o out.png      (.png, .obj, .scad, .npy)
    python -m csgnet render "sp(32,32,32,20)cu(32,32,32,28)*" --dim 3 -o out.obj
    python -m csgnet generate --dim 2 --scale 0.001 --out data/synthetic --workers 2
    python -m csgnet demo --out demo_output
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .lang import ParseError, parse


def _write_render(program, dim: int, out: Path) -> Path:
    import numpy as np

    from . import export, render

    suffix = out.suffix.lower()
    if suffix == ".scad":
        return export.save_scad(program, out)
    img = render(program, dim)[0]
    if suffix == ".png":
        if dim != 2:
            raise SystemExit("error: PNG output is for 2D programs; use .obj, .npy or .scad for 3D")
        return export.save_png(img, out)
    if suffix == ".obj":
        if dim != 3:
            raise SystemExit("error: OBJ output is for 3D programs; use .png, .npy or .scad for 2D")
        return export.save_obj(img, out)
    if suffix == ".npy":
        from shapeio import atomic_write

        return atomic_write(out, lambda f: np.save(f, img, allow_pickle=False))
    raise SystemExit(f"error: unknown output type {suffix!r} for {out}; use .png, .obj, .npy or .scad")


def cmd_render(args) -> int:
    try:
        program = parse(args.program, args.dim)
    except ParseError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    from . import render

    img = render(program, args.dim)[0]
    print(f"{program.text()}  ({len(program)} tokens, {int(img.sum())} {'pixels' if args.dim == 2 else 'voxels'} on)")
    for out in args.output:
        path = _write_render(program, args.dim, Path(out))
        print(f"wrote {path}")
    return 0


def cmd_generate(args) -> int:
    from .data import generate_dataset

    counts = generate_dataset(args.out, dim=args.dim, scale=args.scale, seed=args.seed, workers=args.workers,
                              lengths=args.lengths, progress=not args.quiet)
    print(json.dumps(counts, indent=1, sort_keys=True))
    return 0


def cmd_demo(args) -> int:
    """The main job until the neural parsers ship: a small synthetic dataset and previews."""
    import numpy as np

    from . import export, render
    from .data import generate_dataset, load_dataset

    out = Path(args.out)
    data_dir = out / "synthetic"
    for dim in (2, 3):
        counts = generate_dataset(data_dir, dim=dim, scale=args.scale, seed=args.seed, workers=args.workers,
                                  progress=not args.quiet)
        total = sum(n for per_len in counts.values() for n in (per_len.values() if isinstance(per_len, dict) else [per_len]))
        print(f"{dim}D: generated {total} programs under {data_dir / f'{dim}d'}")
        progs = load_dataset(data_dir, dim, "test")
        preview = out / f"preview_{dim}d"
        preview.mkdir(parents=True, exist_ok=True)
        lines = []
        for length, plist in sorted(progs.items()):
            for i, p in enumerate(plist[: args.per_length]):
                img = render(p, dim)[0]
                stem = preview / f"len{length:02d}_{i}"
                if dim == 2:
                    export.save_png(img, stem.with_suffix(".png"))
                else:
                    export.save_obj(img, stem.with_suffix(".obj"))
                export.save_scad(p, stem.with_suffix(".scad"))
                lines.append(f"{stem.name}\t{p.text()}\t{int(img.sum())}")
                print(f"  {stem.name}: {p.text()}")
        (preview / "programs.tsv").write_text("name\tprogram\ton\n" + "\n".join(lines) + "\n")
        images = [render(line.split("\t")[1], dim)[0] for line in lines]
        if dim == 3:  # three orthographic silhouettes (along x, y, z) side by side
            images = [np.concatenate([v.any(axis=a) for a in range(3)], axis=1) for v in images]
        sheet_path = out / f"preview_{dim}d.png"
        _save_sheet(_contact_sheet(images, cols=6 if dim == 2 else 2), sheet_path)
        print(f"wrote {sheet_path} ({len(lines)} programs; texts in {preview / 'programs.tsv'})")
    print(f"done: {out}")
    return 0


def _contact_sheet(images, cols: int = 6):
    import numpy as np

    h, w = images[0].shape
    rows = -(-len(images) // cols)
    sheet = np.full((rows * (h + 2), cols * (w + 2)), 128, np.uint8)  # grey frames
    for i, img in enumerate(images):
        r, c = divmod(i, cols)
        sheet[r * (h + 2) + 1: r * (h + 2) + 1 + h, c * (w + 2) + 1: c * (w + 2) + 1 + w] = np.where(img, 0, 255)
    return sheet


def _save_sheet(sheet, path: Path, scale: int = 3) -> None:
    import cv2
    import numpy as np

    from shapeio import atomic_write

    big = np.kron(sheet, np.ones((scale, scale), np.uint8))
    ok, buf = cv2.imencode(".png", big)
    if not ok:
        raise RuntimeError(f"could not encode {path}")
    atomic_write(path, buf.tobytes(), mkdir=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m csgnet", description="CSG programs: render, generate datasets.")
    sub = ap.add_subparsers(dest="cmd", required=True)

    r = sub.add_parser("render", help="render one program to .png (2D), .obj (3D), .npy or .scad")
    r.add_argument("program", help='program text, e.g. "c(32,32,28)s(32,32,20)-"')
    r.add_argument("-o", "--output", action="append", required=True, help="output file (repeatable)")
    r.add_argument("--dim", type=int, choices=(2, 3), default=None, help="2 or 3 (default: guessed from the text)")
    r.set_defaults(func=cmd_render)

    g = sub.add_parser("generate", help="generate a synthetic dataset (train/val/test per length)")
    g.add_argument("--dim", type=int, choices=(2, 3), default=2)
    g.add_argument("--scale", type=float, default=0.001, help="fraction of the paper's Table 2 split sizes")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--workers", type=int, default=1)
    g.add_argument("--lengths", type=int, nargs="*", default=None)
    g.add_argument("--out", required=True)
    g.add_argument("--quiet", action="store_true")
    g.set_defaults(func=cmd_generate)

    d = sub.add_parser("demo", help="generate a small 2D and 3D dataset and preview some programs")
    d.add_argument("--out", default="demo_output")
    d.add_argument("--scale", type=float, default=0.0002)
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--workers", type=int, default=2)
    d.add_argument("--per-length", type=int, default=2)
    d.add_argument("--quiet", action="store_true")
    d.set_defaults(func=cmd_demo)

    args = ap.parse_args(argv)
    if getattr(args, "dim", 0) is None:
        args.dim = 3 if any(h in args.program for h in ("sp(", "cu(", "cy(", "p(", "u(", "y(")) else 2
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
