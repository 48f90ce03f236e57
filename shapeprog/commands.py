"""``python -m shapeprog assembly ...``: execute, fit, render and edit ShapeAssembly programs.

A program is named by a corpus id (``chair/173``, ``table/33075``, ``storage/46436``) or the path of a UTF-8
ShapeAssembly file (corpus format with ``Assembly`` blocks, or the flat format). The mesh format follows the
suffix: .obj (the reference layout), .ply or .glb (parts coloured by the program line that created them).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import torch

from shapeedit import port_argument
from shapeio.results import column

from . import corpus
from . import io
from .cli import (add_category, add_command, add_json, add_overwrite, add_quiet, add_seed, add_workers, check_outputs,
                  command_result, emit_text, float_in, int_at_least, macro_library, Program, refuse_existing,
                  refuse_inputs, worker_pool, write_json, write_mesh)
from .errors import ParseError
from .fit import MAX_DECIMALS, MAX_LR, MAX_REG, fit
from .fit import MAX_STEPS as MAX_FIT_STEPS
from .metrics import adaptive_threshold, chamfer, fscore
from .picture import MAX_SIZE as MAX_PICTURE_SIZE
from .picture import render_png
from .sampling import sample_surface
from .silhouettes import MAX_SIZE as SILHOUETTE_MAX_SIZE
from .silhouettes import build, write
from . import volumes

PROGRAM_HELP = "corpus id (chair/173, table/33075, storage/46436) or a UTF-8 program file (corpus or flat format)"


def cmd_run(args) -> int:
    """execute a program and export its cuboids

    Execute a program; print its block and cuboid counts; export a mesh and a picture.

    Example: assembly run chair/173 -o chair.obj --png chair.png"""
    check_outputs([args.out], [args.png])
    prog = Program(args.program)
    refuse_inputs([args.out, args.png], [args.program])
    refuse_existing([args.out, args.png], args.overwrite)
    with torch.no_grad():
        shape = prog.execute(dtype=torch.float64 if args.float64 else torch.float32)
    print(f"{prog.name}: {len(prog.program.blocks)} blocks, {len(shape)} leaf cuboids")
    if args.out:
        write_mesh(args.out, shape)
        print(f"wrote {args.out}")
    if args.png:
        render_png(shape.corners, args.png, labels=shape.line.numpy(), size=args.size)
        print(f"wrote {args.png}")
    return 0


def cmd_fit(args) -> int:
    """fit a program's parameters to a point cloud

    Fit a program's continuous numbers to a point cloud; print chamfer and F-score before and after; write the fitted
    program.

    Example: assembly fit table/33075 --points example --steps 400 -o fitted.txt"""
    check_outputs([args.mesh], [args.out, args.json])
    prog = Program(args.program)
    refuse_inputs([args.out, args.mesh, args.json], [args.program, None if args.points == "example" else args.points])
    refuse_existing([args.out, args.mesh, args.json], args.overwrite)
    if args.points == "example":
        pts = torch.as_tensor(corpus.example_points())
    else:
        try:
            pts = io.read_points(args.points)  # (N, 3) float32
        except ValueError as e:  # the message names the file (and line)
            print(f"error: {e}", file=sys.stderr)
            return 1
        from shapeio.points import MIN_POINTS  # lazy: loaded when the command runs

        if len(pts) < MIN_POINTS:
            print(f"error: {args.points}: {len(pts)} points; fitting needs at least {MIN_POINTS}", file=sys.stderr)
            return 1
    g = torch.Generator().manual_seed(args.seed)
    thr = float(adaptive_threshold(pts))  # the target's F-score threshold, the same before and after

    def score(p):
        with torch.no_grad():
            shape = prog.execute(p)
            x, _ = sample_surface(shape.corners, 10000, generator=torch.Generator().manual_seed(args.seed))
            return float(chamfer(x, pts)), fscore(x, pts, threshold=thr)

    cd0, f0 = score(prog.program)
    res = fit(prog.program, pts, steps=args.steps, lr=args.lr, reg=args.reg, decimals=args.decimals, generator=g)
    cd1, f1 = score(res.program)
    print(f"{prog.name}: chamfer {cd0:.4f} -> {cd1:.4f}, F-score @{thr:.3g} {f0:.1f} -> {f1:.1f}, "
          f"{len(res.losses)} of {args.steps} steps in {res.seconds:.1f} s")
    if res.stopped is not None:
        print(f"{prog.name}: {res.stopped}")
    emit_text(args.out, res.text)
    if args.mesh:
        with torch.no_grad():
            write_mesh(args.mesh, prog.execute(res.program))
    write_json(args, command_result(
        args, f"fit of {prog.name} to {args.points}",
        [column("stage", "stage"), column("chamfer", "chamfer", 4), column("fscore", f"F-score @{thr:.3g}", 1)],
        [{"stage": "before", "chamfer": cd0, "fscore": float(f0)},
         {"stage": "after", "chamfer": cd1, "fscore": float(f1)}],
        [f"{len(res.losses)} of {args.steps} steps in {res.seconds:.1f} s"]
        + ([res.stopped] if res.stopped is not None else [])))
    return 0


def cmd_silhouettes(args) -> int:
    """render front and side silhouettes of the corpus to an .npz

    Render front and side silhouettes of every corpus program (train and val).

    Example: assembly silhouettes --out silhouettes.npz"""
    check_outputs(others=[args.out])
    refuse_existing([args.out], args.overwrite)
    t0 = time.perf_counter()
    try:
        data = build(size=args.size, margin=args.margin, limit=args.limit, progress=not args.quiet)
    except ValueError as e:  # --size / --margin, checked before any program runs
        raise SystemExit(f"error: {e}") from None
    write(args.out, data, margin=args.margin)
    counts = ", ".join(f"{split} {len(s.images)}" for split, s in data.items())
    print(f"wrote {args.out}: {counts} images in {time.perf_counter() - t0:.1f} s")
    return 0


def cmd_volumes(args) -> int:
    """voxelise the corpus's chairs and tables to 64³ volumes in an .npz

    Execute the corpus programs of the categories (train, val and test splits) and voxelise each shape to a
    64³ occupancy volume: the 3D target set of CSGNet's self-training (docs/csgnet.md, "The ShapeAssembly
    volumes").

    Example: assembly volumes --out data/assembly_volumes.npz --workers 2"""
    refuse_existing([args.out], args.overwrite)
    t0 = time.perf_counter()
    try:
        with worker_pool(args.workers) as pool:
            data = volumes.build(args.category, args.size, args.margin, args.limit, pool, progress=not args.quiet)
    except ValueError as e:  # --size / --margin, checked before any program runs
        raise SystemExit(f"error: {e}") from None
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    volumes.write(args.out, data, margin=args.margin)
    counts = ", ".join(f"{split} {len(s)}" for split, s in data.items())
    print(f"wrote {args.out}: {counts} volumes in {time.perf_counter() - t0:.1f} s")
    return 0


def open_for_edit(args):
    """The edit session of ``edit``'s arguments: (session, the text as read, its file name)."""
    # the editor's session code is imported when a page is served, not for --help
    from .editor.session import EditSession, is_corpus_text, read_source, refactor_source  # lazy: loaded when the command runs

    library = None
    if args.library:
        library = macro_library(args.library, "--library: ")
    if args.sample:
        # the VAE's model code loads torch modules only this option needs
        from .vae import load_pretrained, sample  # lazy: loaded when the command runs

        if args.program:
            raise SystemExit("error: give a PROGRAM or --sample, not both")
        text = sample(load_pretrained(args.category), 1, seed=args.seed)[0].text
        file = f"{args.category}_sample_seed{args.seed}.txt"
    elif args.program:
        try:
            text, file = read_source(args.program)
        except (FileNotFoundError, KeyError) as e:
            raise SystemExit(f"error: {e.args[0]}") from None
    else:
        raise SystemExit("error: give a PROGRAM (corpus id or file) or --sample")
    if library is not None and is_corpus_text(text):  # a ShapeAssembly program: edit its refactored form
        cat, _, ident = file.partition("/")
        named = cat in corpus.CATEGORIES and ident.removesuffix(".txt").isdigit()
        try:
            text = refactor_source(text, file, library, cat if named else Path(file).stem,
                                   int(ident.removesuffix(".txt")) if named else 0)
        except (ParseError, ValueError) as e:
            raise SystemExit(f"error: cannot refactor {file} with the library: {e}") from None
        file = str(Path(file).with_suffix("")) + "_macros.txt"
        print(f"refactored {args.program} with the library: {text.count(chr(10) + '# ') + 1} sub-program(s)")
    session = EditSession(text, file, library=library)
    if session.error is not None:
        print(f"error: {session.error} (the page shows it; fix the text there)", file=sys.stderr)
    if args.target:
        try:
            ttext, tfile = read_source(args.target)
        except (FileNotFoundError, KeyError) as e:
            raise SystemExit(f"error: --target: {e.args[0]}") from None
        session.set_target(ttext, tfile)
    return session, text, file


def cmd_edit(args) -> int:
    """edit a program in the browser (needs the 'editor' extra: viser)

    Serve an editor page for a program: the shape in 3D, one control per free parameter, live re-execution, undo / redo
    / reset, export of text, OBJ and PNG. Runs until interrupted. See docs/editor.md.

    Example: assembly edit chair/173 --port 8080 --no-browser --target chair/37982"""
    from shapeedit import editor_preflight, serve_until_interrupted  # lazy: loaded when the command runs

    problem = editor_preflight(args.export_dir)
    if problem:
        raise SystemExit(f"error: {problem}")  # exit status 1, as the argument errors of open_for_edit
    session, text, file = open_for_edit(args)
    # the server needs the optional 'editor' extra (viser), checked by editor_preflight above
    from .editor.server import EditorApp  # lazy: loaded when the command runs

    app = EditorApp(session, host=args.host, port=args.port, export_dir=args.export_dir, source_text=text)
    return serve_until_interrupted(app, file, args.export_dir, not args.no_browser)


def register(sub) -> None:
    """Add the ``assembly`` commands to ``sub``."""
    r = add_command(sub, "run", cmd_run, outputs={"out": "file"})
    r.add_argument("program", help=PROGRAM_HELP)
    r.add_argument("-o", "--out", help="mesh file: .obj (reference layout), .ply or .glb (parts coloured by line)")
    r.add_argument("--png", help="picture file (.png), parts coloured by the program line that created them")
    r.add_argument("--size", type=int_at_least(8, MAX_PICTURE_SIZE), default=512,
                   help=f"picture width and height in pixels (8 to {MAX_PICTURE_SIZE})")
    r.add_argument("--float64", action="store_true", help="execute in float64 (float32 is the reference)")
    add_overwrite(r)
    f = add_command(sub, "fit", cmd_fit, outputs={"out": "file", "json": "file"})
    f.add_argument("program", help=PROGRAM_HELP)
    f.add_argument("--points", default="example",
                   help="point cloud file (.obj 'v x y z' lines, .ply, .xyz or .npy) or 'example' (the vendored "
                        "comp_pc.obj)")
    f.add_argument("--steps", type=int_at_least(0, MAX_FIT_STEPS), default=400, help="optimisation steps")
    f.add_argument("--lr", type=float_in(0, MAX_LR, low_open=True), default=1e-3,
                   help=f"Adam learning rate (above 0, at most {MAX_LR:g})")
    f.add_argument("--reg", type=float_in(0, MAX_REG), default=1e-3,
                   help="weight of the pull towards the starting numbers")
    f.add_argument("--decimals", type=int_at_least(0, MAX_DECIMALS), default=3,
                   help="decimals of the written numbers (the corpus uses 3)")
    add_seed(f, "seed of the surface sampling")
    f.add_argument("-o", "--out", help="fitted program file (ShapeAssembly text; without it: printed)")
    f.add_argument("--mesh", help="also write the fitted shape: .obj, .ply or .glb")
    add_json(f, "the chamfer distance and F-score before and after")
    add_overwrite(f)
    s = add_command(sub, "silhouettes", cmd_silhouettes, outputs={"out": "file"})
    s.add_argument("--out", required=True, help="output file (.npz, compressed NumPy arrays)")
    s.add_argument("--size", type=int_at_least(1, SILHOUETTE_MAX_SIZE), default=64,
                   help=f"image side in pixels (1 to {SILHOUETTE_MAX_SIZE})")
    s.add_argument("--margin", type=int_at_least(0, SILHOUETTE_MAX_SIZE), default=4,
                   help="free pixels on each side of the longer extent")
    s.add_argument("--limit", type=int_at_least(1), help="only the first N shapes per category and split")
    add_quiet(s, "progress bar")
    add_overwrite(s)
    v = add_command(sub, "volumes", cmd_volumes, outputs={"out": "file+"})
    v.add_argument("--out", required=True, help="output file (.npz, compressed NumPy arrays)")
    v.add_argument("--category", nargs="+", choices=corpus.CATEGORIES, default=list(volumes.CATEGORIES),
                   metavar="CATEGORY", help=f"corpus categories: one or more of {', '.join(corpus.CATEGORIES)}")
    v.add_argument("--size", type=int_at_least(1, volumes.MAX_SIZE), default=64,
                   help=f"volume side in voxels (1 to {volumes.MAX_SIZE})")
    v.add_argument("--margin", type=int_at_least(0, volumes.MAX_SIZE), default=4,
                   help="free voxels on each side of the longest extent")
    v.add_argument("--limit", type=int_at_least(1), help="only the first N shapes per category and split")
    add_workers(v, "processes voxelising the shapes (1: none)")
    add_quiet(v, "progress bar")
    add_overwrite(v)
    d = add_command(sub, "edit", cmd_edit)
    d.add_argument("program", nargs="?", help=PROGRAM_HELP + ", or a macro program file (lines 'def ...')")
    d.add_argument("--sample", action="store_true",
                   help="edit a program generated by the shipped VAE of --category instead")
    add_category(d, help="with --sample: the shipped VAE's category")
    add_seed(d, "seed of --sample")
    d.add_argument("--library", help="a shipped ShapeMOD library's category (chair) or a macro library file: a "
                                     "ShapeAssembly program (corpus id or corpus-format file) is refactored with it "
                                     "and its macro calls' parameters are edited; a macro program calls it")
    d.add_argument("--target", help="goal-directed mode: a program (corpus id or file) shown as a wireframe, "
                                    "with the live corner distance to it")
    d.add_argument("--port", type=port_argument, default=8080, help="port of the page (0: a free one)")
    d.add_argument("--host", default="127.0.0.1", help="address to bind (127.0.0.1: this machine only)")
    d.add_argument("--export-dir", default=".", help="the folder exports are written to (never elsewhere)")
    d.add_argument("--no-browser", action="store_true", help="do not open a browser")
