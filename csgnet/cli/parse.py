"""``parse``: shapes (images, grids, meshes) to programs, with the files a user opens."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from shapeio import atomic_write, refuse_overwrite
from shapeio.files import existing_outputs
from shapeio.results import column, make_result, write_result

from .. import export, render
from . import common
from ..lang import ParseError
from .common import beam_width, command_line, located, named


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


def _parse_models(args) -> dict:
    """The models ``parse`` uses, by dimension: a weights file given with ``--weights-2d`` / ``--weights-3d``
    is loaded now, so that a bad one is reported once, before any input; the shipped models (``--model``,
    default the strongest of each dimension) are loaded when an input of their dimension comes."""
    from ..inference import load_model  # lazy: loaded when the command runs

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
    from ..inference import load_pretrained  # lazy: loaded when the command runs

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
    from ..inference import INFER_PRECISION, INFER_VIEWS, parse_shape  # lazy: loaded when the command runs

    dim = shape.ndim
    views = (args.views or INFER_VIEWS[3]) if dim == 3 else 1
    parsed = parse_shape(shape, model=model, beam=args.beam, select=args.select, refine=args.refine,
                         rule=args.refine_rule, refine_iters=args.refine_iters, constrained=not args.unconstrained,
                         graft=not args.no_graft, extend=not args.no_extend, fit=not args.no_fit,
                         precision=args.precision or INFER_PRECISION, views=views)
    res, ref, program = parsed.decoded, parsed.refined, parsed.program
    score = "log-probability" if views == 1 else f"mean log-probability over {views} views"
    line = f"{src}: {res.text}\n  {score} {res.score:.3f}, IoU {100 * res.iou:.2f}%"
    if dim == 2:
        line += f", chamfer {res.chamfer:.3f} px"
    if not res.valid:
        line += " (invalid program: renders empty)"
    print(line)
    record = {"input": str(src), "decoded": res.text, "valid": bool(res.valid), "iou": float(res.iou),
              "chamfer": None if dim == 3 else float(res.chamfer),
              "primitives": len(res.program.draws) if res.valid else 0}
    if ref is not None:
        from ..refinement import MAX_IOU_DROP  # lazy: loaded when the command runs

        (i0, c0), (i1, c1) = ref.before, ref.after
        what = {"short": "IoU - %g per primitive" % _penalty(dim), "guarded": "guarded", "chamfer": "chamfer"}
        print(f"  refined ({parsed.refined_beams} beams, by {'IoU' if dim == 3 else 'chamfer'}; chosen by "
              f"{what[ref.rule]}): {program.text()}\n"
              f"  before: {_scores_line(i0, c0, res.program)}; "
              f"after: {_scores_line(i1, c1, program)}")
        if ref.kept_start and ref.rule == "guarded":
            print(f"  refinement lowered IoU by more than {100 * MAX_IOU_DROP:g} points: "
                  f"wrote the unrefined program {program.text()}")
        record.update(refined=program.text(), rule=ref.rule, iou_refined=float(i1),
                      chamfer_refined=None if dim == 3 else float(c1), primitives_refined=len(program.draws))
    stem.parent.mkdir(parents=True, exist_ok=True)
    txt = atomic_write(named(stem, ".txt"), (res.text if program is None else program.text()) + "\n")
    img = np.zeros((64,) * dim, dtype=bool) if program is None else render(program, dim)[0]
    if dim == 2:
        compare = stem.with_name(stem.name + "_compare.png")
        written = [export.save_png(img, named(stem, ".png")), compare]
        export.save_sheet(export.contact_sheet([shape, img], cols=2), compare, columns=("input", "program"))
    else:
        compare = stem.with_name(stem.name + "_compare.png")
        written = [export.save_obj(img, named(stem, ".obj"), transform=frame), compare]
        export.save_sheet(export.contact_sheet([export.depth_view(shape, a) for a in range(3)]
                                               + [export.depth_view(img, a) for a in range(3)], cols=3), compare,
                          columns=("along x", "along y", "along z"), rows=("input", "program"))
    if program is not None:
        written.append(export.save_scad(program, named(stem, ".scad"), transform=frame))
    print("  wrote " + ", ".join(str(w) for w in written + [txt]))
    return record


def _penalty(dim: int) -> float:
    from ..rewrite import LENGTH_PENALTY  # lazy: loaded when the command runs

    return LENGTH_PENALTY[dim]


RESULT_COLUMNS = (("input", "input", None, 1.0), ("decoded", "decoded program", None, 1.0),
                  ("iou", "IoU (%)", 1, 100.0), ("chamfer", "chamfer (px)", 3, 1.0), ("primitives", "primitives", None, 1.0),
                  ("refined", "refined program", None, 1.0), ("iou_refined", "IoU refined (%)", 1, 100.0),
                  ("chamfer_refined", "chamfer refined (px)", 3, 1.0),
                  ("primitives_refined", "primitives refined", None, 1.0), ("error", "error", None, 1.0))


def _results(records: list[dict], args) -> dict:
    """The inputs' records as a result file (:mod:`shapeio.results`): one row per input, in order."""
    keys = [c[0] for c in RESULT_COLUMNS]
    present = [c for c in RESULT_COLUMNS if any(r.get(c[0]) is not None for r in records)] or RESULT_COLUMNS[:1]
    rows = [{**{k: None for k in keys}, **r} for r in records]
    cols = [column(k, label, digits, scale) for k, label, digits, scale in present]
    return make_result("Shapes parsed into programs", cols, rows, command=command_line(args))


def _results_path(out: Path) -> Path:
    """``out/results.json``, or ``results_2.json``, ... : the first name not taken (never overwritten)."""
    path, k = out / "results.json", 2
    while path.exists():
        path, k = out / f"results_{k}.json", k + 1
    return path


def cmd_parse(args) -> int:
    """Infer a program for each input shape with a trained model; a bad input is reported and skipped."""
    from shapeio import InputError  # lazy: loaded when the command runs

    from ..inference import load_shape_framed  # lazy: loaded when the command runs

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
    problem = existing_outputs(outputs, args.overwrite)  # an earlier parse's files in the folder
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        models = _parse_models(args)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    status = 0
    records = []
    dims = set()
    for src, stem in zip(args.inputs, stems):
        try:
            shape, frame = load_shape_framed(src)  # a mesh's outputs are written in its own units
            dims.add(shape.ndim)
            model = _parse_model(models, shape.ndim, args.model)
            records.append(_parse_one(src, shape, stem, model, args, frame))
        except (InputError, ParseError, ValueError, OSError) as e:
            print(f"error: {located(src, e)}", file=sys.stderr)
            records.append({"input": str(src), "error": located(src, e)})
            status = 2
    if args.views is not None and args.views > 1 and dims == {2}:
        print(f"note: --views {args.views} was not used: it is for 3D inputs, and every input was 2D", file=sys.stderr)
    if out.is_dir():
        results = write_result(_results_path(out), _results(records, args))
        print(f"results of the {len(records)} inputs: {results}")
    return status


def register(sub) -> None:
    """Add this module's subcommands to ``python -m csgnet``."""
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
    p.add_argument("--beam", type=beam_width, default=10, help="beam width, 1 (greedy) to 256 (default 10)")
    p.add_argument("--select", choices=("likelihood", "match"), default="likelihood",
                   help="report the most likely program, or the beam closest to the input")
    p.add_argument("--unconstrained", action="store_true", help="allow invalid programs while decoding")
    p.add_argument("--precision", choices=common.PRECISIONS, default=None,
                   help="the model's arithmetic while decoding: auto (default: bfloat16 autocast on a CPU with "
                   "native bfloat16, AVX512-BF16 or AMX, else float32), float32 (what the docs' tables measure) or "
                   "bfloat16; scores stay float32")
    p.add_argument("--views", type=int, choices=common.VIEWS, default=None,
                   help="3D inputs: mirror images of the volume one decode reads, their log-probabilities averaged "
                   "(default 8; 1 is the paper's decoding); 2D inputs are decoded alone")
    p.add_argument("--refine", action="store_true",
                   help="Powell refinement of every valid beam (by chamfer in 2D, by IoU in 3D)")
    p.add_argument("--refine-iters", type=common.int_in(0, common.MAX_REFINE_ITERS), default=None,
                   help="Powell iterations, 0 or more (default: to convergence)")
    p.add_argument("--refine-rule", choices=("short", "guarded", "chamfer"), default="short",
                   help="short: among the decoded program and every refined beam, each also pruned, the "
                   "highest IoU minus a price per primitive (csgnet.rewrite.LENGTH_PENALTY); guarded: the best "
                   "refined beam unless it costs more than 5 IoU points; chamfer: the paper's choice, the "
                   "lowest chamfer (docs/csgnet.md)")
    p.add_argument("--no-graft", action="store_true",
                   help="with the short rule, do not try adding other beams' primitives to the chosen program")
    p.add_argument("--no-extend", action="store_true",
                   help="with the short rule, do not search the whole vocabulary for primitives to add")
    p.add_argument("--no-fit", action="store_true",
                   help="with the short rule, do not fit primitives of any size to the parts the program gets "
                        "wrong (csgnet.rewrite.fit)")
    p.add_argument("--model", choices=("csgnet", "csgnetstack"), default=None,
                   help="the shipped model to use (default: the strongest of each dimension, CSGNetStack in 2D and "
                   "CSGNet in 3D; docs/csgnet.md)")
    p.add_argument("--weights-2d", default=None, help="2D weights file or checkpoint (instead of a shipped model)")
    p.add_argument("--weights-3d", default=None, help="3D weights file or checkpoint (instead of a shipped model)")
    p.add_argument("--out", default="parse_output", help="folder for the outputs (default parse_output/)")
    p.set_defaults(func=cmd_parse)
