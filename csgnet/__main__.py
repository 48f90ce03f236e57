"""Command line of csgnet: a thin layer over the library.

    python -m csgnet render "c(32,32,28)s(32,32,20)-" -o out.png      (.png, .obj, .scad, .npy)
    python -m csgnet render "sp(32,32,32,20)cu(32,32,32,28)*" --dim 3 -o out.obj
    python -m csgnet generate --dim 2 --scale 0.001 --out data/synthetic --workers 2
    python -m csgnet demo --out demo_output
    python -m csgnet parse examples/house.png examples/snowman.stl --beam 10 --out parse_output
    python -m csgnet evaluate --dim 2 --data data/synthetic --weights csgnet/weights/csgnet2d.pt --out table.md
    python -m csgnet export-weights runs/x/checkpoints/best-012.ckpt --out csgnet/weights/csgnet2d.pt
    python -m csgnet table4 --weights "CSGNet RL=runs/rl.pt" csgnet/weights/csgnet2d.pt --images 50 --out table4.md
    python -m csgnet table6 --data data/synthetic --weights csgnet/weights/csgnet2d.pt --out table6.md
    python -m csgnet edit "c(32,32,28)s(32,32,20)-" --port 8081 --no-browser
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from pathlib import Path

import numpy as np

from shapeio import atomic_write, refuse_overwrite
from shapeio.image import write_png

from . import export, render
from .lang import ParseError, is_valid, parse
from .primitives import primitives
from .shapes2d import load_silhouettes
from .vocab import vocabulary

# The modules that import torch or Lightning (data, inference, refinement, paper, train) are imported
# inside the commands that need them, so that `--help` and `render` start without loading torch.


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
    try:
        program = parse(args.program, args.dim)
    except ParseError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    img = render(program, args.dim)[0]
    print(f"{program.text()}  ({len(program)} tokens, {int(img.sum())} {'pixels' if args.dim == 2 else 'voxels'} on)")
    for out in args.output:
        try:
            path = _write_render(program, args.dim, Path(out))
        except (OSError, ValueError) as e:
            print(f"error: {_located(out, e)}", file=sys.stderr)
            return 2
        print(f"wrote {path}")
    return 0


def cmd_generate(args) -> int:
    from .data import generate_dataset

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
    from .data import generate_dataset, load_dataset

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
        _save_sheet(_contact_sheet(images, cols=6 if dim == 2 else 2), sheet_path)
        print(f"wrote {sheet_path} ({len(lines)} programs; texts in {preview / 'programs.tsv'})")
    print(f"done: {out}")
    return 0


def _named(stem: Path, end: str) -> Path:
    """``stem`` with ``end`` appended (``a.v1`` -> ``a.v1.png``; ``with_suffix`` would give ``a.png``, another
    shape's name)."""
    return stem.with_name(stem.name + end)


def _output_stems(inputs, out: Path) -> list[Path]:
    """One output stem per input under ``out``: the input's stem, or ``stem_2``, ``stem_3``, ... when
    an earlier input (or another input's own stem) already has that name, compared case-insensitively."""
    natural = [Path(src).stem for src in inputs]
    taken: set = set()
    stems = []
    for i, stem in enumerate(natural):
        others = {n.casefold() for j, n in enumerate(natural) if j != i}
        name, k = stem, 2
        while name.casefold() in taken or (name != stem and name.casefold() in others):
            name, k = f"{stem}_{k}", k + 1
        taken.add(name.casefold())
        stems.append(out / name)
    return stems


def _located(src, err: Exception) -> str:
    """``FILE: reason`` for an error about ``src`` (messages that already start with a path are kept)."""
    msg = str(err)
    return msg if msg.startswith(str(src)) else f"{src}: {msg}"


def _parse_models(args) -> dict:
    """The models ``parse`` uses, by dimension: a weights file given with ``--weights-2d`` / ``--weights-3d``
    is loaded now, so that a bad one is reported once, before any input; the shipped models (``--model``,
    default the strongest of each dimension) are loaded when an input of their dimension comes."""
    from .inference import load_model

    models: dict = {}
    for dim, weights in ((2, args.weights_2d), (3, args.weights_3d)):
        if weights:
            model = load_model(weights)
            if model.config.dim != dim:
                raise ValueError(f"{weights}: a {model.config.dim}D model, given for {dim}D inputs (--weights-{dim}d)")
            models[dim] = model
    return models


def _parse_model(models: dict, dim: int, kind: str | None):
    """The ``dim``-D model (a shipped one loaded once; a failure is kept and raised again for every input)."""
    from .inference import load_pretrained

    if dim not in models:
        try:
            models[dim] = load_pretrained(dim, kind=kind)
        except (ValueError, OSError) as e:
            models[dim] = e
    if isinstance(models[dim], Exception):
        raise models[dim]
    return models[dim]


def _scores_line(iou: float, chamfer: float, program) -> str:
    line = f"IoU {100 * iou:.2f}%" + ("" if np.isnan(chamfer) else f", chamfer {chamfer:.3f} px")
    return line + f", {len(program.draws) if program is not None else 0} primitives"


def _parse_one(src, shape: np.ndarray, stem: Path, model, args, frame=None) -> dict:
    """Infer, optionally refine, report and write one input's program (``parse``: one
    :func:`csgnet.inference.parse_shape`); returns its record for the results file."""
    from .inference import parse_shape

    dim = shape.ndim
    parsed = parse_shape(shape, model=model, beam=args.beam, select=args.select, refine=args.refine,
                         rule=args.refine_rule, refine_iters=args.refine_iters, constrained=not args.unconstrained)
    res, ref, program = parsed.decoded, parsed.refined, parsed.program
    line = f"{src}: {res.text}\n  log-probability {res.score:.3f}, IoU {100 * res.iou:.2f}%"
    if dim == 2:
        line += f", chamfer {res.chamfer:.3f} px"
    if not res.valid:
        line += " (invalid program: renders empty)"
    print(line)
    record = {"input": str(src), "decoded": res.text, "valid": bool(res.valid), "iou": float(res.iou),
              "chamfer": None if dim == 3 else float(res.chamfer),
              "primitives": len(res.program.draws) if res.valid else 0}
    if ref is not None:
        from .refinement import MAX_IOU_DROP

        (i0, c0), (i1, c1) = ref.before, ref.after
        what = {"short": "IoU - %g per primitive" % _penalty(dim), "guarded": "guarded", "chamfer": "chamfer"}
        n = sum(_is_valid(b, dim) for b in res.beams)
        print(f"  refined ({n} beams, by {'IoU' if dim == 3 else 'chamfer'}; chosen by "
              f"{what[ref.rule]}): {program.text()}\n"
              f"  before: {_scores_line(i0, c0, res.program)}; "
              f"after: {_scores_line(i1, c1, program)}")
        if ref.kept_start and ref.rule == "guarded":
            print(f"  refinement lowered IoU by more than {100 * MAX_IOU_DROP:g} points: "
                  f"wrote the unrefined program {program.text()}")
        record.update(refined=program.text(), rule=ref.rule, iou_refined=float(i1),
                      chamfer_refined=None if dim == 3 else float(c1), primitives_refined=len(program.draws))
    stem.parent.mkdir(parents=True, exist_ok=True)
    txt = atomic_write(_named(stem, ".txt"), (res.text if program is None else program.text()) + "\n")
    img = np.zeros((64,) * dim, dtype=bool) if program is None else render(program, dim)[0]
    if dim == 2:
        compare = stem.with_name(stem.name + "_compare.png")
        written = [export.save_png(img, _named(stem, ".png")), compare]
        _save_sheet(_contact_sheet([shape, img], cols=2), compare)
    else:
        compare = stem.with_name(stem.name + "_compare.png")
        written = [export.save_obj(img, _named(stem, ".obj"), transform=frame), compare]
        _save_sheet(_contact_sheet([depth_view(shape, a) for a in range(3)]
                                   + [depth_view(img, a) for a in range(3)], cols=3), compare)
    if program is not None:
        written.append(export.save_scad(program, _named(stem, ".scad"), transform=frame))
    print("  wrote " + ", ".join(str(w) for w in written + [txt]))
    return record


def _penalty(dim: int) -> float:
    from .rewrite import LENGTH_PENALTY

    return LENGTH_PENALTY[dim]


def _results_path(out: Path) -> Path:
    """``out/results.json``, or ``results_2.json``, ... : the first name not taken (never overwritten)."""
    path, k = out / "results.json", 2
    while path.exists():
        path, k = out / f"results_{k}.json", k + 1
    return path


def cmd_parse(args) -> int:
    """Infer a program for each input shape with a trained model; a bad input is reported and skipped."""
    from shapeio import InputError

    from .inference import load_shape_framed

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        print(f"error: {out}: --out must be a folder, and this is a file", file=sys.stderr)
        return 2
    stems = _output_stems(args.inputs, out)
    outputs = [stem.with_name(stem.name + end) for stem in stems
               for end in (".txt", ".png", "_compare.png", ".obj", ".scad")]
    try:
        refuse_overwrite(outputs, args.inputs)
    except FileExistsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        models = _parse_models(args)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    status = 0
    records = []
    for src, stem in zip(args.inputs, stems):
        try:
            shape, frame = load_shape_framed(src)  # a mesh's outputs are written in its own units
            model = _parse_model(models, shape.ndim, args.model)
            records.append(_parse_one(src, shape, stem, model, args, frame))
        except (InputError, ParseError, ValueError, OSError) as e:
            print(f"error: {_located(src, e)}", file=sys.stderr)
            records.append({"input": str(src), "error": _located(src, e)})
            status = 2
    if out.is_dir():
        results = _results_path(out)
        atomic_write(results, json.dumps(records, indent=1) + "\n")
        print(f"results of the {len(records)} inputs: {results}")
    return status


def _is_valid(text: str, dim: int = 2) -> bool:
    try:
        return bool(text) and is_valid(parse(text, dim))
    except ParseError:
        return False


def cmd_evaluate(args) -> int:
    from .data import load_dataset
    from .paper.tables import evaluate_model, markdown_tables, nearest_neighbour

    _refuse_table_over_inputs(args)
    tests = load_dataset(args.data, args.dim, "test", args.lengths, errors="raise")
    tests = {L: p[: args.per_length] for L, p in tests.items()}
    rows = []
    if args.nn_train != 0:
        train = [p for L, ps in sorted(load_dataset(args.data, args.dim, "train", args.lengths).items()) for p in ps]
        if args.nn_train > 0:
            train = train[: args.nn_train]
        print(f"nearest neighbour over {len(train)} training programs ...", flush=True)
        rows.append(nearest_neighbour(train, tests, args.dim))
    for name, model in _labelled_models(args.weights, args.dim):
        if model.config.dim != args.dim:
            raise SystemExit(f"error: {name} is a {model.config.dim}D model, not {args.dim}D")
        print(f"decoding with {name} ...", flush=True)
        rows += evaluate_model(model, tests, tuple(args.beams), name=name, mode=args.mode,
                               constrained=args.constrained)
        if args.refined:
            from .paper.tables import evaluate_refined

            print(f"parsing with refinement ({name}, {args.refined} per length) ...", flush=True)
            rows.append(evaluate_refined(model, tests, max(args.beams), name=name, per_length=args.refined))
    note = f"`{_command(args)}`; beam mode {args.mode!r}, {_decoding(args)}; {_measured_on()}."
    if args.out and str(args.out).endswith(".json"):
        from shapeio.results import markdown, write_result

        from .paper.tables import table_result

        result = table_result(rows, args.dim, [f"Beam mode {args.mode!r}, {_decoding(args)}; {_measured_on()}."],
                              _command(args))
        print(markdown(result))
        print(f"wrote {write_result(args.out, result)}")
        return 0
    _write_table(markdown_tables(rows, args.dim, note), args.out)
    return 0


def cmd_export_weights(args) -> int:
    from .inference import export_weights

    if not Path(args.checkpoint).is_file():
        print(f"error: {args.checkpoint}: no such checkpoint file", file=sys.stderr)
        return 2
    try:
        refuse_overwrite([args.out], [args.checkpoint])
        path = export_weights(args.checkpoint, args.out, half=not args.float32)
    except ValueError as e:  # read_checkpoint names the file and what is wrong with it
        print(f"error: {e}; `export-weights` reads the .ckpt files that training writes", file=sys.stderr)
        return 2
    except FileExistsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"error: {_located(args.out, e)}", file=sys.stderr)
        return 2
    print(f"wrote {path} ({path.stat().st_size / 2**20:.2f} MiB)")
    return 0


def _labelled_models(specs, dim: int = 2):
    """``(label, model)`` per ``[LABEL=]PATH`` spec; the shipped ``dim``-D model when there is none."""
    from .inference import load_model, load_pretrained

    def kind(model) -> str:
        return "CSGNetStack" if model.config.stack else "CSGNet"

    if not specs:
        model = load_pretrained(dim)
        return [(f"{kind(model)} (shipped)", model)]
    out = []
    for spec in specs:
        label, sep, path = spec.rpartition("=")
        model = load_model(path)
        out.append((label if sep else f"{kind(model)} ({Path(path).name})", model))
    return out


def _command(args) -> str:
    """The command line that ran, for the notes under written tables."""
    return "python -m csgnet " + shlex.join(args.argv)


def _decoding(args) -> str:
    """How the written tables' programs were decoded, for their notes."""
    return f"{'grammar-constrained' if args.constrained else 'unconstrained'} decoding"


def _measured_on() -> str:
    """Where and when the written tables' times were measured, for their notes."""
    import datetime
    import platform

    import torch

    n = torch.get_num_threads()
    where = (f"{platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}, {n} thread{'s' if n != 1 else ''}"
             f"{', CUDA available' if torch.cuda.is_available() else ''}")
    return f"times measured on {where}, {datetime.date.today().isoformat()} (the load of other jobs is not recorded)"


def _refuse_table_over_inputs(args) -> None:
    """Stop before any work when a table's ``--out`` is one of its input files (weights, silhouettes)."""
    if not getattr(args, "out", None):
        return
    weights = getattr(args, "weights", None) or []
    inputs = [w.rpartition("=")[2] for w in ([weights] if isinstance(weights, str) else weights)]
    inputs += [getattr(args, "silhouettes", None)]
    try:
        refuse_overwrite([args.out], [p for p in inputs if p and Path(p).is_file()])
    except FileExistsError as e:
        raise SystemExit(f"error: {e}") from None


def _write_table(text: str, out) -> None:
    print(text)
    if out:
        atomic_write(out, text, mkdir=True)
        print(f"wrote {out}")


# The shipped CSGNet and small CSGNetStack (csgnetstack2d.pt, the starting point of the RL run), supervised and
# RL-tuned on the silhouettes (docs/csgnet.md says how each was trained): Table 4's rows when no --weights
# are given. The medium CSGNetStack (load_pretrained(2, kind="csgnetstack")) is added with --weights.
TABLE4_MODELS = (("CSGNet supervised", "csgnet2d.pt"), ("CSGNet RL", "rl_csgnet2d.pt"),
                 ("CSGNetStack supervised", "csgnetstack2d.pt"), ("CSGNetStack RL", "rl_csgnetstack2d.pt"))


def cmd_table4(args) -> int:
    from .inference import WEIGHTS
    from .paper.protocols import subset, table4, table4_markdown

    _refuse_table_over_inputs(args)
    test = load_silhouettes("test", args.silhouettes)
    idx = subset(len(test), None if args.images <= 0 else args.images, args.seed)
    train = None if args.no_nn else load_silhouettes("train", args.silhouettes)
    iters = [None if i in ("inf", "none") else int(i) for i in args.iterations]
    specs = args.weights or [f"{label}={WEIGHTS / name}" for label, name in TABLE4_MODELS]
    rows = table4(_labelled_models(specs), test[idx], train, tuple(args.beams), iters,
                  constrained=args.constrained, progress=lambda s: print(s, flush=True))
    note = (f"`{_command(args)}`; {len(idx)} of {len(test)} test silhouettes "
            f"(seed {args.seed}); {_decoding(args)}; {_measured_on()}.")
    _write_table(table4_markdown(rows, note, iters), args.out)
    return 0


def cmd_table6(args) -> int:
    from .paper.protocols import table6, table6_markdown

    _refuse_table_over_inputs(args)
    lengths = args.lengths or [3, 5, 7, 9, 11, 13]
    if args.data:
        from .data import load_dataset

        tests = load_dataset(args.data, 2, "test", lengths, errors="raise")
        programs = [p for L in sorted(tests) for p in tests[L][: args.per_length]]
        source = f"{args.data} (test split, {args.per_length} per length)"
    else:
        from .synth import sample_programs

        rng = np.random.default_rng(args.seed)
        vocab = vocabulary(2)
        programs = [vocab.decode(r) for L in lengths for r in sample_programs(2, L, args.per_length, rng)]
        source = f"sampled with seed {args.seed}, {args.per_length} per length"
    (label, model), = _labelled_models([args.weights] if args.weights else [])
    rows = table6(model, programs, tuple(args.beams), constrained=args.constrained,
                  progress=lambda s: print(s, flush=True))
    note = (f"`{_command(args)}`; {label}; targets: {source}, lengths "
            f"{', '.join(map(str, lengths))}; {_decoding(args)}; {_measured_on()}.")
    _write_table(table6_markdown(rows, note), args.out)
    return 0


def depth_view(vol, axis: int) -> np.ndarray:
    """A grey picture ``(64, 64) uint8`` of a voxel volume seen along ``axis`` (from index 0 on): each
    pixel's first occupied voxel, near dark and far light; white where the ray meets nothing."""
    vol = np.asarray(vol, dtype=bool)
    hit = vol.any(axis=axis)
    depth = np.argmax(vol, axis=axis).astype(np.float64) / max(vol.shape[axis] - 1, 1)
    return np.where(hit, np.round(30 + 170 * depth), 255).astype(np.uint8)


def _contact_sheet(images, cols: int = 6):
    """Images side by side in grey frames: bool images are drawn black on white, uint8 ones as grey levels."""
    h, w = images[0].shape
    rows = -(-len(images) // cols)
    sheet = np.full((rows * (h + 2), cols * (w + 2)), 128, np.uint8)  # grey frames
    for i, img in enumerate(images):
        r, c = divmod(i, cols)
        img = np.asarray(img)
        grey = img if img.dtype == np.uint8 else np.where(img, 0, 255)
        sheet[r * (h + 2) + 1: r * (h + 2) + 1 + h, c * (w + 2) + 1: c * (w + 2) + 1 + w] = grey
    return sheet


def _save_sheet(sheet, path: Path, scale: int = 3) -> None:
    write_png(path, sheet, scale=scale, mkdir=True)


def _beam_width(text: str) -> int:
    from .decode import check_beam  # csgnet.decode imports torch: loaded only when --beam is given

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    try:
        return check_beam(value, "the beam width")
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _non_negative(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}")
    return value


def cmd_edit(args) -> int:
    from shapeio.editing import editor_preflight, serve_until_interrupted

    from .editor import CSGEditSession

    problem = editor_preflight(args.export_dir)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 1
    text, name = args.program, "csg"
    path = Path(args.program)
    if path.is_file():  # a file holding a program (e.g. a parse result): its first non-blank line
        try:
            lines = [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]
        except UnicodeDecodeError as e:
            print(f"error: {path}: not UTF-8 text (byte offset {e.start})", file=sys.stderr)
            return 1
        if not lines:
            print(f"error: {path}: no program in the file", file=sys.stderr)
            return 1
        text, name = lines[0], path.stem
    if args.dim is None:
        args.dim = 3 if any(h + "(" in text for p in primitives(3) for h in (p.kind, p.long) if h) else 2
    session = CSGEditSession(text, args.dim, name=name)
    if session.error is not None:
        print(f"error: {session.error} (the page shows it; fix the text there)", file=sys.stderr)
    from .editor.server import CSGEditorApp

    app = CSGEditorApp(session, host=args.host, port=args.port, export_dir=args.export_dir, source_text=text)
    return serve_until_interrupted(app, repr(text), args.export_dir, not args.no_browser)


def build_parser() -> argparse.ArgumentParser:
    """The command line's parser, every sub-command with its options (``main`` runs what it parses)."""
    ap = argparse.ArgumentParser(prog="python -m csgnet", description="CSG programs: render, generate datasets, parse shapes, evaluate parsers.")
    sub = ap.add_subparsers(dest="cmd", required=True)

    r = sub.add_parser("render", help="render one program to .png (2D), .obj (3D), .npy or .scad")
    r.add_argument("program", help='program text, e.g. "c(32,32,28)s(32,32,20)-"')
    r.add_argument("-o", "--output", action="append", required=True,
                   help="output file, repeatable: .png (2D image), .obj (3D mesh), .npy (bool grid), .scad (OpenSCAD)")
    r.add_argument("--dim", type=int, choices=(2, 3), default=None, help="2 or 3 (default: guessed from the text)")
    r.set_defaults(func=cmd_render)

    g = sub.add_parser("generate", help="generate a synthetic dataset (train/val/test per length)")
    g.add_argument("--dim", type=int, choices=(2, 3), default=2, help="2D or 3D programs (default 2)")
    g.add_argument("--scale", type=float, default=0.001, help="fraction of the paper's Table 2 split sizes")
    g.add_argument("--seed", type=int, default=0, help="random seed; the files do not depend on --workers")
    g.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    g.add_argument("--lengths", type=int, nargs="*", default=None,
                   help="program lengths (default: all, 3..13 in 2D, 3..7 in 3D)")
    g.add_argument("--out", required=True, help="dataset folder (the DIMd/ sub-folder is written)")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    g.set_defaults(func=cmd_generate)

    d = sub.add_parser("demo", help="generate a small 2D and 3D dataset and preview some programs")
    d.add_argument("--out", default="demo_output", help="output folder (default demo_output/)")
    d.add_argument("--scale", type=float, default=0.0002, help="fraction of the paper's Table 2 split sizes")
    d.add_argument("--seed", type=int, default=0, help="random seed")
    d.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    d.add_argument("--per-length", type=int, default=2, help="previewed programs per length")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=cmd_demo)

    p = sub.add_parser("parse", help="infer programs for shapes (images, .npy grids, meshes)",
                       description="Infer a CSG program for each input shape and write, per input, "
                       "NAME.txt (the program), a render (NAME.png in 2D, NAME.obj in 3D), NAME_compare.png "
                       "(the input beside the result; in 3D depth views along x, y and z, input above, "
                       "result below) and NAME.scad into --out; for a mesh, NAME.obj and NAME.scad are in the mesh's "
                       "own units and overlay it. results.json (or results_2.json, ...) lists every input's "
                       "program, IoU, chamfer and primitives, before and after --refine. "
                       "Inputs with the same name get NAME_2, NAME_3, ...; "
                       "a command that would write over one of its inputs is refused. A file that cannot "
                       "be parsed is reported as 'error: FILE: reason' and the others are processed; the "
                       "exit status is 2 if any failed.")
    p.add_argument("inputs", nargs="+", metavar="FILE",
                   help="shape files: images .png .jpg .jpeg .bmp .gif .tif .tiff .webp (2D, at most "
                   "4096x4096 pixels), .npy arrays (2D or 3D, bool/int/float, at most 256^3 cells), meshes "
                   ".obj .ply .stl .off .glb .gltf (3D, at most 5,000,000 triangles)")
    p.add_argument("--beam", type=_beam_width, default=10, help="beam width, 1 (greedy) to 256 (default 10)")
    p.add_argument("--select", choices=("likelihood", "match"), default="likelihood",
                   help="report the most likely program, or the beam closest to the input")
    p.add_argument("--unconstrained", action="store_true", help="allow invalid programs while decoding")
    p.add_argument("--refine", action="store_true",
                   help="Powell refinement of every valid beam (by chamfer in 2D, by IoU in 3D)")
    p.add_argument("--refine-iters", type=_non_negative, default=None,
                   help="Powell iterations, 0 or more (default: to convergence)")
    p.add_argument("--refine-rule", choices=("short", "guarded", "chamfer"), default="short",
                   help="short: among the decoded program and every refined beam, each also pruned, the "
                   "highest IoU minus a price per primitive (csgnet.rewrite.LENGTH_PENALTY); guarded: the best "
                   "refined beam unless it costs more than 5 IoU points; chamfer: the paper's choice, the "
                   "lowest chamfer (docs/csgnet.md)")
    p.add_argument("--model", choices=("csgnet", "csgnetstack"), default=None,
                   help="the shipped model to use (default: the strongest of each dimension, CSGNetStack in 2D and "
                   "CSGNet in 3D; docs/csgnet.md)")
    p.add_argument("--weights-2d", default=None, help="2D weights file or checkpoint (instead of a shipped model)")
    p.add_argument("--weights-3d", default=None, help="3D weights file or checkpoint (instead of a shipped model)")
    p.add_argument("--out", default="parse_output", help="folder for the outputs (default parse_output/)")
    p.set_defaults(func=cmd_parse)

    e = sub.add_parser("evaluate", help="Table 3 / Table 5 style evaluation on a synthetic test split")
    e.add_argument("--dim", type=int, choices=(2, 3), default=2, help="2D or 3D (default 2)")
    e.add_argument("--data", required=True, help="dataset folder written by `generate`")
    e.add_argument("--weights", nargs="*", default=None, help="weights files (default: the shipped model)")
    e.add_argument("--beams", type=_beam_width, nargs="+", default=[1, 5, 10], help="beam widths (default 1 5 10)")
    e.add_argument("--lengths", type=int, nargs="*", default=None, help="program lengths (default: all)")
    e.add_argument("--per-length", type=int, default=None, help="test programs per length (default: all)")
    e.add_argument("--nn-train", type=int, default=-1, help="training programs for the nearest neighbour "
                   "(-1: all, 0: skip)")
    e.add_argument("--mode", choices=("improved", "reference"), default="improved",
                   help="beam search: improved, or the published reference behaviour")
    e.add_argument("--constrained", action="store_true", help="grammar-constrained decoding")
    e.add_argument("--refined", type=_non_negative, default=0, metavar="N",
                   help="add a row of the whole parse (the widest beam, the closest beam, refinement, the short "
                   "rule: what parse --select match --refine writes) on the first N test programs per length")
    e.add_argument("--out", default=None, help="write the table here: FILE.json as a result file (data that "
                   "docs tables are generated from, python -m shapeio.results), any other name as markdown")
    e.set_defaults(func=cmd_evaluate)

    x = sub.add_parser("export-weights", help="write a training checkpoint's model as a small weights file")
    x.add_argument("checkpoint", help="a Lightning .ckpt file written by training")
    x.add_argument("--out", required=True, help="the weights file to write (.pt)")
    x.add_argument("--float32", action="store_true", help="keep float32 (default: float16 storage)")
    x.set_defaults(func=cmd_export_weights)

    t4 = sub.add_parser("table4", help="Table 4 protocol: parsing the test silhouettes, with refinement")
    t4.add_argument("--weights", nargs="*", default=None,
                    help="2D weights files or checkpoints, optionally LABEL=PATH (default: the four shipped "
                    "2D models, supervised and RL-tuned)")
    t4.add_argument("--images", type=int, default=50, help="test silhouettes evaluated (0: all 1,386)")
    t4.add_argument("--seed", type=int, default=0, help="seed of the subset")
    t4.add_argument("--beams", type=_beam_width, nargs="+", default=[1, 10], help="beam widths (default 1 10)")
    t4.add_argument("--iterations", nargs="+", default=["0", "1", "2", "4", "10", "inf"],
                    help="refinement iteration limits ('inf': to convergence)")
    t4.add_argument("--silhouettes", default=None, help="a silhouette file (default: the shipped set)")
    t4.add_argument("--no-nn", action="store_true", help="skip the nearest-neighbour row")
    t4.add_argument("--constrained", action="store_true", help="grammar-constrained decoding")
    t4.add_argument("--out", default=None, help="write the markdown table here")
    t4.set_defaults(func=cmd_table4)

    t6 = sub.add_parser("table6", help="Table 6 protocol: primitive detection AP on synthetic 2D programs")
    t6.add_argument("--weights", default=None, help="2D weights file or checkpoint, optionally LABEL=PATH "
                    "(default: the shipped model)")
    t6.add_argument("--data", default=None, help="dataset folder written by `generate` (default: sample programs)")
    t6.add_argument("--per-length", type=int, default=100, help="test programs per length")
    t6.add_argument("--lengths", type=int, nargs="*", default=None, help="program lengths (default 3..13)")
    t6.add_argument("--seed", type=int, default=0, help="seed for sampled programs")
    t6.add_argument("--beams", type=_beam_width, nargs="+", default=[10, 40], help="beam widths (default 10 40)")
    t6.add_argument("--constrained", action="store_true", help="grammar-constrained decoding")
    t6.add_argument("--out", default=None, help="write the markdown table here")
    t6.set_defaults(func=cmd_table6)

    ed = sub.add_parser("edit", help="edit a program in the browser (needs the 'editor' extra: viser)",
                        description="Serve an editor page for a CSG program: the live render, one slider per "
                                    "primitive parameter, undo / redo / reset, export. Runs until interrupted. "
                                    "See docs/editor.md.")
    ed.add_argument("program", help='program text, e.g. "c(32,32,28)s(32,32,20)-", or a file whose first line is one')
    ed.add_argument("--dim", type=int, choices=(2, 3), default=None, help="2 or 3 (default: guessed from the text)")
    ed.add_argument("--port", type=int, default=8080, help="port of the page")
    ed.add_argument("--host", default="127.0.0.1", help="address to bind (default: this machine only)")
    ed.add_argument("--export-dir", default=".", help="the folder exports are written to (never elsewhere)")
    ed.add_argument("--no-browser", action="store_true", help="do not open a browser")
    ed.set_defaults(func=cmd_edit)

    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    args.argv = list(argv) if argv is not None else sys.argv[1:]
    if args.cmd == "render" and args.dim is None:
        args.dim = 3 if any(h + "(" in args.program for p in primitives(3) for h in (p.kind, p.long) if h) else 2
    try:
        return args.func(args)
    except BrokenPipeError:  # the reader went away (`... | head -1`): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except (ValueError, OSError) as e:  # bad input files (ParseError, InputError, ...): the message names them
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
