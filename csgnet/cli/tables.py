"""``evaluate``, ``table4``, ``table6`` and ``export-weights``: the papers' tables and shipped weights files."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from shapeio import refuse_overwrite

from . import common
from ..shapes2d import load_silhouettes
from ..vocab import vocabulary
from .common import (beam_width, command_line, decoding, labelled_models, located, measured_on,
                     refuse_table_over_inputs, write_table)


def cmd_evaluate(args) -> int:
    from ..data import load_dataset  # lazy: loaded when the command runs
    from ..paper.tables import evaluate_model, markdown_tables, nearest_neighbour, table_result  # lazy: loaded when the command runs

    refuse_table_over_inputs(args)
    if args.dim != 3 and max(args.views) > 1:
        raise SystemExit(f"error: --views {' '.join(map(str, args.views))}: more than 1 view is for 3D models (--dim 3)")
    tests = load_dataset(args.data, args.dim, "test", args.lengths, errors="raise")
    tests = {L: p[: args.per_length] for L, p in tests.items()}
    rows = []
    if args.nn_train != 0:
        train = [p for L, ps in sorted(load_dataset(args.data, args.dim, "train", args.lengths).items()) for p in ps]
        if args.nn_train > 0:
            train = train[: args.nn_train]
        print(f"nearest neighbour over {len(train)} training programs ...", flush=True)
        rows.append(nearest_neighbour(train, tests, args.dim))
    for name, model in labelled_models(args.weights, args.dim):
        if model.config.dim != args.dim:
            raise SystemExit(f"error: {name} is a {model.config.dim}D model, not {args.dim}D")
        views = list(dict.fromkeys(args.views))  # a value given twice gives its rows once
        for v in views:
            print(f"decoding with {name}" + (f", {v} views" if v > 1 else "") + " ...", flush=True)
            rows += evaluate_model(model, tests, tuple(args.beams), name=name, mode=args.mode,
                                   constrained=args.constrained, precision=args.precision, views=v)
        if args.refined:
            from ..paper.tables import evaluate_refined  # lazy: loaded when the command runs

            for v in views:
                print(f"parsing with refinement ({name}, {args.refined} per length"
                      + (f", {v} views" if v > 1 else "") + ") ...", flush=True)
                rows.append(evaluate_refined(model, tests, max(args.beams), name=name, per_length=args.refined,
                                             precision=args.precision, views=v))
    note = "\n\n".join([f"`{command_line(args)}`; beam mode {args.mode!r}, {decoding(args)}; {measured_on()}.",
                        *args.note])
    if write_result_file(args, lambda notes: table_result(rows, args.dim, notes, command_line(args)),
                         [f"Beam mode {args.mode!r}, {decoding(args)}; {measured_on()}.", *args.note]):
        return 0
    write_table(markdown_tables(rows, args.dim, note), args.out)
    return 0


def write_result_file(args, make, notes) -> bool:
    """With ``--out X.json``: write the result ``make(notes)`` there (a result file, :mod:`shapeio.results`),
    print it as markdown and return True; otherwise False (the command writes markdown)."""
    if not (args.out and str(args.out).endswith(".json")):
        return False
    from shapeio.results import markdown, write_result  # lazy: loaded when the command runs

    result = make(notes)
    print(markdown(result))
    print(f"wrote {write_result(args.out, result)}")
    return True


def cmd_export_weights(args) -> int:
    from ..inference import export_weights  # lazy: loaded when the command runs

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
        print(f"error: {located(args.out, e)}", file=sys.stderr)
        return 2
    print(f"wrote {path} ({path.stat().st_size / 2**20:.2f} MiB)")
    return 0


#: Most batches of one ``table1`` or ``datasize`` run (csgnet.train.sweep.MAX_SWEEP_STEPS and
#: csgnet.train.datasize.MAX_DATASIZE_STEPS, repeated here so that ``--help`` does not import Lightning).
MAX_SWEEP_STEPS_CLI = 100_000

# The shipped CSGNet and small CSGNetStack (csgnetstack2d.pt, the starting point of the RL run), supervised and
# RL-tuned on the silhouettes (docs/compute_plan.md says how each was trained): Table 4's rows when no --weights
# are given. The medium CSGNetStack (load_pretrained(2, kind="csgnetstack")) is added with --weights.
TABLE4_MODELS = (("CSGNet supervised", "csgnet2d.pt"), ("CSGNet RL", "rl_csgnet2d.pt"),
                 ("CSGNetStack supervised", "csgnetstack2d.pt"), ("CSGNetStack RL", "rl_csgnetstack2d.pt"))


def cmd_table4(args) -> int:
    from ..inference import WEIGHTS  # lazy: loaded when the command runs
    from ..paper.protocols import subset, table4, table4_markdown, table4_result  # lazy: loaded when the command runs

    refuse_table_over_inputs(args)
    if args.cad:
        from ..shapes2d import load_cad_h5  # lazy: loaded when the command runs

        test, source = load_cad_h5(args.cad, "test"), f"test images of {args.cad} (the paper's CAD set)"
        train = None if args.no_nn else load_cad_h5(args.cad, "train")
    else:
        test, source = load_silhouettes("test", args.silhouettes), "test silhouettes"
        train = None if args.no_nn else load_silhouettes("train", args.silhouettes)
    idx = subset(len(test), None if args.images <= 0 else args.images, args.seed)
    iters = [None if i in ("inf", "none") else int(i) for i in args.iterations]
    specs = args.weights or [f"{label}={WEIGHTS / name}" for label, name in TABLE4_MODELS]
    rows = table4(labelled_models(specs), test[idx], train, tuple(args.beams), iters,
                  constrained=args.constrained, progress=lambda s: print(s, flush=True))
    note = (f"`{command_line(args)}`; {len(idx)} of {len(test)} {source} "
            f"(seed {args.seed}); {decoding(args)}; {measured_on()}.")
    if write_result_file(args, lambda notes: table4_result(rows, iters, notes, command_line(args)),
                         [f"{len(idx)} of {len(test)} {source} (seed {args.seed}); {decoding(args)}; "
                          f"{measured_on()}."]):
        return 0
    write_table(table4_markdown(rows, note, iters), args.out)
    return 0


def cmd_table1(args) -> int:
    from ..inference import WEIGHTS  # lazy: loaded when the command runs
    from ..paper.protocols import subset, table4, table4_markdown, table4_result  # lazy: loaded when the command runs
    from ..train.sweep import reward_sweep  # lazy: loaded when the command runs

    refuse_table_over_inputs(args)
    init = args.init or str(WEIGHTS / "csgnet2d.pt")
    train = load_silhouettes("train", args.silhouettes)
    train = train[subset(len(train), min(args.train_images, len(train)), args.seed)]
    test = load_silhouettes("test", args.silhouettes)
    idx = subset(len(test), None if args.images <= 0 else args.images, args.seed)
    models = reward_sweep(init, args.gammas, args.steps, train, args.batch, args.lr, args.seed, args.accumulate,
                          progress=lambda s: print(s, flush=True))
    rows = table4(models, test[idx], None, tuple(args.beams), (0,), progress=lambda s: print(s, flush=True))
    setup = (f"REINFORCE from {args.init or 'the shipped csgnet2d.pt'}, {args.steps} batches of {args.batch} silhouettes, one SGD update per "
             f"{args.accumulate} (lr {args.lr}, momentum 0.9, gradient norm clipped at 10, the same batches for every gamma, seed {args.seed}, {len(train)} training "
             f"silhouettes); scored on {len(idx)} of {len(test)} test silhouettes; {measured_on()}.")
    paper = ("The paper's Table 1 sweeps gamma on its CAD set, which is not available here (csg-t4-cad), over "
             "full-length runs; this sweep is scaled to the CPU, so compare the rows with each other, not with "
             "the paper's figures.")
    if write_result_file(args, lambda notes: table4_result(rows, (0,), notes, command_line(args), "Table 1 layout (reward shaping: REINFORCE per gamma, PartNet silhouettes, test split)", paper=False), [setup, paper]):
        return 0
    write_table(table4_markdown(rows, f"`{command_line(args)}`; {setup} {paper}", (0,)), args.out)
    return 0


def cmd_datasize(args) -> int:
    from ..data import load_dataset  # lazy: loaded when the command runs
    from ..paper.tables import evaluate_model, markdown_tables, table_result  # lazy: loaded when the command runs
    from ..train.datasize import data_size_runs  # lazy: loaded when the command runs

    refuse_table_over_inputs(args)
    tests = load_dataset(args.data, 2, "test", None, errors="raise")
    tests = {L: p[: args.per_length] for L, p in tests.items()}
    runs = data_size_runs(args.data, args.fractions, args.steps, stack=args.stack, size=args.size,
                          batch_size=args.batch, seed=args.seed, progress=lambda s: print(s, flush=True))
    rows = []
    for f, n, model in runs:
        rows += evaluate_model(model, tests, tuple(args.beams), name=f"{n} training programs ({100 * f:g} %)")
    setup = (f"One {'CSGNetStack' if args.stack else 'CSGNet'} {args.size} run per share of the training programs "
             f"of {args.data}: {args.steps} batches of {args.batch} from seed {args.seed}, the same for every "
             f"share; scored on {args.per_length} test programs per length; {measured_on()}.")
    paper = ("The paper's Figures 6 and 9 plot accuracy against training set size over full-length runs; this "
             "study is scaled to the CPU, so compare its rows with each other.")
    if write_result_file(args, lambda notes: table_result(rows, 2, notes, command_line(args)), [setup, paper]):
        return 0
    write_table(markdown_tables(rows, 2, f"`{command_line(args)}`; {setup} {paper}"), args.out)
    return 0


def cmd_table6(args) -> int:
    from ..paper.protocols import table6, table6_markdown, table6_result  # lazy: loaded when the command runs

    refuse_table_over_inputs(args)
    lengths = args.lengths or [3, 5, 7, 9, 11, 13]
    if args.data:
        from ..data import load_dataset  # lazy: loaded when the command runs

        tests = load_dataset(args.data, 2, "test", lengths, errors="raise")
        programs = [p for L in sorted(tests) for p in tests[L][: args.per_length]]
        source = f"{args.data} (test split, {args.per_length} per length)"
    else:
        from ..synth import sample_programs  # lazy: loaded when the command runs

        rng = np.random.default_rng(args.seed)
        vocab = vocabulary(2)
        programs = [vocab.decode(r) for L in lengths for r in sample_programs(2, L, args.per_length, rng)]
        source = f"sampled with seed {args.seed}, {args.per_length} per length"
    labelled = []
    for label, model in labelled_models(args.weights or []):
        print(f"detection with {label} ...", flush=True)
        labelled.append((label, table6(model, programs, tuple(args.beams), constrained=args.constrained,
                                       progress=lambda s: print(s, flush=True))))
    setup = (f"targets: {source}, lengths {', '.join(map(str, lengths))}; {decoding(args)}; {measured_on()}.")
    if write_result_file(args, lambda notes: table6_result(labelled, notes, command_line(args)), [setup]):
        return 0
    write_table("\n".join(table6_markdown(rows, f"`{command_line(args)}`; {label}; {setup}")
                          for label, rows in labelled), args.out)
    return 0


def register(sub) -> None:
    """Add this module's subcommands to ``python -m csgnet``."""
    e = sub.add_parser("evaluate", help="Table 3 / Table 5 style evaluation on a synthetic test split")
    e.add_argument("--dim", type=int, choices=(2, 3), default=2, help="2D or 3D (default 2)")
    e.add_argument("--data", required=True, help="dataset folder written by `generate`")
    e.add_argument("--weights", nargs="*", default=None, help="weights files (default: the shipped model)")
    e.add_argument("--beams", type=beam_width, nargs="+", default=[1, 5, 10], help="beam widths (default 1 5 10)")
    e.add_argument("--lengths", type=common.length, nargs="*", default=None, help="program lengths (default: all)")
    e.add_argument("--per-length", type=common.per_length, default=None, help="test programs per length (default: all)")
    e.add_argument("--nn-train", type=common.int_in(-1, common.MAX_NN_TRAIN), default=-1, help="training programs for the nearest neighbour "
                   "(-1: all, 0: skip)")
    e.add_argument("--mode", choices=("improved", "reference"), default="improved",
                   help="beam search: improved, or the published reference behaviour")
    e.add_argument("--constrained", action="store_true", help="grammar-constrained decoding")
    e.add_argument("--precision", choices=common.PRECISIONS, default="float32",
                   help="the model's arithmetic while decoding: float32 (default, the protocol of the published "
                   "tables), bfloat16 (autocast; scores stay float32) or auto (bfloat16 on a CPU with native "
                   "bfloat16, else float32)")
    e.add_argument("--views", type=int, choices=common.VIEWS, nargs="+", default=[1],
                   help="3D: mirror images of each volume one decode reads (default 1, the paper's decoding); "
                   "several values give rows for each")
    e.add_argument("--refined", type=common.per_length, default=0, metavar="N",
                   help="add a row of the whole parse (the widest beam, the closest beam, refinement, the short "
                   "rule: what parse --select match --refine writes) on the first N test programs per length")
    e.add_argument("--note", action="append", default=[], help="a line written under the table (repeatable), "
                   "e.g. the paper's figures for comparison")
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
    t4.add_argument("--images", type=common.int_in(0, common.MAX_IMAGES), default=50, help="test silhouettes evaluated (0: all 1,386)")
    t4.add_argument("--seed", type=common.seed, default=0, help="seed of the subset")
    t4.add_argument("--beams", type=beam_width, nargs="+", default=[1, 10], help="beam widths (default 1 10)")
    t4.add_argument("--iterations", nargs="+", default=["0", "1", "2", "4", "10", "inf"],
                    help="refinement iteration limits ('inf': to convergence)")
    t4.add_argument("--silhouettes", default=None, help="a silhouette file (default: the shipped set)")
    t4.add_argument("--cad", default=None, metavar="CAD_H5", help="read the paper's CAD set (cad.h5 of its code "
                    "release; needs the 'cad' extra) instead of the silhouettes")
    t4.add_argument("--no-nn", action="store_true", help="skip the nearest-neighbour row")
    t4.add_argument("--constrained", action="store_true", help="grammar-constrained decoding")
    t4.add_argument("--out", default=None, help="write the table here: FILE.json as a result file, any other "
                    "name as markdown")
    t4.set_defaults(func=cmd_table4)

    t1 = sub.add_parser("table1", help="Table 1 protocol: the reward-shaping sweep (REINFORCE per gamma), "
                        "scored on the test silhouettes")
    t1.add_argument("--init", default=None, help="supervised 2D weights to start every run from (default: the "
                    "shipped csgnet2d.pt)")
    t1.add_argument("--gammas", type=common.float_in(0.0, 1000.0, low_open=True), nargs="+", default=[1, 5, 10, 20],
                    help="reward exponents (default 1 5 10 20; the paper uses 20)")
    t1.add_argument("--steps", type=common.int_in(1, MAX_SWEEP_STEPS_CLI), default=900,
                    help="batches per run (the budget is counted in batches, not seconds)")
    t1.add_argument("--accumulate", type=common.int_in(1, 1000), default=3,
                    help="batches per SGD update (the shipped REINFORCE configs: 3)")
    t1.add_argument("--batch", type=common.int_in(1, 10_000), default=100, help="silhouettes per batch")
    t1.add_argument("--lr", type=common.float_in(0.0, 1.0, low_open=True), default=0.01, help="SGD learning rate")
    t1.add_argument("--train-images", type=common.int_in(1, common.MAX_IMAGES), default=2000,
                    help="training silhouettes drawn (with --seed) for the runs")
    t1.add_argument("--images", type=common.int_in(0, common.MAX_IMAGES), default=200,
                    help="test silhouettes scored (0: all)")
    t1.add_argument("--beams", type=beam_width, nargs="+", default=[1, 10], help="beam widths (default 1 10)")
    t1.add_argument("--seed", type=common.seed, default=0, help="seed of the runs and subsets")
    t1.add_argument("--silhouettes", default=None, help="a silhouette file (default: the shipped set)")
    t1.add_argument("--out", default=None, help="write the table here: FILE.json as a result file, any other "
                    "name as markdown")
    t1.set_defaults(func=cmd_table1)

    ds = sub.add_parser("datasize", help="Figures 6 and 9 protocol: the same supervised run on growing shares of "
                        "a 2D training set, scored on its test split")
    ds.add_argument("--data", required=True, help="2D dataset folder written by `generate`")
    ds.add_argument("--fractions", type=common.float_in(0.0, 1.0, low_open=True), nargs="+",
                    default=[0.0625, 0.25, 1.0], help="shares of each length's training programs")
    ds.add_argument("--steps", type=common.int_in(1, MAX_SWEEP_STEPS_CLI), default=3000,
                    help="training batches per run (the budget is counted in batches, not seconds)")
    ds.add_argument("--batch", type=common.int_in(1, 10_000), default=100, help="programs per batch")
    ds.add_argument("--size", choices=("small", "paper"), default="small", help="model preset")
    ds.add_argument("--stack", action="store_true", help="CSGNetStack instead of CSGNet")
    ds.add_argument("--per-length", type=common.per_length, default=50, help="test programs per length")
    ds.add_argument("--beams", type=beam_width, nargs="+", default=[1, 10], help="beam widths (default 1 10)")
    ds.add_argument("--seed", type=common.seed, default=0, help="seed of the runs")
    ds.add_argument("--out", default=None, help="write the table here: FILE.json as a result file, any other "
                    "name as markdown")
    ds.set_defaults(func=cmd_datasize)

    t6 = sub.add_parser("table6", help="Table 6 protocol: primitive detection AP on synthetic 2D programs")
    t6.add_argument("--weights", nargs="*", default=None, help="2D weights files or checkpoints, optionally "
                    "LABEL=PATH (default: the shipped model)")
    t6.add_argument("--data", default=None, help="dataset folder written by `generate` (default: sample programs)")
    t6.add_argument("--per-length", type=common.per_length, default=100, help="test programs per length")
    t6.add_argument("--lengths", type=common.length, nargs="*", default=None, help="program lengths (default 3..13)")
    t6.add_argument("--seed", type=common.seed, default=0, help="seed for sampled programs")
    t6.add_argument("--beams", type=beam_width, nargs="+", default=[10, 40], help="beam widths (default 10 40)")
    t6.add_argument("--constrained", action="store_true", help="grammar-constrained decoding")
    t6.add_argument("--out", default=None, help="write the table here: FILE.json as a result file, any other "
                    "name as markdown")
    t6.set_defaults(func=cmd_table6)
