"""``python -m shapeprog vae ...``: sample, interpolate and reconstruct programs with the VAE, evaluate
generated programs (the generation tables), train the metrics' classifier, export trained weights.

"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch
from tqdm import tqdm

from shapeio import atomic_write, write_new
from shapeio.results import column
from shapeio.weights import load_payload

from .. import io
from ..cli import (DEFAULT_CATEGORY, add_category, add_command, add_export_weights, add_json, add_overwrite, add_quiet,
                   add_result_options, add_seed, add_workers, category_of, check_outputs, command_line, command_result,
                   emit_text, int_at_least, Program, progress_log, refuse_existing, refuse_inputs, worker_pool,
                   write_json, write_mesh)
from ..errors import ParseError
from ..execute import execute
from ..lang import parse
from ..limits import decode
from ..metrics import adaptive_threshold, chamfer, fscore
from ..picture import MAX_SIZE as MAX_PICTURE_SIZE
from ..picture import check_grid as check_picture_grid
from ..picture import render_grid
from ..sampling import sample_surface
from .decode import MAX_SAMPLES, MAX_TRIES
from .decode import decode as decode_latent
from .decode import encode, interpolate, sample
from .gentable import EVALUATE_TRIES, format_table, generation_result, generation_rows, train_category_classifier
from . import study_commands
from .macro_decode import sample_macro
from .macro_model import MacroVAE
from .pointnet import load_classifier, save_classifier, sha256_file
from .pretrained import export_weights, load_model, load_pretrained

WEIGHTS_HELP = "VAE weights file or Lightning checkpoint (default: the shipped model of the category)"


def load_vae(args, category: str | None, macro: bool = False):
    """The VAE of ``--weights`` or the shipped model of ``category`` (the input's; :data:`DEFAULT_CATEGORY`
    when None); a usage error when ``--weights`` is a model of macro programs and the command (``macro``
    False) reads ShapeAssembly programs."""
    try:
        if args.weights:
            vae = load_model(args.weights, category=args.category)
            if args.category is None and category is not None and vae.category != category:
                raise SystemExit(f"error: {args.weights}: a {vae.category} model, but the input is a {category} "
                                 f"program (give --category {vae.category} to use this model anyway)")
            if isinstance(vae, MacroVAE) and not macro:
                raise SystemExit(f"error: {args.weights} is a VAE over macro programs (ShapeMOD); this command reads "
                                 f"ShapeAssembly programs: use `vae sample` or `vae evaluate` with it")
            return vae
        return load_pretrained(category or DEFAULT_CATEGORY)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"error: {e}") from None


def planned_files(out: str | None, name: str, n: int) -> list[Path]:
    """The ``.txt`` and ``.obj`` files :func:`export_decoded` writes into ``out`` for ``n`` programs."""
    return [] if not out else [Path(out) / f"{name.format(i)}{s}" for i in range(n) for s in (".txt", ".obj")]


def check_grid(count: int, cols: int, size: int) -> None:
    """Stop before any work when a picture grid would exceed :data:`shapeprog.picture.MAX_GRID_PIXELS`."""
    try:
        check_picture_grid(count, cols, size)
    except ValueError as e:
        raise SystemExit(f"error: --png: {e}") from None


def export_decoded(results, out: str | None, name: str, png: str | None, cols: int, size: int,
                   progress: bool = False, overwrite: bool = False) -> None:
    """Write decoded programs: ``name.format(i)`` + ``.txt`` and ``.obj`` in ``out`` (none of which may exist
    yet unless ``overwrite``: the commands check :func:`planned_files` with :func:`refuse_existing` before their
    work, and the text files are written with ``write_new``), a picture grid ``png`` (``cols`` cells of ``size``
    pixels per row); print the programs when neither is given. Each program is executed once."""
    if not out and not png:
        for i, r in enumerate(results):
            print(f"# {name.split('_')[0]} {i}\n{r.text}")
        return
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
    write_text = atomic_write if overwrite else write_new
    shapes = []
    for i, r in enumerate(tqdm(results, desc="writing", unit="shape", disable=not progress)):
        with torch.no_grad():
            shape = execute(r.program)
        if out:
            write_text(Path(out) / f"{name.format(i)}.txt", r.text)
            io.write_obj(Path(out) / f"{name.format(i)}.obj", shape.corners, lines=shape.line)
        shapes.append((shape.corners, shape.line.numpy()))
    if out:
        print(f"wrote {len(results)} programs and meshes to {out}/")
    if png:
        render_grid(shapes, png, cols=cols, size=size)
        print(f"wrote {png}")


def sampling_report(results, max_tries: int, seconds: float) -> str:
    """How often :func:`shapeprog.vae.sample` was refused: first-draw and within-``max_tries`` shares, the
    refused share of all draws, and the rate."""
    n = len(results)
    draws = sum(min(r.tries, max_tries) for r in results)
    first = sum(r.tries == 1 for r in results)
    within = sum(r.tries <= max_tries for r in results)
    return (f"{100 * first / n:.1f} % valid on the first draw, {100 * within / n:.1f} % within {max_tries} draws, "
            f"{100 * (1 - within / max(draws, 1)):.1f} % of {draws} draws refused; sampling took {seconds:.1f} s "
            f"({n / seconds:.1f} samples/s)")


def draw(vae, n: int, seed: int, max_tries: int):
    """``n`` validity-checked samples of ``vae`` (macro programs for a ShapeMOD model)."""
    if isinstance(vae, MacroVAE):  # macro programs: written as macro text, executed through their expansion
        return sample_macro(vae, n, seed=seed, max_tries=max_tries)
    return sample(vae, n, seed=seed, max_tries=max_tries)


def cmd_sample(args) -> int:
    """generate programs with the VAE

    Sample latents from N(0, I) and decode them with semantic validity (rejection sampling); write programs, meshes and
    a picture grid.

    Example: vae sample --category chair -n 16 --seed 0 --out samples --png grid.png"""
    check_outputs(others=[args.png])
    if args.png:
        check_grid(args.n, args.cols, args.size)
    refuse_existing([*planned_files(args.out, "sample_{:04d}", args.n), args.png], args.overwrite)
    vae = load_vae(args, args.category, macro=True)
    t0 = time.perf_counter()
    results = draw(vae, args.n, args.seed, args.max_tries)
    seconds = time.perf_counter() - t0
    first = sum(r.tries == 1 for r in results)
    within = sum(r.tries <= args.max_tries for r in results)
    print(f"{args.n} samples of {vae.category} in {seconds:.1f} s ({args.n / seconds:.1f}/s): "
          f"{first} valid on the first try, {within} within {args.max_tries} tries")
    export_decoded(results, args.out, "sample_{:04d}", args.png, args.cols, args.size, progress=not args.quiet,
                   overwrite=args.overwrite)
    return 0


def cmd_interpolate(args) -> int:
    """decode shapes along the latent line between two programs

    Encode two programs, interpolate their latent means linearly and decode each step (both ends included).

    Example: vae interpolate chair/173 chair/44017 --steps 8 --png interp.png"""
    check_outputs(others=[args.png])
    a, b = Program(args.a), Program(args.b)
    planned = planned_files(args.out, "step_{:03d}", args.steps)
    refuse_inputs([args.png, *planned], [args.a, args.b])
    refuse_existing([*planned, args.png], args.overwrite)
    vae = load_vae(args, args.category or category_of(args.a) or category_of(args.b))
    results = interpolate(vae, a.program, b.program, args.steps)
    export_decoded(results, args.out, "step_{:03d}", args.png, len(results), args.size, overwrite=args.overwrite)
    return 0


def cmd_reconstruct(args) -> int:
    """encode a program and decode it back, with the F-score to the input

    Encode a program to its latent mean, decode it with semantic validity, and print the F-score and chamfer distance to
    the input shape.

    Example: vae reconstruct chair/173 -o recon.txt --json recon.json"""
    check_outputs([args.mesh], [args.out, args.png, args.json])
    prog = Program(args.program)
    outputs = [args.out, args.mesh, args.png, args.json]
    refuse_inputs(outputs, [args.program])
    refuse_existing(outputs, args.overwrite)
    vae = load_vae(args, args.category or category_of(args.program))
    result = decode_latent(vae, encode(vae, prog.program))
    figures = {"program": prog.name, "leaves": None, "input_leaves": None, "fscore": 0.0, "chamfer": None}
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
            figures.update(fscore=float(fscore(x, y, threshold=thr)), chamfer=float(chamfer(x, y)))
            score = f"F-score @{thr:.3g} {figures['fscore']:.1f}, chamfer {figures['chamfer']:.4f}"
    figures.update(leaves=len(shape), input_leaves=len(target))
    print(f"{prog.name}: reconstructed with {len(shape)} leaf cuboids (input {len(target)}), {score}")
    emit_text(args.out, result.text)
    if args.mesh:
        write_mesh(args.mesh, shape)
    if args.png:
        render_grid([(target.corners, target.line.numpy()), (shape.corners, shape.line.numpy())], args.png,
                    cols=2, size=args.size)
        print(f"wrote {args.png} (input, reconstruction)")
    write_json(args, command_result(
        args, "VAE reconstruction", [column("program", "program"), column("leaves", "leaf cuboids"),
                                     column("input_leaves", "input leaf cuboids"),
                                     column("fscore", f"F-score @{thr:.3g}", 1), column("chamfer", "chamfer", 4)],
        [figures], [f"weights: {args.weights or 'the shipped model'}; seed {args.seed}"]))
    return 0


def is_pointcloud_checkpoint(path: str) -> bool:
    """Whether ``path`` is a Lightning checkpoint of a :mod:`shapeprog.pointcloud.train` module."""
    try:
        payload = load_payload(path, "checkpoint")
    except (OSError, ValueError):  # unreadable: the exporter reports it, naming the file
        return False
    return isinstance(payload, dict) and "shapeprog_pointcloud" in payload


def export_vae_weights(checkpoints: list[str], out: str, half: bool = True) -> Path:
    """Write the VAE of a Lightning checkpoint (or weights file) as a weights file that --weights and
    shapeprog.vae.load_pretrained read (a point-cloud model's checkpoint: `pointcloud export-weights`).
    Several checkpoints of one run give the average of their weights (the shipped chair VAE averages the
    five-epoch checkpoints of configs/shapeassembly/vae_chair_kl.yaml)."""
    for checkpoint in checkpoints:
        if Path(checkpoint).is_file() and is_pointcloud_checkpoint(checkpoint):
            raise SystemExit(f"error: {checkpoint}: a checkpoint of a point-cloud model; export it with "
                             "`python -m shapeprog pointcloud export-weights`")
    return export_weights(checkpoints, out, half=half)


def read_programs(folder: str) -> list:
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


#: The decoding options of the paper's rules (its text: every cuboid within 1.1 times the bbox; an attach to the
#: bbox within 0.05 of its bottom or top) where the reference code has 1.5 times and snapping
#: (:class:`shapeprog.vae.validity.DecodeOptions`).
PAPER_DECODING = {"bbox_margin": 1.1, "bbox_attach": "tolerance"}


def vae_samples(args, vae=None, max_tries: int = EVALUATE_TRIES, paper_rules: bool = False) -> tuple[list, str, str]:
    """``-n`` programs sampled from the VAE (``--weights`` or the shipped model of ``args.category``), at most
    ``max_tries`` draws each (1: the No Reject ablation, a refused draw decoded without rejection), under the
    paper's decoding rules (:data:`PAPER_DECODING`) when ``paper_rules``; the row name and a line on how often
    sampling was refused."""
    vae = vae or load_vae(args, args.category, macro=True)
    options = PAPER_DECODING if paper_rules else {}
    if options and isinstance(vae, MacroVAE):
        raise SystemExit("error: --paper-decoding: the macro-program decoder has no such options; leave it out "
                         "with a ShapeMOD model")
    t0 = time.perf_counter()
    if options:
        results = sample(vae, args.n, seed=args.seed, max_tries=max_tries, **options)
    else:
        results = draw(vae, args.n, args.seed, max_tries)
    seconds = time.perf_counter() - t0
    where = args.weights or f"the shipped {args.category} model"
    meta = getattr(vae, "meta", {}) or {}
    epoch = f", epoch {meta['epoch']}" if "epoch" in meta else ""
    if max_tries == 1:
        how = "No Reject: one draw each, a refused draw decoded without rejection"
    else:
        how = f"rejection, at most {max_tries} draws each"
    rules = "; the paper's rules: bbox 1.1x, attach to bbox within 0.05 of its bottom or top" if options else ""
    name = f"VAE samples ({where}; {how}{rules})"
    line = (f"{name}: {len(results)} samples{epoch}, seed {args.seed}: "
            f"{sampling_report(results, max_tries, seconds)}. A sample refused {max_tries} times is decoded without "
            "rejection and kept."
            + (" The samples are macro programs; the metrics read their expansions (% novel compares those "
               "with the corpus's ShapeAssembly programs)." if isinstance(vae, MacroVAE) else "") + "\n\n")
    return [r.program for r in results], name, line


def cmd_evaluate(args) -> int:
    """the generation tables (Tables 2, 4, 5) of VAE samples or a folder of programs

    Measure generated programs with the ShapeAssembly paper's generation metrics (% rooted, % stable, % fool, FD, leaf
    parts, generalization, coverage, variety, % novel) against the corpus train split, beside the ground truth (the val
    split) and the paper's figures; print a markdown table.

    Example: vae evaluate --category chair table -n 300 --max-tries 10 1 --paper-decoding --json table.json"""
    check_outputs(others=[args.out, args.json])
    refuse_inputs([args.out, args.json], [args.classifier])
    refuse_existing([args.out, args.json], args.overwrite)
    categories = list(dict.fromkeys(args.category))
    if args.programs and args.n:
        raise SystemExit("error: give either --programs DIR or -n N (samples of the VAE), not both")
    if len(categories) > 1 and (args.programs or args.weights):
        raise SystemExit("error: --programs and --weights belong to one category: give one --category with them")
    if (args.paper_decoding or args.max_tries != [EVALUATE_TRIES]) and not args.n:
        raise SystemExit("error: --max-tries and --paper-decoding choose how VAE samples are decoded: give -n N")
    if not args.n and not args.programs and args.no_ground_truth:
        raise SystemExit("error: nothing to evaluate: give --programs or -n, or leave out --no-ground-truth")
    model = None
    if args.classifier:
        try:
            model = load_classifier(args.classifier)[0]
        except (FileNotFoundError, ValueError) as e:
            raise SystemExit(f"error: {e}") from None
    t0 = time.perf_counter()
    texts, tables, notes, sampling, papers = [], [], [], [], set()
    with worker_pool(args.workers, "spawn") as pool:
        for category in categories:
            one = argparse.Namespace(**{**vars(args), "category": category})
            header, sets, paper = "", [], "shapeassembly"
            if args.n:
                vae = load_vae(one, category, macro=True)
                paper = "shapemod" if isinstance(vae, MacroVAE) else "shapeassembly"
                decodings = [(k, False) for k in dict.fromkeys(args.max_tries)]
                if args.paper_decoding:
                    decodings.append((args.max_tries[0], True))
                for k, paper_rules in decodings:
                    samples, name, line = vae_samples(one, vae, k, paper_rules=paper_rules)
                    sets.append((name, samples))
                    header += line
                    sampling.append(line.strip())
            elif args.programs:
                sets.append((f"programs in {args.programs}", read_programs(args.programs)))
            rows, notes = generation_rows(
                sets, category, ground_truth=not args.no_ground_truth, executor=pool, model=model,
                stability=not args.no_stability, fool=not args.no_fool, fool_epochs=args.fool_epochs,
                fool_average_last=args.fool_average_last, fool_points=args.fool_points,
                candidates=args.candidates or None, seed=args.seed, log=progress_log(args))
            table = header + format_table(rows, category, notes, paper=paper)
            sys.stdout.write(table)
            texts.append(table)
            tables.append((category, rows))
            papers.add(paper)
    if args.out:
        atomic_write(args.out, "\n".join(texts))
        print(f"wrote {args.out} ({time.perf_counter() - t0:.0f} s)")
    write_json(args, generation_result(tables, [*sampling, *notes], command_line(args), paper=papers.pop()))
    return 0


def cmd_train_classifier(args) -> int:
    """train the PointNet classifier of the generation metrics

    Train the chair / table / storage PointNet classifier on the corpus train split; print its val accuracy; write its
    weights and their SHA-256.

    Example: vae train-classifier --out runs/pointnet_cls.pt"""
    check_outputs(others=[args.out, args.json])
    refuse_existing([args.out, args.json], args.overwrite)
    log = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    model, meta = train_category_classifier(epochs=args.epochs, per_class=args.per_class, points=args.points,
                                            finetune_epochs=args.finetune_epochs, seed=args.seed, log=log)
    save_classifier(args.out, model, meta["categories"], meta)
    per = ", ".join(f"{c} {a:.1f}" for c, a in meta["val_accuracy_per_category"].items())
    print(f"val accuracy {meta['val_accuracy']:.2f} % ({per}); trained in {meta['train_seconds']:.0f} s")
    print(f"wrote {args.out}, SHA-256 {sha256_file(args.out)}")
    rows = [{"category": c, "accuracy": float(a)} for c, a in meta["val_accuracy_per_category"].items()]
    rows.append({"category": "all", "accuracy": float(meta["val_accuracy"])})
    write_json(args, command_result(args, "PointNet category classifier: val accuracy (%)",
                                    [column("category", "category"), column("accuracy", "val accuracy (%)", 2)], rows,
                                    [f"weights {args.out}, SHA-256 {sha256_file(args.out)}; trained in "
                                     f"{meta['train_seconds']:.0f} s"]))
    return 0


def register(sub) -> None:
    """Add the ``vae`` commands to ``sub``."""
    g = add_command(sub, "sample", cmd_sample, outputs={"out": "folder"})
    add_category(g, from_input="the --weights model", help="the shipped model to use")
    g.add_argument("-n", type=int_at_least(1, MAX_SAMPLES), default=16, help=f"number of samples (1 to {MAX_SAMPLES})")
    add_seed(g, "seed of the latents (an integer)")
    g.add_argument("--max-tries", type=int_at_least(1, MAX_TRIES), default=10,
                   help="draws per sample before giving up rejection")
    g.add_argument("--out", help="folder for sample_NNNN.txt and sample_NNNN.obj (without it and --png: printed)")
    g.add_argument("--png", help="picture grid of the samples (.png)")
    g.add_argument("--cols", type=int_at_least(1), default=4, help="grid columns")
    g.add_argument("--size", type=int_at_least(8, MAX_PICTURE_SIZE), default=192, help="grid cell side in pixels")
    g.add_argument("--weights", help=WEIGHTS_HELP)
    add_quiet(g, "progress bar")
    add_overwrite(g)
    i = add_command(sub, "interpolate", cmd_interpolate, outputs={"out": "folder"})
    i.add_argument("a", help="the first program: " + "corpus id (chair/173) or a program file")
    i.add_argument("b", help="the last program: " + "corpus id (chair/44017) or a program file")
    i.add_argument("--steps", type=int_at_least(2), default=8, help="shapes along the line, ends included (>= 2)")
    add_category(i, from_input="the first corpus id", help="model category")
    i.add_argument("--out", help="folder for step_NNN.txt and step_NNN.obj")
    i.add_argument("--png", help="picture strip of the steps (.png)")
    i.add_argument("--size", type=int_at_least(8, MAX_PICTURE_SIZE), default=160, help="cell side in pixels")
    i.add_argument("--weights", help=WEIGHTS_HELP)
    add_overwrite(i)
    c = add_command(sub, "reconstruct", cmd_reconstruct, outputs={"out": "file", "json": "file"})
    c.add_argument("program", help="corpus id (chair/173) or a program file")
    add_category(c, from_input="the corpus id", help="model category")
    c.add_argument("-o", "--out", help="reconstructed program file (without it: printed)")
    c.add_argument("--mesh", help="also write the reconstructed shape: .obj, .ply or .glb")
    c.add_argument("--png", help="picture of the input beside the reconstruction (.png)")
    c.add_argument("--size", type=int_at_least(8, MAX_PICTURE_SIZE), default=256, help="cell side in pixels")
    add_seed(c, "seed of the surface samples of the F-score")
    c.add_argument("--weights", help=WEIGHTS_HELP)
    add_result_options(c, "the F-score and chamfer distance", quiet=None)
    e = add_command(sub, "evaluate", cmd_evaluate, outputs={"out": "file", "json": "file"})
    add_category(e, multiple=True, help="the categories (one table each; --programs and --weights: one)")
    e.add_argument("--programs", help="folder of program files (*.txt, one program each); without it and -n, the "
                                      "ground-truth row alone")
    e.add_argument("-n", type=int_at_least(1, MAX_SAMPLES), help="evaluate N samples of the VAE (the shipped model "
                                                                 "of the category, or --weights) instead of a folder")
    e.add_argument("--weights", help=WEIGHTS_HELP)
    e.add_argument("--max-tries", type=int_at_least(1, MAX_TRIES), nargs="+", default=[EVALUATE_TRIES],
                   metavar="K", help=f"with -n: draws per sample before a sample is decoded without rejection; "
                                     f"several give one row each (1: the No Reject ablation; default "
                                     f"{EVALUATE_TRIES})")
    e.add_argument("--paper-decoding", action="store_true",
                   help="with -n: one more row decoded under the paper's rules (cuboids within 1.1x the bbox, "
                        "attach to the bbox within 0.05 of its bottom or top; the code: 1.5x and snapping)")
    e.add_argument("--classifier", help="PointNet weights for FD and the features (a train-classifier output; "
                                        "default: the shipped shapeprog/weights/pointnet_cls.pt)")
    e.add_argument("--out", help="also write the table to this markdown file")
    add_json(e, "the table")
    e.add_argument("--no-ground-truth", action="store_true", help="leave out the ground-truth (val split) row")
    e.add_argument("--no-stability", action="store_true", help="skip the stability test (about 0.5 s per shape)")
    e.add_argument("--no-fool", action="store_true", help="skip %% fool (trains a PointNet per row)")
    e.add_argument("--fool-epochs", type=int_at_least(1), default=12, help="%% fool training epochs (paper: 300)")
    e.add_argument("--fool-average-last", type=int_at_least(1), default=4, help="%% fool: epochs averaged at the end")
    e.add_argument("--fool-points", type=int_at_least(16), default=512, help="%% fool: points per shape")
    e.add_argument("--candidates", type=int_at_least(0), default=16,
                   help="shapes measured exactly per nearest-chamfer search (0: every pair)")
    add_workers(e, "processes for the per-shape work")
    add_seed(e, "seed of the sampling and of the %% fool training")
    add_quiet(e, "progress lines on stderr")
    add_overwrite(e)
    study_commands.register(sub)
    t = add_command(sub, "train-classifier", cmd_train_classifier, outputs={"out": "file+", "json": "file"})
    t.add_argument("--out", required=True, help="weights file (.pt)")
    t.add_argument("--epochs", type=int_at_least(1), default=10, help="epochs on point subsets")
    t.add_argument("--per-class", type=int_at_least(1), default=500, help="shapes per category and epoch")
    t.add_argument("--points", type=int_at_least(16), default=512, help="points per shape and visit")
    t.add_argument("--finetune-epochs", type=int_at_least(0), default=1, help="final epochs on all 2,500 points")
    add_seed(t, "seed of the sampling and the training")
    add_result_options(t, "the val accuracy", quiet="training log")
    add_export_weights(sub, export_vae_weights, help="write a VAE training checkpoint as a small weights file",
                       example="vae export-weights runs/vae_chair/checkpoints/last.ckpt --out vae_chair.pt",
                       checkpoint_help="a .ckpt file written by `python train.py fit --config "
                                       "configs/shapeassembly/...`", average=True)
