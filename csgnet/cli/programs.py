"""``render``, ``generate`` and ``demo``: programs to files, synthetic datasets, a preview of them."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from shapeio import atomic_write
from shapeio.files import existing_outputs

from .. import export, render
from . import common
from ..lang import ParseError, parse
from ..primitives import primitives
from .common import located


def _write_render(program, dim: int, out: Path) -> Path:
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
        return atomic_write(out, lambda f: np.save(f, img, allow_pickle=False))
    raise SystemExit(f"error: unknown output type {suffix!r} for {out}; use .png, .obj, .npy or .scad")


def cmd_render(args) -> int:
    if args.dim is None:
        args.dim = 3 if any(h + "(" in args.program for p in primitives(3) for h in (p.kind, p.long) if h) else 2
    try:
        program = parse(args.program, args.dim)
    except ParseError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    problem = existing_outputs(args.output, args.overwrite)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    img = render(program, args.dim)[0]
    print(f"{program.text()}  ({len(program)} tokens, {int(img.sum())} {'pixels' if args.dim == 2 else 'voxels'} on)")
    for out in args.output:
        try:
            path = _write_render(program, args.dim, Path(out))
        except (OSError, ValueError) as e:
            print(f"error: {located(out, e)}", file=sys.stderr)
            return 2
        print(f"wrote {path}")
    return 0


def cmd_generate(args) -> int:
    from ..data import generate_dataset  # lazy: loaded when the command runs

    existing = Path(args.out) / f"{args.dim}d"
    if (existing / "meta.json").exists() or any(existing.glob("len_*")):
        raise SystemExit(f"error: {existing} holds a dataset already; generate never replaces one (a model may "
                         "have been trained on it): choose another --out or remove that folder")
    counts = generate_dataset(args.out, dim=args.dim, scale=args.scale, seed=args.seed, workers=args.workers,
                              lengths=args.lengths, progress=not args.quiet)
    print(json.dumps(counts, indent=1, sort_keys=True))
    return 0


def cmd_demo(args) -> int:
    """A small synthetic 2D and 3D dataset and previews of some of its programs (PNG, OBJ, OpenSCAD, a TSV)."""
    from ..data import generate_dataset, load_dataset  # lazy: loaded when the command runs

    out = Path(args.out)
    data_dir = out / "synthetic"
    earlier = [p for p in (data_dir / "2d", data_dir / "3d", out / "preview_2d", out / "preview_3d") if p.exists()]
    if earlier:  # a second demo into the folder would mix its previews and data with the first one's
        raise SystemExit(f"error: {earlier[0]} exists (an earlier demo's output); choose another --out or remove it")
    for dim in (2, 3):
        counts = generate_dataset(data_dir, dim=dim, scale=args.scale, seed=args.seed, workers=args.workers,
                                  progress=not args.quiet)
        total = sum(n for per_len in counts.values() for n in per_len.values())
        print(f"{dim}D: generated {total} programs under {data_dir / f'{dim}d'}")
        progs = load_dataset(data_dir, dim, "test")
        preview = out / f"preview_{dim}d"
        preview.mkdir(parents=True, exist_ok=True)
        lines, images = [], []
        for length, plist in sorted(progs.items()):
            for i, p in enumerate(plist[: args.per_length]):
                img = render(p, dim)[0]
                images.append(img)
                stem = preview / f"len{length:02d}_{i}"
                if dim == 2:
                    export.save_png(img, stem.with_suffix(".png"))
                else:
                    export.save_obj(img, stem.with_suffix(".obj"))
                export.save_scad(p, stem.with_suffix(".scad"))
                lines.append(f"{stem.name}\t{p.text()}\t{int(img.sum())}")
                print(f"  {stem.name}: {p.text()}")
        atomic_write(preview / "programs.tsv", "name\tprogram\ton\n" + "\n".join(lines) + "\n")
        if dim == 3:  # three orthographic silhouettes (along x, y, z) side by side
            images = [np.concatenate([v.any(axis=a) for a in range(3)], axis=1) for v in images]
        sheet_path = out / f"preview_{dim}d.png"
        export.save_sheet(export.contact_sheet(images, cols=6 if dim == 2 else 2), sheet_path)
        print(f"wrote {sheet_path} ({len(lines)} programs; texts in {preview / 'programs.tsv'})")
    print(f"done: {out}")
    return 0


def register(sub) -> None:
    """Add this module's subcommands to ``python -m csgnet``."""
    r = sub.add_parser("render", help="render one program to .png (2D), .obj (3D), .npy or .scad")
    r.add_argument("program", help='program text, e.g. "c(32,32,28)s(32,32,20)-"')
    r.add_argument("-o", "--out", "--output", dest="output", action="append", required=True,
                   help="output file, repeatable: .png (2D image), .obj (3D mesh), .npy (bool grid), .scad (OpenSCAD)")
    r.add_argument("--dim", type=int, choices=(2, 3), default=None, help="2 or 3 (default: guessed from the text)")
    r.set_defaults(func=cmd_render)

    g = sub.add_parser("generate", help="generate a synthetic dataset (train/val/test per length)")
    g.add_argument("--dim", type=int, choices=(2, 3), default=2, help="2D or 3D programs (default 2)")
    g.add_argument("--scale", type=common.scale, default=0.001, help="fraction of the paper's Table 2 split sizes")
    g.add_argument("--seed", type=common.seed, default=0, help="random seed; the files do not depend on --workers")
    g.add_argument("--workers", type=common.workers, default=1, help="worker processes (default 1)")
    g.add_argument("--lengths", type=common.length, nargs="*", default=None,
                   help="program lengths (default: all, 3..13 in 2D, 3..7 in 3D)")
    g.add_argument("--out", required=True, help="dataset folder (the DIMd/ sub-folder is written)")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    g.set_defaults(func=cmd_generate)

    d = sub.add_parser("demo", help="generate a small 2D and 3D dataset and preview some programs")
    d.add_argument("--out", default="demo_output", help="output folder (default demo_output/)")
    d.add_argument("--scale", type=common.scale, default=0.0002, help="fraction of the paper's Table 2 split sizes")
    d.add_argument("--seed", type=common.seed, default=0, help="random seed")
    d.add_argument("--workers", type=common.workers, default=2, help="worker processes (default 2)")
    d.add_argument("--per-length", type=common.per_length, default=2, help="previewed programs per length")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=cmd_demo)
