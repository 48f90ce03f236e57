"""Command line: execute, fit, generate, interpolate and reconstruct ShapeAssembly programs.

    python -m shapeprog run chair/173 -o chair.obj --png chair.png
    python -m shapeprog run my_program.txt -o shape.ply
    python -m shapeprog fit table/33075 --points cloud.obj --steps 400 -o fitted.txt
    python -m shapeprog silhouettes --out silhouettes.npz
    python -m shapeprog infer scan.ply --category chair --fit --out result/
    python -m shapeprog make-clouds --category chair --points 10000 --workers 2 --out clouds
    python -m shapeprog sample chair -n 16 --seed 0 --out samples --png grid.png
    python -m shapeprog interpolate chair/173 chair/44017 --steps 8 --png interp.png
    python -m shapeprog reconstruct chair/173 -o recon.txt
    python -m shapeprog export-weights runs/vae_chair/checkpoints/last.ckpt --out vae_chair.pt
    python -m shapeprog evaluate-generation --category chair -n 1000 --out table.md
    python -m shapeprog evaluate-generation --category chair --programs samples/ --out table.md
    python -m shapeprog train-classifier --out shapeprog/weights/pointnet_cls.pt
    python -m shapeprog edit chair/173 --port 8080 --no-browser --target chair/37982
    python -m shapeprog discover-macros --category chair --rounds 5 --workers 2 --out runs/shapemod_chair
    python -m shapeprog refactor chair/173 --library chair
    python -m shapeprog refactor-corpus --category chair --library chair --workers 2 --out chair_macros
    python -m shapeprog table1 --categories chair --limit 200 --out table1.md
    python -m shapeprog table2-coder --categories chair table storage --workers 2 --out shapecoder_tables.md

A program is named by a corpus id (``chair/173``, ``table/33075``, ``storage/46436``) or the
path of a UTF-8 ShapeAssembly file (corpus format with ``Assembly`` blocks, or the flat format).
The mesh format follows the suffix: .obj (the reference layout), .ply or .glb (parts coloured by
the program line that created them). Errors name the file, line and column; exit status 2 for a
program that does not parse or execute, 1 for a file that cannot be read or written.
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import torch

from shapeio import InputError, atomic_write, refuse_overwrite, write_new
from shapeio.editing import port_argument
from shapeio.files import output_problem, write_new_set
from shapeio.options import float_in, int_in
from shapeio.mesh import WRITE_SUFFIXES
from shapeio.points import MAX_POINTS

from . import corpus, io
from .errors import ExecutionError, ParseError, RefactorError
from .execute import execute
from .fit import MAX_DECIMALS, MAX_LR, MAX_REG, fit
from .fit import MAX_STEPS as MAX_FIT_STEPS
from .vae.gentable import generation_table, train_category_classifier
from .lang import parse
from .limits import decode
from .metrics import adaptive_threshold, chamfer, fscore
from .picture import MAX_SIZE as MAX_PICTURE_SIZE
from .picture import render_grid, render_png
from .vae.pointnet import save_classifier, sha256_file
from .sampling import sample_surface
from .silhouettes import MAX_SIZE as SILHOUETTE_MAX_SIZE
from .silhouettes import build, write
from .vae.decode import MAX_SAMPLES, MAX_TRIES




class _Program:
    """A loaded program, the name printed for it and the file name its errors carry."""

    def __init__(self, spec: str):
        path = Path(spec)
        cat, _, ident = spec.partition("/")
        if path.is_file():
            self.name = self.file = str(path)
            text = decode(path.read_bytes(), self.file)
        elif cat in corpus.CATEGORIES and ident.isascii() and ident.isdigit():
            self.name, self.file = spec, f"{cat}/{int(ident)}.txt"
            try:
                text = corpus.read(cat, int(ident))
            except KeyError:
                raise SystemExit(f"error: no program {cat}/{int(ident)} in the corpus") from None
        else:
            raise SystemExit(f"error: {spec!r} is neither a file nor a corpus id like 'chair/173'")
        self.program = parse(text, file=self.file)

    def execute(self, program=None, **kwargs):
        """Execute this program (or ``program``, e.g. a fitted version); errors carry the file name."""
        try:
            return execute(self.program if program is None else program, **kwargs)
        except ExecutionError as e:
            raise ExecutionError(e.reason, e.line, file=self.file) from None


def _check_outputs(meshes=(), others=()) -> None:
    """Stop before any work when an output's folder is missing or a mesh suffix is unknown."""
    for path in [p for p in (*meshes, *others) if p]:
        folder = Path(path).parent
        if not folder.is_dir():
            raise SystemExit(f"error: {path}: folder {str(folder)!r} does not exist")
    for path in [p for p in meshes if p]:
        if Path(path).suffix.lower() not in WRITE_SUFFIXES:
            raise SystemExit(f"error: {path}: unknown mesh format {Path(path).suffix!r} "
                             f"(use {', '.join(WRITE_SUFFIXES)})")


def _refuse_overwrite(outputs, inputs) -> None:
    """Stop before writing an output over an input file (a corpus id is no file: never matches)."""
    try:
        refuse_overwrite(outputs, [p for p in inputs if p is not None and Path(p).is_file()])
    except FileExistsError as e:
        raise SystemExit(f"error: {e}") from None


def _write_mesh(path: str, shape) -> None:
    suffix = Path(path).suffix.lower()
    if suffix == ".obj":
        io.write_obj(path, shape.corners, lines=shape.line)
    elif suffix == ".ply":
        io.write_ply(path, shape.corners, labels=shape.line.numpy())
    else:
        io.write_glb(path, shape.corners, labels=shape.line.numpy())


def _emit_text(path: str | None, text: str) -> None:
    """Write a program to ``path`` (atomically) or, without one, print it."""
    if path:
        atomic_write(path, text)
        print(f"wrote {path}")
    else:
        sys.stdout.write(text)


def _png(path: str, shape, size: int) -> None:
    render_png(shape.corners, path, labels=shape.line.numpy(), size=size)


def _cmd_run(args) -> int:
    _check_outputs([args.output], [args.png])
    prog = _Program(args.program)
    _refuse_overwrite([args.output, args.png], [args.program])
    with torch.no_grad():
        shape = prog.execute(dtype=torch.float64 if args.float64 else torch.float32)
    print(f"{prog.name}: {len(prog.program.blocks)} blocks, {len(shape)} leaf cuboids")
    if args.output:
        _write_mesh(args.output, shape)
        print(f"wrote {args.output}")
    if args.png:
        _png(args.png, shape, args.size)
        print(f"wrote {args.png}")
    return 0


def _cmd_fit(args) -> int:
    _check_outputs([args.mesh], [args.output])
    prog = _Program(args.program)
    _refuse_overwrite([args.output, args.mesh], [args.program, None if args.points == "example" else args.points])
    if args.points == "example":
        pts = torch.as_tensor(corpus.example_points())
    else:
        try:
            pts = io.read_points(args.points)  # (N, 3) float32
        except ValueError as e:  # the message names the file (and line)
            print(f"error: {e}", file=sys.stderr)
            return 1
        from shapeio.points import MIN_POINTS

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
    _emit_text(args.output, res.text)
    if args.mesh:
        with torch.no_grad():
            _write_mesh(args.mesh, prog.execute(res.program))
    return 0


def _cmd_silhouettes(args) -> int:
    _check_outputs(others=[args.out])
    t0 = time.perf_counter()
    try:
        data = build(size=args.size, margin=args.margin, limit=args.limit, progress=not args.quiet)
    except ValueError as e:  # --size / --margin, checked before any program runs
        raise SystemExit(f"error: {e}") from None
    write(args.out, data, margin=args.margin)
    counts = ", ".join(f"{split} {len(s.images)}" for split, s in data.items())
    print(f"wrote {args.out}: {counts} images in {time.perf_counter() - t0:.1f} s")
    return 0


def _fmt_metrics(m: dict) -> str:
    cd = "n/a" if m["cd"] is None else f"{1000 * m['cd']:.1f}"
    yes = {True: "yes", False: "no", None: "not run"}
    from .pointcloud.infer import FSCORE_THRESHOLD

    return (f"CD x1000 {cd}, F-score @{FSCORE_THRESHOLD:g} {m['fscore']:.1f}, rooted {yes[m['rooted']]}, "
            f"stable {yes[m['stable']]}")


def _retrieval_index(category: str, clouds):
    """The retrieval index of ``category``'s training shapes: from a make-clouds folder, or sampled from the
    corpus (with a progress line on stderr)."""
    from .pointcloud.retrieval import RetrievalIndex

    t0 = time.perf_counter()
    if clouds:
        try:
            index = RetrievalIndex.from_cache(clouds, category)
        except (OSError, ValueError, KeyError) as e:
            raise SystemExit(f"error: {clouds}: {e}") from None
    else:
        from tqdm import tqdm

        bar = None

        def progress(done, total):  # only called when the index is not in the cache yet
            nonlocal bar
            if bar is None:
                bar = tqdm(total=total, desc=f"{category} retrieval index (cached after this run)", unit="shape",
                           file=sys.stderr)
            bar.update(done - bar.n)

        index = RetrievalIndex.from_corpus(category, progress=progress)
        if bar is not None:
            bar.close()
    print(f"retrieval index: {len(index)} {category} training shapes ({time.perf_counter() - t0:.0f} s)",
          file=sys.stderr, flush=True)
    return index


def _cmd_infer(args) -> int:
    import json

    import numpy as np

    from shapeio.points import read_cloud
    from .errors import PointCloudError
    from .picture import render_grid
    from .pointcloud.infer import RETRIEVAL_CANDIDATES, cloud_corners, infer, load_model
    from .pointcloud.search import parse_schedule

    src = Path(args.file)
    out = Path(args.out)
    stem = src.stem
    try:
        model = load_model(args.weights, args.category) if args.weights else None
    except (FileNotFoundError, ValueError) as e:  # the message names the weights file
        raise SystemExit(f"error: {e}") from None
    kinds = [("program", ".txt"), ("mesh", ".obj"), ("png", ".png"), ("json", ".json")]
    if model is not None and model.layout is not None:
        kinds.append(("macros", "_macros.txt"))  # the decoded macro program (ShapeMOD)
    files = {k: out / f"{stem}{suffix}" for k, suffix in kinds}
    _refuse_overwrite(list(files.values()), [args.file])
    _refuse_existing(files.values())
    points = read_cloud(src)
    index = None
    if args.retrieval is not None:
        index = _retrieval_index(args.category if model is None else model.category, args.clouds)
    elif args.clouds:
        raise SystemExit("error: --clouds is only used with --retrieval")
    try:
        schedule = parse_schedule(args.search_schedule) if args.search_schedule else None
        r = infer(points, args.category, fit=args.fit, model=model, up=args.up, fit_steps=args.steps,
                  stability=not args.no_stability, seed=args.seed, search=args.search or schedule is not None,
                  search_schedule=schedule, retrieval=index,
                  retrieval_candidates=args.retrieval or RETRIEVAL_CANDIDATES)
    except PointCloudError as e:
        raise SystemExit(f"error: {src}: {e}") from None
    except ValueError as e:
        raise SystemExit(f"error: {src}: {e}") from None
    out.mkdir(parents=True, exist_ok=True)
    write_new_set(_inference_files(r, points, src, model, files, args))  # all or none: no half result is left
    return _print_inference(r, files)


def _inference_files(r, points, src, model, files, args) -> list[tuple[Path, str | bytes]]:
    """``(path, content)`` of each file of ``infer``, in writing order."""
    import json

    import numpy as np

    from shapeio.image import png_bytes

    from .io import obj_text
    from .picture import render_grid
    from .pointcloud.infer import cloud_corners

    out = [(files["program"], r.text)]
    if "macros" in files and r.macro_text is not None:
        out.append((files["macros"], r.macro_text))
    with torch.no_grad():
        part_lines = execute(r.program).line
    out.append((files["mesh"], obj_text(torch.from_numpy(r.corners()), lines=part_lines)))
    unit = r.transform.apply(points)
    canon = execute(r.canonical).corners + torch.from_numpy(r.canonical_offset).float()
    sheet = render_grid([cloud_corners(unit[np.random.default_rng(args.seed).permutation(len(unit))]), canon],
                        cols=2, size=args.size)
    out.append((files["png"], png_bytes(sheet, where=files["png"])))
    record = {"input": str(src), "category": args.category if model is None else model.category,
              "fit": bool(args.fit), "points": int(len(points)), "unit": r.unit, "offset": r.offset.tolist(),
              "rotation": r.rotation.tolist(), "transform": r.transform.to_dict(), "metrics": r.metrics,
              "before_fit": r.before, "fit_stopped": r.fit_stopped, "search": r.search, "retrieval": r.retrieval,
              "seconds": r.seconds,
              "macro_text": r.macro_text,
              "note": "the program's executed points p lie on the input at (p * unit) @ rotation + offset; metrics "
                      "are in canonical units (bounding-box diagonal 2)"}
    out.append((files["json"], json.dumps(record, indent=1) + "\n"))
    return out


def _print_inference(r, files) -> int:
    import numpy as np

    if r.search is not None:
        s = r.search
        start = "none" if s["start_cd"] is None else f"{1000 * s['start_cd']:.1f}"
        print(f"latent search: {s['decodes']} decodes, chamfer to the cloud x1000 {start} -> {1000 * s['cd']:.1f}")
    if r.retrieval is not None:
        v = r.retrieval
        dec = "no shape" if v["decoded_cd"] is None else f"{1000 * v['decoded_cd']:.1f}"
        kept = f"the training program {v['chosen']}" if v["chosen"] else "the decoded program"
        print(f"retrieval: {v['candidates']} training programs against the decoded one (chamfer to the cloud x1000 "
              f"{dec}); kept {kept} ({1000 * v['cd']:.1f})")
    if r.before is not None:
        print(f"before fitting: {_fmt_metrics(r.before)}")
    if r.fit_stopped is not None:
        print(f"fitting: {r.fit_stopped}")
    print(("after fitting:  " if r.before is not None else "") + _fmt_metrics(r.metrics))
    print(f"wrote {files['program']}, {files['mesh']}, {files['png']} and {files['json']} "
          f"(offset {np.round(r.offset, 4).tolist()}" + ("" if r.unit == 1 else f", unit {r.unit:g}") + ")")
    if "macros" in files and r.macro_text is not None:
        print(f"wrote {files['macros']}: the decoded macro program (library calls; in the decoder's frame, before "
              f"alignment and fitting; {files['program']} is its expansion in the input's frame)")
    return 0


def _cmd_pointcloud_tables(args) -> int:
    from .pointcloud.tables import evaluate, write_tables

    _refuse_overwrite([args.out], [args.weights])
    executor = None
    if args.workers > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        executor = ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn"))

    def progress(done, total):
        if not args.quiet and (done % 10 == 0 or done == total):
            print(f"{done}/{total} shapes", file=sys.stderr, flush=True)

    try:
        result = evaluate(args.clouds, args.category, weights=args.weights, limit=args.limit, steps=args.steps,
                          stability=not args.no_stability, retrieval=not args.no_retrieval, executor=executor,
                          seed=args.seed, progress=progress, search=args.search, augmented=args.augmented)
    finally:
        if executor is not None:
            executor.shutdown()
    command = "python -m shapeprog " + " ".join(sys.argv[1:] if args.argv is None else args.argv)
    write_tables(result, args.out, command)
    for row, m in result.rows.items():
        print(f"{row}: {m}")
    print(f"wrote {args.out}")
    return 0


def _cmd_make_clouds(args) -> int:
    from tqdm import tqdm

    from .pointcloud.data import make_clouds

    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise SystemExit(f"error: {args.out}: not a folder")
    from .pointcloud.data import cache_paths
    _refuse_existing(cache_paths(args.out, args.category))  # an expensive cache is never replaced
    ids = None
    if args.limit:
        ids = corpus.ids(args.category, "train")[:args.limit] + corpus.ids(args.category, "val")[:args.limit]
    bar = tqdm(total=len(ids) if ids is not None else len(corpus.ids(args.category, "all")), unit="shape",
               desc=f"{args.category} clouds", disable=args.quiet)
    try:
        rep = make_clouds(args.category, args.out, n_points=args.points, seed=args.seed, workers=args.workers,
                          val_fraction=args.val_fraction, split_seed=args.split_seed, dtype=args.dtype, ids=ids,
                          progress=lambda done, total: bar.update(1))
    except ValueError as e:  # --points, --val-fraction: checked before any work
        raise SystemExit(f"error: {e}") from None
    finally:
        bar.close()
    for shape_id, reason in rep.failures:
        print(f"warning: {args.category}/{shape_id} skipped: {reason}", file=sys.stderr)
    print(f"wrote {rep.cache} ({rep.count} clouds of {args.points} points, {rep.bytes / 2**20:.1f} MiB, "
          f"{len(rep.failures)} failed) and {rep.split} in {rep.seconds:.1f} s")
    return 0


def _load_vae(args, category: str | None, macro: bool = False):
    """The VAE of ``--weights`` or the shipped model of ``category``; a usage error when neither is known, or
    when ``--weights`` is a model of macro programs and the command (``macro`` False) reads ShapeAssembly
    programs."""
    from .vae.macro_model import MacroVAE
    from .vae.pretrained import load_model, load_pretrained

    try:
        if args.weights:
            vae = load_model(args.weights, category=args.category)
            if args.category is None and category is not None and vae.category != category:
                raise SystemExit(f"error: {args.weights}: a {vae.category} model, but the input is a {category} "
                                 f"program (give --category {vae.category} to use this model anyway)")
            if isinstance(vae, MacroVAE) and not macro:
                raise SystemExit(f"error: {args.weights} is a VAE over macro programs (ShapeMOD); this command reads "
                                 f"ShapeAssembly programs: use `sample` or `evaluate-generation` with it")
            return vae
        if category is None:
            raise SystemExit("error: name the model's category with --category (or give --weights)")
        return load_pretrained(category)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"error: {e}") from None


def _planned_files(out: str | None, name: str, n: int) -> list[Path]:
    """The ``.txt`` and ``.obj`` files :func:`_export_decoded` writes into ``out`` for ``n`` programs."""
    return [] if not out else [Path(out) / f"{name.format(i)}{s}" for i in range(n) for s in (".txt", ".obj")]


def _check_grid(count: int, cols: int, size: int) -> None:
    """Stop before any work when a picture grid would exceed :data:`shapeprog.picture.MAX_GRID_PIXELS`."""
    from .picture import check_grid

    try:
        check_grid(count, cols, size)
    except ValueError as e:
        raise SystemExit(f"error: --png: {e}") from None


def _refuse_existing(paths) -> None:
    """Stop before writing when one of ``paths`` exists: a second run into the same folder would leave a mix
    of both runs' files that looks like one."""
    taken = [p for p in paths if Path(p).exists()]
    if taken:
        raise SystemExit(f"error: {taken[0]}: exists ({len(taken)} of the outputs do); the command never "
                         "overwrites a file: choose another --out or remove them")


def _export_decoded(results, out: str | None, name: str, png: str | None, cols: int, size: int,
                    progress: bool = False) -> None:
    """Write decoded programs: ``name.format(i)`` + ``.txt`` and ``.obj`` in ``out`` (none of which may exist
    yet: the commands check :func:`_planned_files` with :func:`_refuse_existing` before their work, and the text
    files are written with ``write_new``), a picture grid ``png`` (``cols`` cells of ``size`` pixels per row);
    print the programs when neither is given. Each program is executed once."""
    from tqdm import tqdm

    if not out and not png:
        for i, r in enumerate(results):
            print(f"# {name.split('_')[0]} {i}\n{r.text}")
        return
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
    shapes = []
    for i, r in enumerate(tqdm(results, desc="writing", unit="shape", disable=not progress)):
        with torch.no_grad():
            shape = execute(r.program)
        if out:
            write_new(Path(out) / f"{name.format(i)}.txt", r.text)
            io.write_obj(Path(out) / f"{name.format(i)}.obj", shape.corners, lines=shape.line)
        shapes.append((shape.corners, shape.line.numpy()))
    if out:
        print(f"wrote {len(results)} programs and meshes to {out}/")
    if png:
        render_grid(shapes, png, cols=cols, size=size)
        print(f"wrote {png}")


def _sampling_report(results, max_tries: int, seconds: float) -> str:
    """How often :func:`shapeprog.vae.sample` was refused: first-draw and within-``max_tries`` shares, the
    refused share of all draws, and the rate."""
    n = len(results)
    draws = sum(min(r.tries, max_tries) for r in results)
    first = sum(r.tries == 1 for r in results)
    within = sum(r.tries <= max_tries for r in results)
    return (f"{100 * first / n:.1f} % valid on the first draw, {100 * within / n:.1f} % within {max_tries} draws, "
            f"{100 * (1 - within / max(draws, 1)):.1f} % of {draws} draws refused; sampling took {seconds:.1f} s "
            f"({n / seconds:.1f} samples/s)")


def _cmd_sample(args) -> int:
    from .vae import sample

    from .vae.macro_model import MacroVAE

    _check_outputs(others=[args.png])
    if args.png:
        _check_grid(args.n, args.cols, args.size)
    _refuse_existing(_planned_files(args.out, "sample_{:04d}", args.n))
    vae = _load_vae(args, args.category, macro=True)
    t0 = time.perf_counter()
    if isinstance(vae, MacroVAE):  # macro programs: written as macro text, executed through their expansion
        from .vae.macro_decode import sample_macro
        results = sample_macro(vae, args.n, seed=args.seed, max_tries=args.max_tries)
    else:
        results = sample(vae, args.n, seed=args.seed, max_tries=args.max_tries)
    seconds = time.perf_counter() - t0
    first = sum(r.tries == 1 for r in results)
    within = sum(r.tries <= args.max_tries for r in results)
    print(f"{args.n} samples of {vae.category} in {seconds:.1f} s ({args.n / seconds:.1f}/s): "
          f"{first} valid on the first try, {within} within {args.max_tries} tries")
    _export_decoded(results, args.out, "sample_{:04d}", args.png, args.cols, args.size, progress=not args.quiet)
    return 0


def _category_of(spec: str) -> str | None:
    cat = spec.partition("/")[0]
    return cat if cat in corpus.CATEGORIES and not Path(spec).is_file() else None


def _cmd_interpolate(args) -> int:
    from .vae import interpolate

    _check_outputs(others=[args.png])
    a, b = _Program(args.a), _Program(args.b)
    planned = _planned_files(args.out, "step_{:03d}", args.steps)
    _refuse_overwrite([args.png, *planned], [args.a, args.b])
    _refuse_existing(planned)
    vae = _load_vae(args, args.category or _category_of(args.a) or _category_of(args.b))
    results = interpolate(vae, a.program, b.program, args.steps)
    _export_decoded(results, args.out, "step_{:03d}", args.png, len(results), args.size)
    return 0


def _cmd_reconstruct(args) -> int:
    from .vae import decode, encode

    _check_outputs([args.mesh], [args.output, args.png])
    prog = _Program(args.program)
    _refuse_overwrite([args.output, args.mesh, args.png], [args.program])
    vae = _load_vae(args, args.category or _category_of(args.program))
    result = decode(vae, encode(vae, prog.program))
    with torch.no_grad():
        target, shape = prog.execute(), execute(result.program)
        if len(shape) == 0:  # nothing to sample: no point of the input is recovered
            y, _ = sample_surface(target.corners, 10000, generator=torch.Generator().manual_seed(args.seed))
            thr = float(adaptive_threshold(y))
            score = f"F-score @{thr:.3g} 0.0 (no leaf cuboid decoded)"
        else:
            g = torch.Generator().manual_seed(args.seed)
            x, _ = sample_surface(shape.corners, 10000, generator=g)
            y, _ = sample_surface(target.corners, 10000, generator=g)
            thr = float(adaptive_threshold(y))  # fscore's default threshold, printed with the score
            score = f"F-score @{thr:.3g} {fscore(x, y, threshold=thr):.1f}, chamfer {float(chamfer(x, y)):.4f}"
    print(f"{prog.name}: reconstructed with {len(shape)} leaf cuboids (input {len(target)}), {score}")
    _emit_text(args.output, result.text)
    if args.mesh:
        _write_mesh(args.mesh, shape)
    if args.png:
        render_grid([(target.corners, target.line.numpy()), (shape.corners, shape.line.numpy())], args.png,
                    cols=2, size=args.size)
        print(f"wrote {args.png} (input, reconstruction)")
    return 0


def _is_pointcloud_checkpoint(path: str) -> bool:
    """Whether ``path`` is a Lightning checkpoint of a :mod:`shapeprog.pointcloud.train` module."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # unreadable: the VAE exporter reports it, naming the file
        return False
    return isinstance(payload, dict) and "shapeprog_pointcloud" in payload


def _cmd_export_weights(args) -> int:
    from .vae.pretrained import export_weights

    _check_outputs(others=[args.out])
    _refuse_overwrite([args.out], [args.checkpoint])
    if Path(args.checkpoint).is_file() and _is_pointcloud_checkpoint(args.checkpoint):
        from .pointcloud.train import export_weights  # noqa: F811 - a point-cloud model's checkpoint
    try:
        path = export_weights(args.checkpoint, args.out, half=not args.float32)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"error: {e}") from None
    print(f"wrote {path} ({path.stat().st_size / 2**20:.2f} MiB)")
    return 0


def _read_programs(folder: str) -> list:
    """The ``*.txt`` files of ``folder`` in name order, parsed; a file that does not decode or parse is
    kept as its text (it counts as an invalid sample) and reported on stderr."""
    path = Path(folder)
    if not path.is_dir():
        raise SystemExit(f"error: {folder}: no such folder")
    files = sorted(path.glob("*.txt"))
    if not files:
        raise SystemExit(f"error: {folder}: no .txt program files")
    out = []
    for f in files:
        text = ""
        try:
            text = decode(f.read_bytes(), str(f))
            out.append(parse(text, file=str(f)))
        except ParseError as e:
            print(f"warning: {e}", file=sys.stderr)
            out.append(text)
    return out


def _vae_samples(args) -> tuple[list, str, str]:
    """``-n`` programs sampled from the VAE (``--weights`` or the shipped model), the row name and a line
    on how often sampling was refused."""
    from .vae import sample

    from .vae.macro_model import MacroVAE

    vae = _load_vae(args, args.category, macro=True)
    t0 = time.perf_counter()
    if isinstance(vae, MacroVAE):  # macro programs (ShapeMOD): measured through their expansions
        from .vae.macro_decode import sample_macro
        results = sample_macro(vae, args.n, seed=args.seed, max_tries=10)
    else:
        results = sample(vae, args.n, seed=args.seed, max_tries=10)
    seconds = time.perf_counter() - t0
    where = args.weights or f"the shipped {args.category} model"
    meta = getattr(vae, "meta", {}) or {}
    epoch = f", epoch {meta['epoch']}" if "epoch" in meta else ""
    line = (f"Samples: {len(results)} from {where}{epoch} (seed {args.seed}, validity-checked decoding with "
            f"rejection, at most 10 draws each): {_sampling_report(results, 10, seconds)}. A sample refused 10 "
            f"times is decoded without rejection and kept."
            + (" The samples are macro programs; the metrics read their expansions (% novel compares those "
               "with the corpus's ShapeAssembly programs)." if isinstance(vae, MacroVAE) else "") + "\n\n")
    return [r.program for r in results], f"VAE samples ({where})", line


def _cmd_evaluate_generation(args) -> int:
    _check_outputs(others=[args.out])
    _refuse_overwrite([args.out], [args.classifier])
    if args.programs and args.n:
        raise SystemExit("error: give either --programs DIR or -n N (samples of the VAE), not both")
    model = None
    if args.classifier:
        from .vae.pointnet import load_classifier

        try:
            model = load_classifier(args.classifier)[0]
        except (FileNotFoundError, ValueError) as e:
            raise SystemExit(f"error: {e}") from None
    header, name = "", f"programs in {args.programs}" if args.programs else "generated"
    if args.n:
        samples, name, header = _vae_samples(args)
    else:
        samples = _read_programs(args.programs) if args.programs else []
    if not samples and args.no_ground_truth:
        raise SystemExit("error: nothing to evaluate: give --programs or -n, or leave out --no-ground-truth")
    pool = None
    if args.workers > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        pool = ProcessPoolExecutor(max_workers=args.workers, mp_context=multiprocessing.get_context("spawn"))
    t0 = time.perf_counter()
    try:
        table = generation_table(samples, args.category, ground_truth=not args.no_ground_truth, executor=pool,
                                 model=model,
                                 stability=not args.no_stability, fool=not args.no_fool, fool_epochs=args.fool_epochs,
                                 fool_average_last=args.fool_average_last, fool_points=args.fool_points,
                                 candidates=args.candidates or None, seed=args.seed,
                                 name=name,
                                 log=None if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True)))
    finally:
        if pool is not None:
            pool.shutdown()
    table = header + table
    sys.stdout.write(table)
    if args.out:
        atomic_write(args.out, table)
        print(f"wrote {args.out} ({time.perf_counter() - t0:.0f} s)")
    return 0


def _cmd_train_classifier(args) -> int:
    _check_outputs(others=[args.out])
    model, meta = train_category_classifier(epochs=args.epochs, per_class=args.per_class, points=args.points,
                                            finetune_epochs=args.finetune_epochs, seed=args.seed,
                                            log=lambda s: print(s, flush=True))
    save_classifier(args.out, model, meta["categories"], meta)
    per = ", ".join(f"{c} {a:.1f}" for c, a in meta["val_accuracy_per_category"].items())
    print(f"val accuracy {meta['val_accuracy']:.2f} % ({per}); trained in {meta['train_seconds']:.0f} s")
    print(f"wrote {args.out}, SHA-256 {sha256_file(args.out)}")
    return 0


#: The largest value of a count, step or size option that has no maximum of its own.
MAX_COUNT_OPTION = 10_000_000
#: The most worker processes of an option ``--workers``.
MAX_WORKERS = 256
#: The largest seed (NumPy and torch both take 0 to 2**63 - 1).
MAX_SEED = 2 ** 63 - 1
#: The largest time option, in seconds (``--stop-after``, ``--wake-seconds``; minutes options: this / 60).
MAX_SECONDS_OPTION = 366 * 24 * 3600.0
#: ``abstract-infer --passes`` at most.
MAX_PASSES = 100


def _int_at_least(low: int, high: int = MAX_COUNT_OPTION):
    """An argparse type: an int from ``low`` to ``high`` (:func:`shapeio.options.int_in`)."""
    return int_in(low, high)


def _seed(text: str) -> int:
    """An argparse type: a seed, 0 to :data:`MAX_SEED`."""
    return _int_at_least(0, MAX_SEED)(text)


_float_in = float_in  # an argparse type: a finite float in an interval


def _positive_float(text: str) -> float:
    """An argparse type: a positive finite float."""
    import math

    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _add_search_budget(parser, prefix: str, needs: str) -> None:
    """``--{prefix}search-seconds --{prefix}search-batches``: the recognition network's search budget per step
    of post hoc inference (default the wake's, the paper's 1 s; used with ``needs``)."""
    from .coder.search import WAKE_BATCH, WAKE_BATCHES, WAKE_SECONDS

    parser.add_argument(f"--{prefix}search-seconds", type=_positive_float, default=WAKE_SECONDS, metavar="S",
                        help=f"with {needs}: seconds of the network search per step (default {WAKE_SECONDS:g}, the "
                             "paper's wake; another budget is ours)")
    parser.add_argument(f"--{prefix}search-batches", type=_int_at_least(1), default=WAKE_BATCHES, metavar="N",
                        help=f"with {needs}: batches of {WAKE_BATCH} samples per search step at most "
                             f"(default {WAKE_BATCHES})")


def _search_budget(seconds: float, batches: int, network: bool, prefix: str, needs: str) -> dict:
    """``infer``'s budget keywords; a budget other than the wake's without the network is refused."""
    from .coder.search import WAKE_BATCHES, WAKE_SECONDS

    if (seconds, batches) != (WAKE_SECONDS, WAKE_BATCHES) and not network:
        raise SystemExit(f"error: --{prefix}search-seconds / --{prefix}search-batches need {needs}")
    return {"search_seconds": seconds, "search_batches": batches}


def _cmd_discover_abstractions(args) -> int:
    from .coder.discover import Config, discover_category

    category = args.category or args.category_pos
    if category not in ("chair", "table", "storage"):
        raise SystemExit("error: give the category: chair, table or storage")
    progress = None
    if not args.quiet:
        from tqdm import tqdm
        progress = lambda it, total, desc: tqdm(it, total=total, desc=desc, leave=False)  # noqa: E731
    try:
        cfg = Config(rounds=args.rounds, n_proposals=args.proposals, n_abstractions=args.abstractions,
                     seed=args.seed, wake=args.wake, n_dreams=args.dreams, train_seconds=60.0 * args.train_minutes,
                     train_epochs=args.train_epochs, train_lr=args.train_lr, dropout=args.dropout,
                     wake_seconds=args.wake_seconds, device=args.device, iterations=args.iterations,
                     max_nodes=args.max_nodes, time_limit=args.time_limit, egraph_values=args.egraph_values,
                     semantic_rewrites=not args.no_semantic_rewrites, network_from=args.network_from_round,
                     wake_repeats=args.wake_repeats)
    except ValueError as e:  # a setting out of range, named
        raise SystemExit(f"error: {e}") from None
    start = None
    if args.start_round is not None and not args.start_from:
        raise SystemExit("error: --start-round needs --start-from")
    if args.start_from:
        from .coder import tables

        src = Path(args.start_from)
        try:
            run = tables.from_run(src, category) if src.is_dir() else tables.shipped(args.start_from)
            log = tables.log_of(run)
        except (OSError, ValueError) as e:
            raise SystemExit(f"error: --start-from: {e}") from None
        if len(run.programs) < args.shapes:
            raise SystemExit(f"error: {args.start_from} has {len(run.programs)} programs, fewer than --shapes "
                             f"{args.shapes}")
        start = (run.library, list(run.programs[:args.shapes]), log)
    t0 = time.time()
    try:
        res = discover_category(category, args.out, cfg, args.shapes, args.workers, args.minutes, progress=progress,
                                start=start, start_round=args.start_round)
    except ValueError as e:  # a start that does not fit the shapes, named
        raise SystemExit(f"error: {e}") from None
    s = res.summary()
    print(f"{category}: F={s.F:.2f} |L|={s.library_size} struct={s.num_struct:.2f} param={s.num_param:.2f} "
          f"shapes={s.shapes} ({time.time() - t0:.0f} s); wrote {args.out}/library.txt, programs.txt, log.json")
    return 0


def _add_egraph_limits(parser) -> None:
    """``--iterations --max-nodes --time-limit``: the e-graph limits of each ShapeCoder refactor call (default
    the paper's; checked by :mod:`shapeprog.coder.refactor` before any work), and ``--egraph-values``."""
    from .coder.refactor import MAX_ENODES, MAX_ITERATIONS, TIME_LIMIT, VALUE_SCHEDULES, VALUES

    parser.add_argument("--iterations", type=_int_at_least(0, 1000), default=MAX_ITERATIONS,
                        help=f"e-graph iterations per refactor call (paper: {MAX_ITERATIONS})")
    parser.add_argument("--max-nodes", type=_int_at_least(1, 10_000_000), default=MAX_ENODES,
                        help=f"e-node limit per refactor call (paper: {MAX_ENODES}); larger e-graphs find cheaper "
                             f"programs at more time (docs/shapecoder.md)")
    parser.add_argument("--time-limit", type=_float_in(0, 3600, low_open=True), default=TIME_LIMIT,
                        help=f"seconds per refactor call (paper: {TIME_LIMIT:g})")
    parser.add_argument("--egraph-values", choices=VALUE_SCHEDULES, default=VALUES,
                        help=f"the e-graph's value table: {VALUES} (default, as the reference: up to date before every "
                             f"iteration) or lagged (one iteration behind, as runs made before 2026-11-29; to "
                             f"reproduce them)")


def _cmd_abstract_infer(args) -> int:
    from .coder import data
    from .coder.infer import infer, load_library, shipped_libraries
    from .coder.lang import Library

    if args.library in shipped_libraries():
        lib = load_library(args.library)
    else:
        path = Path(args.library)
        if not path.is_file():
            raise SystemExit(f"error: {args.library!r} is neither a shipped library "
                             f"({', '.join(shipped_libraries()) or 'none'}) nor a file")
        lib = Library.from_text(decode(path.read_bytes(), str(path)), file=str(path))
    spec = args.shape
    cat, _, num = spec.partition("/")
    if cat in data.CATEGORIES and num.isdigit():
        lines = data.read_lines(cat)
        if not 1 <= int(num) <= len(lines):
            raise SystemExit(f"error: {cat} has lines 1 to {len(lines)}")
        line = data.parse_record(lines[int(num) - 1], f"PN_{cat}.txt", int(num))
        shape = line.prims
    elif Path(spec).is_file():
        found = [(n, ln.rstrip("\r")) for n, ln in enumerate(decode(Path(spec).read_bytes(), spec).split("\n"), 1)
                 if ln.strip()]
        if len(found) != 1:
            raise SystemExit(f"error: {spec}: " + ("no shape line" if not found else
                             f"{len(found)} shape lines (the second at line {found[1][0]}); abstract-infer "
                             "reads one shape (table2-coder evaluates many)"))
        shape = data.parse_record(found[0][1], spec, found[0][0]).prims
    elif Path(spec).is_dir():
        raise SystemExit(f"error: {spec}: is a folder, not a shape file")
    elif "(" not in spec:  # a shape line always has a program: this is a file name
        raise SystemExit(f"error: {spec}: no such file (nor a PN_<category>.txt line or <category>/<line number>)")
    else:
        shape = spec
    network = None
    budget = _search_budget(args.search_seconds, args.search_batches, args.network, "", "--network")
    if args.network:
        from .coder.infer import load_network

        if args.library not in shipped_libraries():
            raise SystemExit("error: --network needs a shipped library (its recognition network ships with it)")
        try:
            network = load_network(args.library)
        except ValueError as e:
            raise SystemExit(f"error: --network: {e}") from None
    try:
        r = infer(shape, lib, passes=args.passes, iterations=args.iterations, max_nodes=args.max_nodes,
                  time_limit=args.time_limit, values=args.egraph_values, network=network, **budget)
    except ParseError:
        raise  # located in the shape's text; main reports it
    except ValueError as e:
        raise SystemExit(f"error: {args.shape}: {e}") from None
    print(f"program:  {r.text}\nexpanded: {r.expanded}\ncost: {r.cost:.2f}  error: {r.error:.4f}  e-graph: {r.stop}")
    return 0


def _open_for_edit(args):
    """The edit session of ``edit``'s arguments: (session, the text as read, its file name)."""
    from .editor.session import EditSession, is_corpus_text, read_source, refactor_source

    library = None
    if args.library:
        library = _macro_library(args.library, "--library: ")
    if args.sample:
        from .vae import load_pretrained, sample

        if args.program:
            raise SystemExit("error: give a PROGRAM or --sample, not both")
        text = sample(load_pretrained(args.sample), 1, seed=args.seed)[0].text
        file = f"{args.sample}_sample_seed{args.seed}.txt"
    elif args.program:
        try:
            text, file = read_source(args.program)
        except (FileNotFoundError, KeyError) as e:
            raise SystemExit(f"error: {e.args[0]}") from None
    else:
        raise SystemExit("error: give a PROGRAM (corpus id or file) or --sample CATEGORY")
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


def _cmd_edit(args) -> int:
    from shapeio.editing import editor_preflight, serve_until_interrupted

    problem = editor_preflight(args.export_dir)
    if problem:
        raise SystemExit(f"error: {problem}")  # exit status 1, as the argument errors of _open_for_edit
    session, text, file = _open_for_edit(args)
    from .editor.server import EditorApp

    app = EditorApp(session, host=args.host, port=args.port, export_dir=args.export_dir, source_text=text)
    return serve_until_interrupted(app, file, args.export_dir, not args.no_browser)


def _cmd_discover_macros(args) -> int:
    import os
    import platform
    from concurrent.futures import ProcessPoolExecutor

    from .macros.api import collection
    from .macros.discover import Discovery, discover, load_config, prior_rounds, rounds_line

    cfg = load_config(args.config, num_rounds=args.rounds, cand_cluster_num=args.proposal_steps,
                      abs_shape_num=args.subsample, selection=args.selection, search=args.search)
    lib0, text0 = _macro_library(args.start_from, "--start-from: ", text=True) if args.start_from else (None, "")
    prior = prior_rounds(text0, str(args.start_from)) if args.start_from else []
    out = Path(args.out)
    _refuse_overwrite([out / "library.txt"], [args.start_from, args.config])
    if (out / "library.txt").exists() and not (out / "state.json").exists():  # user files are never overwritten
        raise SystemExit(f"error: {out} holds a library.txt but no state.json of a discovery run to resume; "
                         "choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    command = "python -m shapeprog " + " ".join(sys.argv[1:] if args.argv is None else args.argv)
    pool = ProcessPoolExecutor(args.workers) if args.workers > 1 else None
    t0 = time.time()
    log = (lambda m: None) if args.quiet else (lambda m: print(f"[{time.time() - t0:7.1f} s] {m}", flush=True))
    try:
        nodes, ids = collection(args.category, args.split, args.limit, args.seed, executor=pool,
                                max_orders=cfg["abs_order_num"])
        log(f"{args.category}: {len(ids)} shapes, {len(nodes.keys)} sub-programs")
        start = None if lib0 is None else Discovery.from_library(lib0, nodes, prior, args.start_from)
        state = discover(nodes, cfg, seed=args.seed, executor=pool, out=out, log=log,
                         stop_after=args.stop_after, start=start)
    finally:
        if pool is not None:
            pool.shutdown()
    lib = state.library()
    header = (f"# ShapeMOD library ({args.category}), {len(lib.macros)} macros, |L| = {len(lib)}\n"
              f"# command: {command}\n"
              f"# shapes: {len(ids)} of split '{args.split}' (seed {args.seed}), sub-programs: {len(nodes.keys)}\n"
              f"{rounds_line(state, cfg)}\n"
              f"# time: {time.time() - t0:.0f} s on {platform.machine()}, {os.cpu_count()} CPUs, "
              f"{args.workers} worker(s)\n")
    atomic_write(out / "library.txt", header + lib.to_text())
    print(f"wrote {out / 'library.txt'} ({len(lib.macros)} macros)")
    return 0


def _macro_library(name: str, option: str = "", text: bool = False):
    """The ShapeMOD library ``name``: a library file when one exists at that path, else a shipped category;
    SystemExit with the reason otherwise. ``text``: (library, its file's text)."""
    from .macros import Library, load_library
    from .macros.api import library_text

    if Path(name).is_file():
        src = decode(Path(name).read_bytes(), name)
        lib = Library.from_text(src, name)
    else:
        try:
            lib, src = load_library(name), (library_text(name) if text else "")
        except ValueError as e:
            raise SystemExit(f"error: {option}{e}" + (" (or give a library file)" if option else "")) from None
    return (lib, src) if text else lib


def _cmd_refactor(args) -> int:
    from .macros import from_lines, refactor, to_text

    _refuse_overwrite([args.output], [args.program, args.library])
    prog = _Program(args.program)
    lib = _macro_library(args.library)
    cat, _, ident = args.program.partition("/")
    named = cat in corpus.CATEGORIES and ident.isdigit() and not Path(args.program).is_file()
    r = refactor(prog.program, lib, mode=args.search, category=cat if named else Path(args.program).stem,
                 shape_id=int(ident) if named else 0)
    for b in r.blocks:
        print(f"# {b.key}: f {b.f_base:.2f} (base) -> {b.f:.2f} (macros)")
        base = to_text(from_lines(b.lines))
        left = base.splitlines()
        right = b.text.splitlines()
        width = max((len(x) for x in left), default=0)
        for i in range(max(len(left), len(right))):
            a = left[i] if i < len(left) else ""
            c = right[i] if i < len(right) else ""
            print(f"{a:<{width}}  |  {c}")
        print()
    st = r.stats
    print(f"total: f {st['f_base']:.2f} -> {st['f']:.2f}; lines {st['lines']}, floats {st['float']}, "
          f"cuboid ids {st['cube']}, categoricals {st['categorical']}, booleans {st['bool']} "
          f"(after the bbox lines)")
    if args.output:
        atomic_write(args.output, r.text)
        print(f"wrote {args.output}")
    return 0


def _size(path: Path) -> str:
    n = path.stat().st_size if path.is_file() else sum(f.stat().st_size for f in path.iterdir())
    return f"{n / 1024:.0f} KiB"


def _cmd_refactor_corpus(args) -> int:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from .macros.refactored import check_target, refactor_corpus, write_refactored

    out = Path(args.out)
    try:
        check_target(out)
    except (FileExistsError, FileNotFoundError) as e:
        raise SystemExit(f"error: {e}") from None
    lib = _macro_library(args.library)
    command = "python -m shapeprog " + " ".join(sys.argv[1:] if args.argv is None else args.argv)
    pool = (ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn"))
            if args.workers > 1 else None)
    t0 = time.perf_counter()
    try:
        rc = refactor_corpus(args.category, lib, args.library, split=args.split, limit=args.limit, seed=args.seed,
                             executor=pool, mode=args.search, check=not args.no_check)
    finally:
        if pool is not None:
            pool.shutdown()
    seconds = time.perf_counter() - t0
    rc.meta["seconds"] = round(seconds, 1)
    rc.meta["workers"] = args.workers
    write_refactored(rc, out, command)
    s = rc.summary()
    m = s["mean_per_shape"]
    print(f"{args.category}: {s['refactored']} of {s['shapes']} shapes refactored with {args.library} "
          f"(|L| = {len(lib)}) in {seconds:.0f} s, {s['failed']} failed")
    if m["f_before"] is not None:
        print(f"per shape: f {m['f_before']:.2f} -> {m['f_after']:.2f}, lines {m['lines_before']:.2f} -> "
              f"{m['lines_after']:.2f}, floats {m['float_before']:.2f} -> {m['float_after']:.2f}")
    if s["max_corner_error"] is not None:
        print(f"check: largest leaf-corner distance to the original {s['max_corner_error']:.4f}; "
              f"{len(s['over_tolerance'])} shape(s) above {s['check_tolerance']}")
    for f in s["failures"]:
        print(f"failed: {args.category}/{f['id']}: {f['reason']}", file=sys.stderr)
    print(f"wrote {out} ({s['refactored']} programs and summary.json, {_size(out)})")
    return 0


def _category_pairs(values, form: str, flag: str = "--library") -> dict:
    """``--library CATEGORY=PATH`` values as a dict; a value without '=' stops with the expected form."""
    bad = [x for x in values or () if "=" not in x]
    if bad:
        raise SystemExit(f"error: {flag} {bad[0]!r}: expected {form}")
    return dict(x.split("=", 1) for x in values or ())


def _cmd_table1(args) -> int:
    from concurrent.futures import ProcessPoolExecutor

    from .macros.table1 import table1

    library_files = _category_pairs(args.library, "CATEGORY=FILE")
    _refuse_overwrite([args.out], library_files.values())
    pool = ProcessPoolExecutor(args.workers) if args.workers > 1 else None
    try:
        text = table1(args.categories, limit=args.limit, seed=args.seed, executor=pool, mode=args.search,
                      library_files=library_files,
                      log=None if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True)))
    finally:
        if pool is not None:
            pool.shutdown()
    print(text)
    if args.out:
        atomic_write(args.out, text + "\n")
        print(f"wrote {args.out}")
    return 0


def _cmd_table2_coder(args) -> int:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from .coder import tables

    runs = _category_pairs(args.library, "CATEGORY=FOLDER")
    baselines = {kind: _category_pairs(getattr(args, f"baseline_{kind}"), "CATEGORY=FOLDER", f"--baseline-{kind}")
                 for kind in ("input", "wake")}
    for flag, given in (("--library", runs), ("--baseline-input", baselines["input"]),
                        ("--baseline-wake", baselines["wake"])):
        unknown = sorted(set(given) - set(args.categories))
        if unknown:
            raise SystemExit(f"error: {flag} {unknown[0]}=...: {unknown[0]} is not among --categories")
    _check_outputs(others=[args.out])
    limits = {"iterations": args.iterations, "max_nodes": args.max_nodes, "time_limit": args.time_limit,
              "values": args.egraph_values}
    budget = _search_budget(args.phi_search_seconds, args.phi_search_batches, args.phi_network, "phi-", "--phi-network")
    command = "python -m shapeprog " + " ".join(sys.argv[1:] if args.argv is None else args.argv)
    parts = [f"# ShapeCoder Tables 2 and 3\n\n# command: {command}"]
    progress = None if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    # workers forked after this process ran torch can hang: with a network they start from a fresh interpreter
    ctx = multiprocessing.get_context("forkserver") if args.phi_network else None
    pool = ProcessPoolExecutor(args.workers, mp_context=ctx) if args.workers > 1 else None
    try:
        for cat in args.categories:
            try:
                run = tables.from_run(runs[cat], cat) if cat in runs else tables.shipped(cat)
                t2 = tables.table2(run)
                rows = [(kind, tables.baseline(tables.from_run(given[cat], cat), run))
                        for kind, given in baselines.items() if cat in given]
            except ValueError as e:
                raise SystemExit(f"error: {e}") from None
            try:
                network = tables.network_of(run) if args.phi_network else None
            except ValueError as e:
                raise SystemExit(f"error: --phi-network: {e}") from None
            t3 = tables.table3(run, train=args.train, heldout=args.heldout, executor=pool, progress=progress,
                               network=network, **limits, **budget)
            parts.append(tables.format_tables(run, t2, t3, **limits, network=network is not None, baselines=rows,
                                              **budget))
            print(parts[-1] + "\n", flush=True)
    finally:
        if pool is not None:
            pool.shutdown()
    if args.out:
        atomic_write(args.out, "\n\n".join(parts) + "\n")
        print(f"wrote {args.out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The command line's parser, every sub-command with its options (``main`` runs what it parses)."""
    ap = argparse.ArgumentParser(prog="shapeprog", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    program_help = "corpus id (chair/173, table/33075, storage/46436) or a UTF-8 program file (corpus or flat format)"
    r = sub.add_parser("run", help="execute a program and export its cuboids",
                       description="Execute a program; print its block and cuboid counts; export a mesh and a picture.")
    r.add_argument("program", help=program_help)
    r.add_argument("-o", "--output", help="mesh file: .obj (reference layout), .ply or .glb (parts coloured by line)")
    r.add_argument("--png", help="picture file (.png), parts coloured by the program line that created them")
    r.add_argument("--size", type=_int_at_least(8, MAX_PICTURE_SIZE), default=512,
                   help=f"picture width and height in pixels (8 to {MAX_PICTURE_SIZE})")
    r.add_argument("--float64", action="store_true", help="execute in float64 (default float32, the reference)")
    r.set_defaults(func=_cmd_run)
    f = sub.add_parser("fit", help="fit a program's parameters to a point cloud",
                       description="Fit a program's continuous numbers to a point cloud; print chamfer and F-score "
                                   "before and after; write the fitted program.")
    f.add_argument("program", help=program_help)
    f.add_argument("--points", default="example",
                   help="point cloud file (.obj 'v x y z' lines, .ply, .xyz or .npy) or 'example' (the vendored comp_pc.obj)")
    f.add_argument("--steps", type=_int_at_least(0, MAX_FIT_STEPS), default=400, help="optimisation steps")
    f.add_argument("--lr", type=_float_in(0, MAX_LR, low_open=True), default=1e-3,
                   help=f"Adam learning rate (above 0, at most {MAX_LR:g})")
    f.add_argument("--reg", type=_float_in(0, MAX_REG), default=1e-3, help="weight of the pull towards the starting numbers")
    f.add_argument("--decimals", type=_int_at_least(0, MAX_DECIMALS), default=3, help="decimals of the written numbers (the corpus uses 3)")
    f.add_argument("--seed", type=_seed, default=0, help="seed of the surface sampling")
    f.add_argument("-o", "--output", help="fitted program file (ShapeAssembly text; default: print it)")
    f.add_argument("--mesh", help="also write the fitted shape: .obj, .ply or .glb")
    f.set_defaults(func=_cmd_fit)
    s = sub.add_parser("silhouettes", help="render front and side silhouettes of the corpus to an .npz",
                       description="Render front and side silhouettes of every corpus program (train and val).")
    s.add_argument("--out", required=True, help="output file (.npz, compressed NumPy arrays)")
    s.add_argument("--size", type=_int_at_least(1, SILHOUETTE_MAX_SIZE), default=64,
                   help=f"image side in pixels (1 to {SILHOUETTE_MAX_SIZE})")
    s.add_argument("--margin", type=_int_at_least(0, SILHOUETTE_MAX_SIZE), default=4, help="free pixels on each side of the longer extent")
    s.add_argument("--limit", type=_int_at_least(1), help="only the first N shapes per category and split")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=_cmd_silhouettes)
    i = sub.add_parser("infer", help="a ShapeAssembly program for a point cloud or a mesh",
                       description="Encode a point cloud (.ply .obj .xyz .npy) or a mesh (.obj .ply .stl .glb, "
                                   "sampled by area) with the trained point-cloud model, decode a program, "
                                   "optionally polish its numbers by fitting (--fit), and write into --out: "
                                   "<name>.txt (the program at the input's scale, in the power of ten of input units that "
                                   "keeps its numbers in the corpus's range: the json's unit), <name>.obj (its cuboids in "
                                   "the input's frame), <name>.png (input beside result) and <name>.json "
                                   "(offset, rotation, metrics). Existing files are never overwritten.")
    i.add_argument("file", help="point cloud or mesh file")
    i.add_argument("--category", default="chair", choices=corpus.CATEGORIES,
                   help="the shipped model to use (chair, table or storage)")
    i.add_argument("--weights", help="a point-cloud weights file instead of the shipped one")
    i.add_argument("--fit", action="store_true", help="polish the program's numbers against the cloud")
    i.add_argument("--steps", type=_int_at_least(0), default=150, help="fitting steps (with --fit)")
    i.add_argument("--search", action="store_true",
                   help="latent search: decode 96 more codes around the predicted one and keep the program closest "
                        "to the cloud (about 1 s; before --fit)")
    i.add_argument("--search-schedule", metavar="N:SIGMA,...",
                   help="the search's steps, e.g. 16:0.75,16:0.5, or 'quick' (5 decodes; with --retrieval), 'fast' (17 decodes, "
                        "about 4.5x a plain decode's time) or 'default' (implies --search)")
    i.add_argument("--retrieval", nargs="?", type=_int_at_least(1), const=0, metavar="K",
                   help="retrieval-augmented decoding (ours, not the papers'): the decoded program competes with the K "
                        "training programs nearest to the cloud (without K: the constant "
                        "RETRIEVAL_CANDIDATES of shapeprog/pointcloud/infer.py); the one closest to the cloud is kept. Give the file before "
                        "--retrieval: a file right after it is read as K")
    i.add_argument("--clouds", metavar="DIR",
                   help="with --retrieval: a make-clouds folder whose training clouds make the index (else it is "
                        "sampled from the corpus, about 20 s for chairs)")
    i.add_argument("--up", default="y", choices=("y", "z", "x", "-y", "-z", "-x"), help="the input's up axis")
    i.add_argument("--no-stability", action="store_true", help="skip the stability test (about 0.5 s)")
    i.add_argument("--size", type=_int_at_least(8, MAX_PICTURE_SIZE), default=256, help="picture cell size in pixels")
    i.add_argument("--seed", type=_seed, default=0, help="seed of the point subsets")
    i.add_argument("--out", required=True, help="output folder (created if missing)")
    i.set_defaults(func=_cmd_infer)
    pt = sub.add_parser("pointcloud-tables", help="the papers' point-cloud reconstruction tables on the test split",
                        description="Measure the point-cloud model (no fitting, Opt Program, Opt Cuboids) and the "
                                    "retrieval baseline on the test split of a make-clouds cache (noisy 2,048-point "
                                    "inputs in random scale and position) and write the ShapeMOD Table 3 and "
                                    "ShapeAssembly Table 7 layouts as Markdown.")
    pt.add_argument("--category", default="chair", choices=corpus.CATEGORIES, help="the category")
    pt.add_argument("--clouds", required=True, help="the make-clouds folder")
    pt.add_argument("--weights", help="a point-cloud weights file (default: the shipped model)")
    pt.add_argument("--limit", type=_int_at_least(1), help="the first N test shapes only")
    pt.add_argument("--steps", type=_int_at_least(0), default=150, help="fitting steps of the optimisation rows")
    pt.add_argument("--no-stability", action="store_true", help="skip the stability test")
    pt.add_argument("--no-retrieval", action="store_true", help="leave out the retrieval row")
    pt.add_argument("--search", action="store_true", help="also measure the latent-search rows (ours, not the papers')")
    pt.add_argument("--augmented", action="store_true",
                    help="also measure the retrieval-augmented decoding rows (ours, not the papers')")
    pt.add_argument("--workers", type=_int_at_least(1, MAX_WORKERS), default=1, help="processes for the per-shape work")
    pt.add_argument("--seed", type=_seed, default=0, help="seed of the inputs' noise, subsets, scales and positions")
    pt.add_argument("--quiet", action="store_true", help="no progress lines")
    pt.add_argument("--out", required=True, help="Markdown file (e.g. docs/tables/pointcloud_chair.md)")
    pt.set_defaults(func=_cmd_pointcloud_tables, argv=None)
    m = sub.add_parser("make-clouds", help="sample point clouds of a category's corpus shapes into a cache",
                       description="Sample area-weighted surface points of every executed program of a category "
                                   "into <out>/<category>_clouds.npz, and write the train / val / test split "
                                   "(val: a seeded carve-out of the corpus train split; test: the corpus val "
                                   "split) to <out>/<category>_split.json. A program that fails is reported "
                                   "and skipped.")
    m.add_argument("--category", required=True, choices=corpus.CATEGORIES, help="the corpus category")
    m.add_argument("--out", required=True, help="the cache folder (created if missing)")
    m.add_argument("--points", type=_int_at_least(1, MAX_POINTS), default=10000, help="points per shape (the papers' 10,000)")
    m.add_argument("--workers", type=_int_at_least(1, MAX_WORKERS), help="processes (default: the CPU count; 1: none)")
    m.add_argument("--seed", type=_seed, default=0, help="sampling seed (each shape's seed is a hash of category, "
                                                       "id and this)")
    m.add_argument("--val-fraction", type=_float_in(0, 1, high_open=True), default=0.05, help="share of the corpus train split carved out "
                                                                    "for validation")
    m.add_argument("--split-seed", type=_seed, default=0, help="seed of the validation carve-out")
    m.add_argument("--dtype", choices=("float16", "float32"), default="float16",
                   help="storage type of the points (float16: half the size, within 5e-4)")
    m.add_argument("--limit", type=_int_at_least(1), help="only the first N shapes of the corpus train and val "
                                                          "splits (a quick check)")
    m.add_argument("--quiet", action="store_true", help="no progress bar")
    m.set_defaults(func=_cmd_make_clouds)
    weights_help = "VAE weights file or Lightning checkpoint (default: the shipped model of the category)"
    g = sub.add_parser("sample", help="generate programs with the VAE",
                       description="Sample latents from N(0, I) and decode them with semantic validity "
                                   "(rejection sampling); write programs, meshes and a picture grid.")
    g.add_argument("category", nargs="?", choices=corpus.CATEGORIES, help="the shipped model to use")
    g.add_argument("-n", type=_int_at_least(1, MAX_SAMPLES), default=16, help=f"number of samples (1 to {MAX_SAMPLES})")
    g.add_argument("--seed", type=_seed, default=0, help="seed of the latents (an integer)")
    g.add_argument("--max-tries", type=_int_at_least(1, MAX_TRIES), default=10, help="draws per sample before giving up rejection")
    g.add_argument("--out", help="folder for sample_NNNN.txt and sample_NNNN.obj")
    g.add_argument("--png", help="picture grid of the samples (.png)")
    g.add_argument("--cols", type=_int_at_least(1), default=4, help="grid columns")
    g.add_argument("--size", type=_int_at_least(8, MAX_PICTURE_SIZE), default=192, help="grid cell side in pixels")
    g.add_argument("--weights", help=weights_help)
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    g.set_defaults(func=_cmd_sample)
    i = sub.add_parser("interpolate", help="decode shapes along the latent line between two programs",
                       description="Encode two programs, interpolate their latent means linearly and decode "
                                   "each step (both ends included).")
    i.add_argument("a", help=program_help)
    i.add_argument("b", help=program_help)
    i.add_argument("--steps", type=_int_at_least(2), default=8, help="shapes along the line, ends included (>= 2)")
    i.add_argument("--category", choices=corpus.CATEGORIES, help="model category (default: the first corpus id's)")
    i.add_argument("--out", help="folder for step_NNN.txt and step_NNN.obj")
    i.add_argument("--png", help="picture strip of the steps (.png)")
    i.add_argument("--size", type=_int_at_least(8, MAX_PICTURE_SIZE), default=160, help="cell side in pixels")
    i.add_argument("--weights", help=weights_help)
    i.set_defaults(func=_cmd_interpolate)
    c = sub.add_parser("reconstruct", help="encode a program and decode it back, with the F-score to the input",
                       description="Encode a program to its latent mean, decode it with semantic validity, and "
                                   "print the F-score and chamfer distance to the input shape.")
    c.add_argument("program", help=program_help)
    c.add_argument("--category", choices=corpus.CATEGORIES, help="model category (default: the corpus id's)")
    c.add_argument("-o", "--output", help="reconstructed program file (default: print it)")
    c.add_argument("--mesh", help="also write the reconstructed shape: .obj, .ply or .glb")
    c.add_argument("--png", help="picture of the input beside the reconstruction (.png)")
    c.add_argument("--size", type=_int_at_least(8, MAX_PICTURE_SIZE), default=256, help="cell side in pixels")
    c.add_argument("--seed", type=_seed, default=0, help="seed of the surface samples of the F-score")
    c.add_argument("--weights", help=weights_help)
    c.set_defaults(func=_cmd_reconstruct)
    x = sub.add_parser("export-weights", help="write a VAE or point-cloud training checkpoint as a small weights file",
                       description="Write the VAE of a Lightning checkpoint (or weights file) as a weights file "
                                   "that --weights and shapeprog.vae.load_pretrained read; a checkpoint of a "
                                   "point-cloud model (configs/pointcloud/) becomes the file that `infer "
                                   "--weights` and shapeprog.pointcloud.load_model read.")
    x.add_argument("checkpoint", help="a .ckpt file written by `python train.py fit --config configs/shapeassembly/...` "
                                      "or `configs/pointcloud/...`")
    x.add_argument("--out", required=True, help="the weights file to write (.pt)")
    x.add_argument("--float32", action="store_true", help="keep float32 (default: float16 storage)")
    x.set_defaults(func=_cmd_export_weights)
    e = sub.add_parser("evaluate-generation", help="the generation tables (Tables 2, 4, 5) of VAE samples or a folder of programs",
                       description="Measure generated programs with the ShapeAssembly paper's generation metrics "
                                   "(% rooted, % stable, % fool, FD, leaf parts, generalization, coverage, variety, "
                                   "% novel) against the corpus train split, beside the ground truth (the val split) "
                                   "and the paper's figures; print a markdown table.")
    e.add_argument("--category", required=True, choices=corpus.CATEGORIES, help="the category the programs belong to")
    e.add_argument("--programs", help="folder of program files (*.txt, one program each); without it, the "
                                      "ground-truth row alone")
    e.add_argument("-n", type=_int_at_least(1, MAX_SAMPLES), help="evaluate N samples of the VAE (the shipped model of the "
                                                    "category, or --weights) instead of a folder")
    e.add_argument("--weights", help=weights_help)
    e.add_argument("--classifier", help="PointNet weights for FD and the features (a train-classifier output; "
                                        "default: the shipped shapeprog/weights/pointnet_cls.pt)")
    e.add_argument("--out", help="also write the table to this markdown file")
    e.add_argument("--no-ground-truth", action="store_true", help="leave out the ground-truth (val split) row")
    e.add_argument("--no-stability", action="store_true", help="skip the stability test (about 0.5 s per shape)")
    e.add_argument("--no-fool", action="store_true", help="skip %% fool (trains a PointNet per row)")
    e.add_argument("--fool-epochs", type=_int_at_least(1), default=12, help="%% fool training epochs (paper: 300)")
    e.add_argument("--fool-average-last", type=_int_at_least(1), default=4, help="%% fool: epochs averaged at the end")
    e.add_argument("--fool-points", type=_int_at_least(16), default=512, help="%% fool: points per shape")
    e.add_argument("--candidates", type=_int_at_least(0), default=16,
                   help="shapes measured exactly per nearest-chamfer search (0: every pair)")
    e.add_argument("--workers", type=_int_at_least(1, MAX_WORKERS), default=1, help="processes for the per-shape work")
    e.add_argument("--seed", type=_seed, default=0, help="seed of the sampling and of the %% fool training")
    e.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    e.set_defaults(func=_cmd_evaluate_generation)
    t = sub.add_parser("train-classifier", help="train the PointNet classifier of the generation metrics",
                       description="Train the chair / table / storage PointNet classifier on the corpus train "
                                   "split; print its val accuracy; write its weights and their SHA-256.")
    t.add_argument("--out", required=True, help="weights file (.pt)")
    t.add_argument("--epochs", type=_int_at_least(1), default=10, help="epochs on point subsets")
    t.add_argument("--per-class", type=_int_at_least(1), default=500, help="shapes per category and epoch")
    t.add_argument("--points", type=_int_at_least(16), default=512, help="points per shape and visit")
    t.add_argument("--finetune-epochs", type=_int_at_least(0), default=1, help="final epochs on all 2,500 points")
    t.add_argument("--seed", type=_seed, default=0, help="seed of the sampling and the training")
    t.set_defaults(func=_cmd_train_classifier)
    d = sub.add_parser("discover-abstractions", help="ShapeCoder: discover a library of abstractions for a category",
                       description="Run ShapeCoder's discovery (wake by e-graph refactoring or, with --wake "
                                   "network, with dreams and a recognition network; proposal, integration, "
                                   "removal sweep; a final wake with the library fixed) on the first N discovery "
                                   "shapes of a PartNet category; write library.txt, programs.txt, log.json and a "
                                   "resumable state.json into --out.")
    d.add_argument("category_pos", nargs="?", metavar="category", help="chair, table or storage")
    d.add_argument("--category", choices=("chair", "table", "storage"), help="the category (or give it first)")
    d.add_argument("--out", required=True, help="output folder (an earlier run's folder resumes it)")
    d.add_argument("--rounds", type=_int_at_least(0), default=4, help="proposal/integration rounds (paper: 4)")
    d.add_argument("--shapes", type=_int_at_least(1), default=400, help="the first N discovery shapes (paper: 400)")
    d.add_argument("--proposals", type=_int_at_least(1), default=10000, help="proposals per round (paper: 10,000)")
    d.add_argument("--abstractions", type=_int_at_least(1), default=20, help="candidates tried per round (N_A, 20)")
    d.add_argument("--seed", type=_seed, default=42, help="seed of the proposals")
    d.add_argument("--workers", type=_int_at_least(1, MAX_WORKERS), default=2, help="processes for the per-program refactors")
    d.add_argument("--minutes", type=_float_in(0, MAX_SECONDS_OPTION / 60), help="start no phase after this many minutes (the run stays resumable)")
    d.add_argument("--wake", choices=("refactor", "network"), default="refactor",
                   help="wake search: by refactoring only (default), or with dreams and a recognition network "
                        "(needs torch)")
    d.add_argument("--dreams", type=_int_at_least(1), default=10000,
                   help="network wake: valid dreams per function (N_D, paper: 10,000)")
    d.add_argument("--train-minutes", type=_float_in(0, MAX_SECONDS_OPTION / 60), default=200.0,
                   help="network wake: training budget per round in minutes (paper: 200)")
    d.add_argument("--train-epochs", type=_int_at_least(1), default=300, help="network wake: epochs at most (300)")
    d.add_argument("--train-lr", type=_float_in(0, MAX_LR, low_open=True), default=1e-4, help="network wake: Adam learning rate (1e-4)")
    d.add_argument("--dropout", type=_float_in(0, 1, high_open=True), default=0.5, help="network wake: the network's dropout (0.5)")
    d.add_argument("--wake-seconds", type=_float_in(0, MAX_SECONDS_OPTION, low_open=True), default=1.0,
                   help="network wake: seconds of sampling per search step (1)")
    d.add_argument("--device", default="auto", help="network wake: where to train (auto: CUDA when available)")
    d.add_argument("--network-from-round", type=_int_at_least(0), default=0,
                   help="network wake: the first round that uses the network; earlier rounds use the refactor-only "
                        "wake (0: every round, the paper)")
    d.add_argument("--wake-repeats", type=_int_at_least(1), default=1,
                   help="network wake: wakes per round with the round's network, each from the last one's programs "
                        "with other sampling seeds (1: the paper)")
    d.add_argument("--start-from", metavar="LIBRARY",
                   help="begin with an earlier run's library and programs: a shipped category (chair) or a "
                        "discover-abstractions output folder; e.g. with --wake network, the final wake again with "
                        "the recognition network")
    d.add_argument("--start-round", type=_int_at_least(0),
                   help="with --start-from: the round whose wake comes first (default --rounds: only the final "
                        "wake)")
    d.add_argument("--no-semantic-rewrites", action="store_true",
                   help="refactor with the abstraction rules only (the paper's 'no semantic rewrites' ablation; "
                        "with the default wake, the structure-only library-learning baseline of table2-coder "
                        "--baseline-input / --baseline-wake)")
    _add_egraph_limits(d)
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    d.set_defaults(func=_cmd_discover_abstractions)
    a = sub.add_parser("abstract-infer", help="ShapeCoder: infer one shape's program with a discovered library",
                       description="Post hoc inference: refactor the naive program of one shape with a library's "
                                   "abstractions; print the program, its expansion, its cost and error.")
    a.add_argument("shape", help="a PN_<category>.txt line, a file with one such line, or <category>/<line number> "
                                 "of the vendored data (e.g. chair/401)")
    a.add_argument("--library", required=True, help="a shipped category (chair) or a library.txt file")
    _add_egraph_limits(a)
    a.add_argument("--passes", type=_int_at_least(1, MAX_PASSES), default=3, help="refactor calls at most, each on the previous result")
    a.add_argument("--network", action="store_true",
                   help="also search with the shipped library's recognition network (the paper's post hoc "
                        "inference; slower)")
    _add_search_budget(a, "", "--network")
    a.set_defaults(func=_cmd_abstract_infer)
    d = sub.add_parser("edit", help="edit a program in the browser (needs the 'editor' extra: viser)",
                       description="Serve an editor page for a program: the shape in 3D, one control per free "
                                   "parameter, live re-execution, undo / redo / reset, export of text, OBJ and "
                                   "PNG. Runs until interrupted. See docs/editor.md.")
    d.add_argument("program", nargs="?", help=program_help + ", or a macro program file (lines 'def ...')")
    d.add_argument("--sample", choices=corpus.CATEGORIES, help="edit a program generated by the shipped VAE instead")
    d.add_argument("--seed", type=_seed, default=0, help="seed of --sample")
    d.add_argument("--library", help="a shipped ShapeMOD library's category (chair) or a macro library file: a "
                                     "ShapeAssembly program (corpus id or corpus-format file) is refactored with it "
                                     "and its macro calls' parameters are edited; a macro program calls it")
    d.add_argument("--target", help="goal-directed mode: a program (corpus id or file) shown as a wireframe, "
                                    "with the live corner distance to it")
    d.add_argument("--port", type=port_argument, default=8080, help="port of the page (0: a free one)")
    d.add_argument("--host", default="127.0.0.1", help="address to bind (default: this machine only)")
    d.add_argument("--export-dir", default=".", help="the folder exports are written to (never elsewhere)")
    d.add_argument("--no-browser", action="store_true", help="do not open a browser")
    d.set_defaults(func=_cmd_edit)
    d = sub.add_parser("discover-macros", help="ShapeMOD: discover a macro library from a category's programs",
                       description="Run ShapeMOD discovery (proposal, generalisation, integration, filterBadOrders) "
                                   "on a corpus category; state.json is written after every round and an "
                                   "interrupted run resumes from it; library.txt holds the result.")
    d.add_argument("--category", required=True, choices=corpus.CATEGORIES)
    d.add_argument("--out", required=True, help="output folder (state.json, library.txt)")
    d.add_argument("--config", help="settings YAML (default: configs/shapemod/default.yaml's values)")
    d.add_argument("--rounds", type=_int_at_least(1), help="rounds (default 5)")
    d.add_argument("--proposal-steps", type=_int_at_least(1), help="proposal steps per round (default 10000)")
    d.add_argument("--subsample", type=_int_at_least(1), help="sub-programs of the integration subsample (1000)")
    d.add_argument("--selection", choices=("greedy", "milp"), help="greedy (the reference) or milp (exact)")
    d.add_argument("--search", choices=("beam", "exact"), help="best-program search: beam (reference) or exact")
    d.add_argument("--split", default="all", choices=("train", "val", "all"))
    d.add_argument("--limit", type=_int_at_least(1), help="a random subset of N shapes")
    d.add_argument("--seed", type=_seed, default=0)
    d.add_argument("--workers", type=_int_at_least(1, MAX_WORKERS), default=1, help="processes for the searches (1: none)")
    d.add_argument("--stop-after", type=_float_in(0, MAX_SECONDS_OPTION), help="seconds after which no new round starts")
    d.add_argument("--start-from", metavar="LIBRARY",
                   help="continue from a library (a shipped category's or a file) when --out holds no state: "
                        "its macros are L, the rounds its header records count toward --rounds, and the "
                        "orderings are filtered with it first (a library file does not record them)")
    d.add_argument("--quiet", action="store_true")
    d.set_defaults(func=_cmd_discover_macros, argv=None)
    rf = sub.add_parser("refactor", help="rewrite a program with a ShapeMOD library",
                        description="Rewrite every sub-program with the library's macros (best program over its "
                                    "orderings); print it beside the base program with both f.")
    rf.add_argument("program", help=program_help)
    rf.add_argument("--library", default="chair", help="a shipped library's category or a library file")
    rf.add_argument("--search", choices=("beam", "exact"), default="beam")
    rf.add_argument("-o", "--output", help="write the macro programs here")
    rf.set_defaults(func=_cmd_refactor)
    rc = sub.add_parser("refactor-corpus", help="ShapeMOD: rewrite every corpus program of a category with a library",
                        description="Refactor every corpus program of a category with a ShapeMOD library (process "
                                    "pool with --workers > 1), check each against its original (parse back, "
                                    "execute, leaf cuboids matched), and write one macro program per shape "
                                    "(<id>.txt) and summary.json into a new folder, atomically.")
    rc.add_argument("--category", required=True, choices=corpus.CATEGORIES)
    rc.add_argument("--library", required=True, help="a shipped library's category or a library file")
    rc.add_argument("--out", required=True, help="the new folder (must not exist, or be empty), or a new "
                                                 "FILE.tar.xz archive of the same files")
    rc.add_argument("--split", default="all", choices=("train", "val", "all"))
    rc.add_argument("--limit", type=_int_at_least(1), help="a random subset of N shapes of the split")
    rc.add_argument("--seed", type=_seed, default=0, help="seed of --limit's subset")
    rc.add_argument("--search", choices=("beam", "exact"), default="beam")
    rc.add_argument("--workers", type=_int_at_least(1, MAX_WORKERS), default=2,
                    help="processes of the pool (default 2; 1: no pool, everything in this process)")
    rc.add_argument("--no-check", action="store_true", help="skip reading back and executing every result")
    rc.set_defaults(func=_cmd_refactor_corpus, argv=None)
    tb = sub.add_parser("table1", help="ShapeMOD Table 1: No Macros, Baseline macros and ShapeMOD rows",
                        description="Compute the ShapeMOD paper's Table 1 (f, |L|, fn, d, f, b per shape) for the "
                                    "given categories beside the paper's rows.")
    tb.add_argument("--categories", nargs="+", default=["chair"], choices=corpus.CATEGORIES)
    tb.add_argument("--limit", type=_int_at_least(1), help="a random subset of N shapes per category")
    tb.add_argument("--seed", type=_seed, default=0)
    tb.add_argument("--library", action="append", help="CATEGORY=FILE: a library file instead of the shipped one")
    tb.add_argument("--search", choices=("beam", "exact"), default="beam")
    tb.add_argument("--workers", type=_int_at_least(1, MAX_WORKERS), default=1)
    tb.add_argument("--out", help="also write the table (markdown) here")
    tb.add_argument("--quiet", action="store_true")
    tb.set_defaults(func=_cmd_table1)
    t2 = sub.add_parser("table2-coder", help="ShapeCoder Tables 2 and 3 of discovered libraries",
                        description="Write the ShapeCoder paper's Table 2 (Input Prims and ShapeCoder rows: F, |L|, "
                                    "Num Struct, Num Param on the discovery shapes) and Table 3 (F of the discovered "
                                    "programs, and post hoc inference on the first --train discovery and --heldout "
                                    "held-out shapes) for the shipped libraries or discover-abstractions folders, "
                                    "beside the paper's rows.")
    t2.add_argument("--categories", nargs="+", default=["chair"], choices=("chair", "table", "storage"))
    t2.add_argument("--library", action="append",
                    help="CATEGORY=FOLDER: a discover-abstractions output folder instead of the shipped library")
    t2.add_argument("--baseline-input", action="append", metavar="CATEGORY=FOLDER",
                    help="a discover-abstractions folder of the same shapes run with --no-semantic-rewrites from "
                         "the naive programs: Table 2's structure-only row beside the paper's ShapeMOD+Input (ours)")
    t2.add_argument("--baseline-wake", action="append", metavar="CATEGORY=FOLDER",
                    help="the same, started (--start-from, --start-round 0) from the programs of one wake with the "
                         "semantic rewrites: the row beside the paper's ShapeMOD+Wake (ours)")
    t2.add_argument("--train", type=_int_at_least(1), default=100, help="train-PHI: the first N discovery shapes")
    t2.add_argument("--heldout", type=_int_at_least(1), default=100, help="validation-PHI: the first N held-out shapes")
    t2.add_argument("--workers", type=_int_at_least(1, MAX_WORKERS), default=2,
                    help="processes for the per-shape inference (1: everything in this process)")
    _add_egraph_limits(t2)
    t2.add_argument("--phi-network", action="store_true",
                    help="post hoc inference with the library's recognition network as well (the paper's; the "
                         "shipped <category>_recnet.pt, or a run folder's last recnet_round<k>.pt); default: "
                         "refactoring only")
    _add_search_budget(t2, "phi-", "--phi-network")
    t2.add_argument("--out", help="also write the tables (markdown) here, atomically")
    t2.add_argument("--quiet", action="store_true")
    t2.set_defaults(func=_cmd_table2_coder, argv=None)
    return ap


#: Each command's output options and what they name: ``"folder"`` (created with its parents), ``"file"`` (in
#: an existing folder) or ``"file+"`` (its folder created); :func:`main` checks them with
#: :func:`shapeio.files.output_problem` before the command's work starts.
OUTPUTS = {
    "run": {"output": "file"}, "fit": {"output": "file"}, "reconstruct": {"output": "file"}, "refactor": {"output": "file"},
    "silhouettes": {"out": "file"}, "infer": {"out": "folder"}, "pointcloud-tables": {"out": "file"},
    "make-clouds": {"out": "folder"}, "sample": {"out": "folder"}, "interpolate": {"out": "folder"},
    "export-weights": {"out": "file"}, "evaluate-generation": {"out": "file"}, "train-classifier": {"out": "file+"},
    "discover-abstractions": {"out": "folder"}, "discover-macros": {"out": "folder"},
    "refactor-corpus": {"out": "folder"}, "table1": {"out": "file"}, "table2-coder": {"out": "file"},
}


def _output_problem(args) -> str | None:
    """The first of ``args``' outputs (:data:`OUTPUTS`) that cannot be written, as an error line."""
    for attr, kind in OUTPUTS.get(args.cmd, {}).items():
        value = getattr(args, attr, None)
        if value:
            problem = output_problem(value, folder=kind == "folder", create=kind != "file")
            if problem:
                return f"error: --{attr} {value}: {problem}"
    return None


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    problem = _output_problem(args)
    if problem:
        raise SystemExit(problem)
    if getattr(args, "argv", False) is None:  # commands that record their own command line
        args.argv = list(argv) if argv is not None else None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            return args.func(args)
    except (ParseError, ExecutionError, RefactorError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (OSError, InputError) as e:  # unreadable inputs, unwritable outputs: the message names the file
        print(f"error: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
