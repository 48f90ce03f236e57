"""``python -m shapeprog pointcloud ...``: programs for point clouds and meshes (infer), the point-cloud tables,
the cloud cache they read (make-clouds), and the export of trained weights."""
from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from shapeio import atomic_write
from shapeio.files import write_new_set
from shapeio.image import png_bytes
from shapeio.points import MAX_POINTS
from shapeio.points import read_cloud

from .. import corpus
from ..cli import (add_category, add_command, add_export_weights, add_json, add_overwrite, add_quiet, add_seed,
                   add_workers, command_line, float_in, int_at_least, markdown_result, refuse_existing, refuse_inputs,
                   worker_pool, write_json)
from ..errors import PointCloudError
from ..execute import execute
from ..io import obj_text
from ..picture import MAX_SIZE as MAX_PICTURE_SIZE
from ..picture import render_grid
from .data import cache_paths
from .data import make_clouds
from .infer import (DEFAULT_METHOD, FSCORE_THRESHOLD, METHODS, POLISH_STEPS, RETRIEVAL_CANDIDATES, ROBUST_CANDIDATES,
                    ROBUST_SUBSETS, SELECT_POINTS, UpAxisWarning, cloud_corners, infer, load_model)
from .retrieval import RetrievalIndex
from .search import parse_schedule
from .tables import evaluate, write_tables



def fmt_metrics(m: dict) -> str:
    cd = "n/a" if m["cd"] is None else f"{1000 * m['cd']:.1f}"
    yes = {True: "yes", False: "no", None: "not run"}
    return (f"CD x1000 {cd}, F-score @{FSCORE_THRESHOLD:g} {m['fscore']:.1f}, rooted {yes[m['rooted']]}, "
            f"stable {yes[m['stable']]}" + (" (--stability)" if m["stable"] is None else ""))


def retrieval_index(category: str, clouds):
    """The retrieval index of ``category``'s training shapes: from a make-clouds folder, or sampled from the
    corpus (with a progress line on stderr)."""
    t0 = time.perf_counter()
    if clouds:
        try:
            index = RetrievalIndex.from_cache(clouds, category)
        except (OSError, ValueError, KeyError) as e:
            raise SystemExit(f"error: {clouds}: {e}") from None
    else:
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


def cmd_infer(args) -> int:
    """a ShapeAssembly program for a point cloud or a mesh

    Encode a point cloud (.ply .obj .xyz .npy) or a mesh (.obj .ply .stl .glb, sampled by area) with the trained
    point-cloud model, decode a program, optionally polish its numbers by fitting (--fit), and write into --out:
    <name>.txt (the program at the input's scale, in the power of ten of input units that keeps its numbers in the
    corpus's range: the json's unit), <name>.obj (its cuboids in the input's frame), <name>.png (input beside result)
    and <name>.json (offset, rotation, metrics).

    Example: pointcloud infer scan.ply --category chair --fit --out result/"""
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
    refuse_inputs(list(files.values()), [args.file])
    refuse_existing(files.values(), args.overwrite)
    points = read_cloud(src)
    search = args.search or bool(args.search_schedule)
    method = args.method or ("decode" if search or args.retrieval is not None else DEFAULT_METHOD)
    index = None
    if args.retrieval is not None or (method == "robust" and args.clouds):
        index = retrieval_index(args.category if model is None else model.category, args.clouds)
    elif args.clouds:
        raise SystemExit("error: --clouds is only used with --retrieval or the robust method")
    if method == "robust":
        candidates = args.candidates if args.candidates is not None else (args.retrieval or ROBUST_CANDIDATES)
    else:
        candidates = args.retrieval or RETRIEVAL_CANDIDATES
    try:
        schedule = parse_schedule(args.search_schedule) if args.search_schedule else None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", UpAxisWarning)
            r = infer(points, args.category, fit=args.fit, model=model, up=args.up, fit_steps=args.steps,
                      stability=args.stability, seed=args.seed, search=search, search_schedule=schedule,
                      retrieval=index, retrieval_candidates=candidates, method=method, subsets=args.subsets,
                      polish_steps=args.polish_steps, select=args.select, check_up=not args.no_up_check)
        for w in caught:  # the up-axis hint as one line; other warnings as they came
            if issubclass(w.category, UpAxisWarning):
                print(f"warning: {src}: {w.message}", file=sys.stderr)
            else:
                warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    except PointCloudError as e:
        raise SystemExit(f"error: {src}: {e}") from None
    except ValueError as e:
        raise SystemExit(f"error: {src}: {e}") from None
    out.mkdir(parents=True, exist_ok=True)
    items = inference_files(r, points, src, model, files, args)
    if args.overwrite:
        for path, data in items:
            atomic_write(path, data)
    else:
        write_new_set(items)  # all or none: no half result is left
    return print_inference(r, files)


def inference_files(r, points, src, model, files, args) -> list[tuple[Path, str | bytes]]:
    """``(path, content)`` of each file of ``infer``, in writing order."""
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
              "method": "robust" if r.robust is not None else "decode", "robust": r.robust, "up_scores": r.up_scores,
              "seconds": r.seconds,
              "macro_text": r.macro_text,
              "note": "the program's executed points p lie on the input at (p * unit) @ rotation + offset; metrics "
                      "are in canonical units (bounding-box diagonal 2)"}
    out.append((files["json"], json.dumps(record, indent=1) + "\n"))
    return out


def print_inference(r, files) -> int:
    if r.robust is not None:
        b = r.robust
        kept = f"the training program {b['chosen']}" if b.get("chosen") else "a decoded program"
        polish = "" if b.get("polished") is None else f", polished to F {b['polished'][0]:.1f}"
        print(f"robust: {b['decoded']} decoded and {b['retrieved']} retrieved candidates; kept {kept} "
              f"(F@{FSCORE_THRESHOLD:g} {b['score'][0]:.1f} against {SELECT_POINTS} input points{polish})")
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
        print(f"before fitting: {fmt_metrics(r.before)}")
    if r.fit_stopped is not None:
        print(f"fitting: {r.fit_stopped}")
    print(("after fitting:  " if r.before is not None else "") + fmt_metrics(r.metrics))
    print(f"wrote {files['program']}, {files['mesh']}, {files['png']} and {files['json']} "
          f"(offset {np.round(r.offset, 4).tolist()}" + ("" if r.unit == 1 else f", unit {r.unit:g}") + ")")
    if "macros" in files and r.macro_text is not None:
        print(f"wrote {files['macros']}: the decoded macro program (library calls; in the decoder's frame, before "
              f"alignment and fitting; {files['program']} is its expansion in the input's frame)")
    return 0


def cmd_tables(args) -> int:
    """the papers' point-cloud reconstruction tables on the test split

    Measure the point-cloud model (no fitting, Opt Program, Opt Cuboids) and the retrieval baseline on the test split of
    a make-clouds cache (noisy 2,048-point inputs in random scale and position) and write the ShapeMOD Table 3 and
    ShapeAssembly Table 7 layouts as Markdown.

    Example: pointcloud tables --category chair --clouds clouds --limit 20 --out pointcloud_chair.md"""
    refuse_inputs([args.out, args.json], [args.weights])
    refuse_existing([args.out, args.json], args.overwrite)

    def progress(done, total):
        if not args.quiet and (done % 10 == 0 or done == total):
            print(f"{done}/{total} shapes", file=sys.stderr, flush=True)

    with worker_pool(args.workers, "spawn") as executor:
        result = evaluate(args.clouds, args.category, weights=args.weights, limit=args.limit, steps=args.steps,
                          stability=not args.no_stability, retrieval=not args.no_retrieval, executor=executor,
                          seed=args.seed, progress=progress, search=args.search, augmented=args.augmented)
    command = command_line(args)
    path = write_tables(result, args.out, command)
    for row, m in result.rows.items():
        print(f"{row}: {m}")
    print(f"wrote {args.out}")
    write_json(args, markdown_result(Path(path).read_text(encoding="utf-8"),
                                     f"point-cloud reconstruction ({args.category}, test split)", command))
    return 0


def cmd_make_clouds(args) -> int:
    """sample point clouds of a category's corpus shapes into a cache

    Sample area-weighted surface points of every executed program of a category into <out>/<category>_clouds.npz, and
    write the train / val / test split (val: a seeded carve-out of the corpus train split; test: the corpus val split)
    to <out>/<category>_split.json. A program that fails is reported and skipped. An existing cache is never replaced
    (remove it, or choose another --out).

    Example: pointcloud make-clouds --category chair --points 10000 --workers 2 --out clouds"""
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise SystemExit(f"error: {args.out}: not a folder")
    refuse_existing(cache_paths(args.out, args.category),
                    hint="an expensive cache is never replaced: remove it, or choose another --out")
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


def export_cloud_weights(checkpoint: str, out: str, half: bool = True) -> Path:
    """Write the model of a point-cloud training checkpoint (configs/pointcloud/) as the file that `pointcloud infer
    --weights` and shapeprog.pointcloud.load_model read."""
    # the training module imports Lightning, needed only to read a training checkpoint
    from .train import export_weights  # lazy: the training module brings Lightning

    return export_weights(checkpoint, out, half=half)


def register(sub) -> None:
    """Add the ``pointcloud`` commands to ``sub``."""
    i = add_command(sub, "infer", cmd_infer, outputs={"out": "folder"})
    i.add_argument("file", help="point cloud or mesh file")
    add_category(i, help="the shipped model to use")
    i.add_argument("--weights", help="a point-cloud weights file instead of the shipped one")
    i.add_argument("--fit", action="store_true", help="polish the program's numbers against the cloud")
    i.add_argument("--steps", type=int_at_least(0), default=150, help="fitting steps (with --fit)")
    i.add_argument("--search", action="store_true",
                   help="latent search: decode 96 more codes around the predicted one and keep the program closest "
                        "to the cloud (about 1 s; before --fit)")
    i.add_argument("--search-schedule", metavar="N:SIGMA,...",
                   help="the search's steps, e.g. 16:0.75,16:0.5, or 'quick' (5 decodes; with --retrieval), 'fast' "
                        "(17 decodes, about 4.5x a plain decode's time) or 'default' (implies --search)")
    i.add_argument("--retrieval", nargs="?", type=int_at_least(1), const=0, metavar="K",
                   help="retrieval-augmented decoding (ours, not the papers'): the decoded program competes with the K "
                        "training programs nearest to the cloud (without K: the constant RETRIEVAL_CANDIDATES of "
                        "shapeprog/pointcloud/infer.py); the one closest to the cloud is kept. Give the file before "
                        "--retrieval: a file right after it is read as K")
    i.add_argument("--clouds", metavar="DIR",
                   help="with --retrieval: a make-clouds folder whose training clouds make the index (else it is "
                        "sampled from the corpus, about 20 s for chairs)")
    i.add_argument("--method", choices=METHODS,
                   help=f"robust (the default): {ROBUST_SUBSETS} encoder subsets decoded and the training programs "
                        "nearest to the cloud compete, the best against the input is kept and polished; decode: the "
                        "papers' single decode (the default when --search or --retrieval is given)")
    i.add_argument("--subsets", type=int_at_least(1, 64), default=ROBUST_SUBSETS,
                   help="robust method: encoder subsets decoded")
    i.add_argument("--candidates", type=int_at_least(0, 1000), default=None,
                   help=f"robust method: training programs that compete (0: none; default {ROBUST_CANDIDATES}; the "
                        f"index is built from the corpus on the first run of a machine, then cached)")
    i.add_argument("--polish-steps", type=int_at_least(0, 10_000), default=POLISH_STEPS,
                   help="robust method: fitting steps of the final polish (kept only when it helps)")
    i.add_argument("--select", choices=("fscore", "chamfer"), default="fscore",
                   help="robust method: how candidates are compared with the input")
    i.add_argument("--up", default="y", choices=("y", "z", "x", "-y", "-z", "-x", "auto"),
                   help="the input's up axis; auto: the orientation closest to the category's training shapes")
    i.add_argument("--no-up-check", action="store_true",
                   help="robust method: do not compare the other up axes (a warning names --up when one fits "
                        "clearly better)")
    i.add_argument("--stability", action="store_true",
                   help="also run the physics stability test of the result (about 0.5 s per cloud)")
    i.add_argument("--no-stability", action="store_true",
                   help="no stability test: the default, kept for older command lines (see --stability)")
    i.add_argument("--size", type=int_at_least(8, MAX_PICTURE_SIZE), default=256, help="picture cell size in pixels")
    add_seed(i, "seed of the point subsets")
    i.add_argument("--out", required=True, help="output folder (created if missing)")
    add_overwrite(i)
    pt = add_command(sub, "tables", cmd_tables, outputs={"out": "file", "json": "file"})
    add_category(pt)
    pt.add_argument("--clouds", required=True, help="the make-clouds folder")
    pt.add_argument("--weights", help="a point-cloud weights file (default: the shipped model)")
    pt.add_argument("--limit", type=int_at_least(1), help="the first N test shapes only")
    pt.add_argument("--steps", type=int_at_least(0), default=150, help="fitting steps of the optimisation rows")
    pt.add_argument("--no-stability", action="store_true", help="skip the stability test")
    pt.add_argument("--no-retrieval", action="store_true", help="leave out the retrieval row")
    pt.add_argument("--search", action="store_true", help="also measure the latent-search rows (ours, not the papers')")
    pt.add_argument("--augmented", action="store_true",
                    help="also measure the retrieval-augmented decoding rows (ours, not the papers')")
    add_workers(pt, "processes for the per-shape work")
    add_seed(pt, "seed of the inputs' noise, subsets, scales and positions")
    add_quiet(pt, "progress lines")
    pt.add_argument("--out", required=True, help="Markdown file (e.g. docs/tables/pointcloud_chair.md)")
    add_json(pt, "the tables")
    add_overwrite(pt)
    m = add_command(sub, "make-clouds", cmd_make_clouds, outputs={"out": "folder"})
    add_category(m, help="the corpus category")
    m.add_argument("--out", required=True, help="the cache folder (created if missing)")
    m.add_argument("--points", type=int_at_least(1, MAX_POINTS), default=10000,
                   help="points per shape (the papers' 10,000)")
    add_workers(m, "processes (default: the CPU count; 1: none)", default=None)
    add_seed(m, "sampling seed (each shape's seed is a hash of category, id and this)")
    m.add_argument("--val-fraction", type=float_in(0, 1, high_open=True), default=0.05,
                   help="share of the corpus train split carved out for validation")
    add_seed(m, "seed of the validation carve-out", flag="--split-seed")
    m.add_argument("--dtype", choices=("float16", "float32"), default="float16",
                   help="storage type of the points (float16: half the size, within 5e-4)")
    m.add_argument("--limit", type=int_at_least(1), help="only the first N shapes of the corpus train and val "
                                                         "splits (a quick check)")
    add_quiet(m, "progress bar")
    add_export_weights(sub, export_cloud_weights,
                       help="write a point-cloud training checkpoint as a small weights file",
                       example="pointcloud export-weights runs/pc_chair/checkpoints/last.ckpt --out pc_chair.pt",
                       checkpoint_help="a .ckpt file written by `python train.py fit --config configs/pointcloud/...`")
