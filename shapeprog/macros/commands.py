"""``python -m shapeprog macros ...``: ShapeMOD, discover macro libraries, refactor programs and the corpus
with them, and the paper's Table 1."""
from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

from shapeio import atomic_write
from shapeio.results import column

from .. import corpus
from ..cli import (MAX_SECONDS_OPTION, add_category, add_command, add_quiet, add_result_options, add_seed, add_workers,
                   category_pairs, command_line, command_result, float_in, int_at_least, macro_library, Program,
                   progress_log, refuse_existing, refuse_inputs, report, worker_pool, write_json)
from .api import collection
from .api import refactor
from .baseline import baseline_library
from .discover import discover, prior_rounds, rounds_line
from .state import Discovery, Nodes
from .config import load_config
from .lang import from_lines, to_text
from .refactored import check_target, refactor_corpus, write_refactored
from .ablation import VARIANTS, ablation_result, run_ablation
from .table1 import table1_result, table1_rows

SPLITS = ("train", "val", "all")
#: Table 5's variants (the keys of :data:`shapeprog.macros.ablation.VARIANTS`): the choices of ``ablation --variants``.
ABLATION_VARIANTS = tuple(VARIANTS)
#: Most samples per model of ``generation`` (the paper: 1,000).
MAX_GENERATION_SAMPLES = 10_000
#: Largest noise sigma accepted by ``perturbation`` (the shapes are about one unit tall).
MAX_SIGMA = 10.0
#: The full study's noise levels (``shapeprog.macros.perturb_study.SIGMAS``, repeated here so that ``--help``
#: imports no torch model).
SIGMAS = (0.0, 0.01, 0.025, 0.05, 0.1, 0.15, 0.2)
SEARCHES = ("beam", "exact")


def merged_collection(categories, split: str = "all", limit: int | None = None, seed: int = 0, executor=None,
                      max_orders: int = 1000):
    """The sub-programs of several categories as one collection (:func:`~.api.collection` of each, ``limit``
    shapes per category, joined in the given order; keys carry the category) and the shapes' keys
    (``category/id``)."""
    if len(set(categories)) != len(categories):
        raise SystemExit(f"error: --category: a category is named twice ({' '.join(categories)})")
    keys, lines, sigs, ids = [], [], [], []
    for cat in categories:
        nodes, cat_ids = collection(cat, split, limit, seed, executor=executor, max_orders=max_orders)
        keys += nodes.keys
        lines += nodes.lines
        sigs += nodes.sigs
        ids += [f"{cat}/{i}" for i in cat_ids]
    return Nodes(keys, lines, sigs), ids


def cmd_discover(args) -> int:
    """discover a macro library from a category's programs

    Run ShapeMOD discovery (proposal, generalisation, integration, filterBadOrders) on a corpus category; state.json is
    written after every round and an interrupted run resumes from it (an --out folder of a run is continued, never
    overwritten); library.txt holds the result.

    Example: macros discover --category chair --rounds 5 --workers 2 --out runs/shapemod_chair"""
    cfg = load_config(args.config, num_rounds=args.rounds, cand_cluster_num=args.proposal_steps,
                      abs_shape_num=args.subsample, selection=args.selection, search=args.search)
    lib0, text0 = macro_library(args.start_from, "--start-from: ", text=True) if args.start_from else (None, "")
    prior = prior_rounds(text0, str(args.start_from)) if args.start_from else []
    out = Path(args.out)
    refuse_inputs([out / "library.txt"], [args.start_from, args.config])
    if (out / "library.txt").exists() and not (out / "state.json").exists():  # user files are never overwritten
        raise SystemExit(f"error: {out} holds a library.txt but no state.json of a discovery run to resume; "
                         "choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    command = command_line(args)
    t0 = time.time()
    log = (lambda m: None) if args.quiet else (lambda m: print(f"[{time.time() - t0:7.1f} s] {m}", flush=True))
    with worker_pool(args.workers) as pool:
        nodes, ids = merged_collection(args.category, args.split, args.limit, args.seed, executor=pool,
                                       max_orders=cfg["abs_order_num"])
        log(f"{', '.join(args.category)}: {len(ids)} shapes, {len(nodes.keys)} sub-programs")
        if args.baseline:
            return _write_library(out, args, baseline_library([ls[0] for ls in nodes.lines]), nodes, ids,
                                  command, t0, "ShapeMOD Baseline macros", "")
        start = None if lib0 is None else Discovery.from_library(lib0, nodes, prior, args.start_from)
        state = discover(nodes, cfg, seed=args.seed, executor=pool, out=out, log=log,
                         stop_after=args.stop_after, start=start)
    return _write_library(out, args, state.library(), nodes, ids, command, t0, "ShapeMOD library",
                          rounds_line(state, cfg) + "\n")


def _write_library(out: Path, args, lib, nodes: Nodes, ids: list, command: str, t0: float, title: str,
                   rounds: str) -> int:
    """``library.txt`` in ``out``: a header (what, the command, the shapes, the rounds, the time), then ``lib``."""
    header = (f"# {title} ({', '.join(args.category)}), {len(lib.macros)} macros, |L| = {len(lib)}\n"
              f"# command: {command}\n"
              f"# shapes: {len(ids)} of split '{args.split}' (seed {args.seed}"
              + (f", up to {args.limit} per category" if len(args.category) > 1 and args.limit else "")
              + f"), sub-programs: {len(nodes.keys)}\n{rounds}"
              f"# time: {time.time() - t0:.0f} s on {platform.machine()}, {os.cpu_count()} CPUs, "
              f"{args.workers} worker(s)\n")
    atomic_write(out / "library.txt", header + lib.to_text())
    print(f"wrote {out / 'library.txt'} ({len(lib.macros)} macros)")
    return 0


def cmd_refactor(args) -> int:
    """rewrite a program with a ShapeMOD library

    Rewrite every sub-program with the library's macros (best program over its orderings); print it beside the base
    program with both f.

    Example: macros refactor chair/173 --library chair"""
    refuse_inputs([args.out, args.json], [args.program, args.library])
    refuse_existing([args.out, args.json], args.overwrite)
    prog = Program(args.program)
    lib = macro_library(args.library)
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
    if args.out:
        atomic_write(args.out, r.text)
        print(f"wrote {args.out}")
    rows = [{"block": b.key, "f_base": float(b.f_base), "f": float(b.f)} for b in r.blocks]
    rows.append({"block": "total", "f_base": float(st["f_base"]), "f": float(st["f"])})
    write_json(args, command_result(args, f"ShapeMOD refactor of {prog.name} with {args.library}",
                                    [column("block", "sub-program"), column("f_base", "f (base)", 2),
                                     column("f", "f (macros)", 2)], rows,
                                    [f"total: lines {st['lines']}, floats {st['float']}, cuboid ids {st['cube']}, "
                                     f"categoricals {st['categorical']}, booleans {st['bool']} (after the bbox "
                                     "lines)"]))
    return 0


def _size(path: Path) -> str:
    n = path.stat().st_size if path.is_file() else sum(f.stat().st_size for f in path.iterdir())
    return f"{n / 1024:.0f} KiB"


def cmd_refactor_corpus(args) -> int:
    """rewrite every corpus program of a category with a library

    Refactor every corpus program of a category with a ShapeMOD library (process pool with --workers > 1), check each
    against its original (parse back, execute, leaf cuboids matched), and write one macro program per shape (<id>.txt)
    and summary.json (its figures) into a new folder, atomically.

    Example: macros refactor-corpus --category chair --library chair --workers 2 --out chair_macros"""
    out = Path(args.out)
    try:
        check_target(out)
    except (FileExistsError, FileNotFoundError) as e:
        raise SystemExit(f"error: {e}") from None
    lib = macro_library(args.library)
    command = command_line(args)
    t0 = time.perf_counter()
    with worker_pool(args.workers, "spawn") as pool:
        rc = refactor_corpus(args.category, lib, args.library, split=args.split, limit=args.limit, seed=args.seed,
                             executor=pool, mode=args.search, check=not args.no_check)
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


def cmd_tables(args) -> int:
    """ShapeMOD Table 1: No Macros, Baseline macros and ShapeMOD rows

    Compute the ShapeMOD paper's Table 1 (f, |L|, fn, d, f, b per shape) for the given categories; f also as a ratio to
    the same run's No Macros f, beside the paper's ratio (the paper's absolute f is on another scale).

    Example: macros tables --category chair --limit 200 --out table1.md --json table1.json"""
    library_files = category_pairs(args.library, "CATEGORY=FILE")
    extra_files = category_pairs(args.extra, "NAME=FILE", "--extra")
    refuse_inputs([args.out, args.json], [*library_files.values(), *extra_files.values()])
    refuse_existing([args.out, args.json], args.overwrite)
    extra = {name: macro_library(f, f"--extra {name}=") for name, f in extra_files.items()}
    try:
        with worker_pool(args.workers) as pool:
            rows = table1_rows(args.category, limit=args.limit, seed=args.seed, executor=pool, mode=args.search,
                               library_files=library_files, extra=extra, log=progress_log(args))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    return report(args, table1_result(rows, command_line(args), args.limit, args.seed, args.note or ()), out=args.out)


def cmd_perturbation(args) -> int:
    """ShapeMOD Fig. 7: FD of perturbed programs without and with macros

    Refactor N random train shapes without macros and with a ShapeMOD library, add sigma * N(0, 1) to every continuous
    parameter, and measure the Frechet distance of the perturbed shapes' classifier features to the val split's, per
    sigma (mean, min and max over the noise draws).

    Example: macros perturbation --category chair --n 100 --repeats 1 --sigmas 0 0.05 0.1 --json fig7.json"""
    from .perturb_study import perturbation_result, perturbation_study, plot  # lazy: torch models on use

    refuse_existing([args.json, args.png], args.overwrite)
    name = args.library or args.category
    lib = macro_library(name, "--library ")
    try:
        study = perturbation_study(args.category, lib, name, n=args.n, sigmas=args.sigmas, repeats=args.repeats,
                                   seed=args.seed, log=progress_log(args))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    for ident, reason in study["left_out"]:
        print(f"left out: {args.category}/{ident}: {reason}", file=sys.stderr)
    report(args, perturbation_result(study, command_line(args)))
    if args.png:
        plot(study, args.png)
        print(f"wrote {args.png}")
    return 0


def cmd_ablation(args) -> int:
    """ShapeMOD Table 5: discovery with one part switched off per variant, on the same shapes

    Run discovery once per variant (the full method, and each with one part switched off: P_matches-dist weighting, beam
    search, the bad-order filter, generalisation, the valid-macro criteria) on the same shapes and seed; report f per
    sub-program after each round and of each final library over all the sub-programs.

    Example: macros ablation --category chair --limit 30 --rounds 1 --proposal-steps 20 --json t5.json"""
    refuse_existing([args.json], args.overwrite)
    unknown = [v for v in args.variants if v not in VARIANTS]
    if unknown:
        raise SystemExit(f"error: --variants: unknown variant {unknown[0]!r}; expected some of "
                         + ", ".join(repr(v) for v in VARIANTS))
    base = load_config(args.config, num_rounds=args.rounds, cand_cluster_num=args.proposal_steps,
                       abs_shape_num=args.subsample)
    t0 = time.time()
    log = None if args.quiet else (lambda m: print(f"[{time.time() - t0:7.1f} s] {m}", file=sys.stderr, flush=True))
    with worker_pool(args.workers) as pool:
        nodes, ids = collection(args.category, "all", args.limit, args.seed, executor=pool,
                                max_orders=base["abs_order_num"])
        if log:
            log(f"{args.category}: {len(ids)} shapes, {len(nodes.keys)} sub-programs")
        rows = run_ablation(nodes, args.variants, base, seed=args.seed, executor=pool, log=log)
    scale = (f"{args.category}: {len(ids)} shapes ({len(nodes.keys)} sub-programs; "
             + ("all" if args.limit is None else f"a random subset, seed {args.seed}") + f"), {base['num_rounds']} "
             f"round(s) of {base['cand_cluster_num']} proposal steps, subsample {base['abs_shape_num']} sub-programs")
    return report(args, ablation_result(rows, command_line(args), scale))


def cmd_generation(args) -> int:
    """ShapeMOD Table 2: generation by the VAE without and with macros, beside the paper's rows

    Sample N programs from the VAE over ShapeAssembly programs (No Macros) and from the VAE over macro programs
    (ShapeMOD), measure both with the generation metrics against the same corpus references, and print the ShapeMOD
    paper's Table 2 rows beside them.

    Example: macros generation --category chair -n 20 --no-stability --fool-epochs 4 --json t2.json"""
    # lazy: the VAE models and the generation metrics only when the command runs
    from ..vae.pretrained import load_model, load_pretrained
    from .table2 import generation_rows, table2_result

    refuse_existing([args.json], args.overwrite)
    models = {}
    shipped = Path(__file__).resolve().parents[1] / "weights"
    weights = args.weights or str(shipped / f"vae_{args.category}_macros.pt")
    baseline = args.baseline_weights or shipped / f"vae_{args.category}_baseline_macros.pt"
    # without a Baseline Macros model (none ships for this category) the table says so in its row
    named = [("No Macros", args.base_weights),
             *([("Baseline Macros", baseline)] if Path(baseline).is_file() or args.baseline_weights else []),
             ("ShapeMOD", weights)]
    for name, path in named:
        try:
            models[name] = load_model(path, category=args.category) if path else load_pretrained(args.category)
        except (FileNotFoundError, ValueError) as e:
            raise SystemExit(f"error: {e}") from None
    with worker_pool(args.workers, "spawn") as pool:
        rows, settings = generation_rows(args.category, models, args.n, args.seed, stability=not args.no_stability,
                                         fool_epochs=args.fool_epochs, executor=pool, log=progress_log(args),
                                         ground_truth=not args.no_ground_truth)
    return report(args, table2_result(args.category, rows, settings, args.n, args.seed, command_line(args)))


def cmd_pointcloud(args) -> int:
    """ShapeMOD Table 3: point cloud to program without and with macros, beside the paper's rows

    Decode the test clouds of make-clouds caches with the shipped end-to-end point-cloud models without macros and with
    the ShapeMOD library (one decode, no fitting) and measure CD, F-score, rooted and stable beside the paper's Table 3.

    Example: macros pointcloud --clouds chair=clouds --limit 20 --json t3.json"""
    from .table3 import pointcloud_rows, table3_result  # lazy: torch models on use

    refuse_existing([args.json], args.overwrite)
    pairs = category_pairs(args.clouds, "CATEGORY=FOLDER", "--clouds")
    bad = [c for c in pairs if c not in corpus.CATEGORIES]
    if bad:
        raise SystemExit(f"error: --clouds {bad[0]}=...: unknown category; expected {', '.join(corpus.CATEGORIES)}")
    missing = [f for f in pairs.values() if not Path(f).is_dir()]
    if missing:
        raise SystemExit(f"error: --clouds: {missing[0]}: no such folder (make it with `python -m shapeprog "
                         "pointcloud make-clouds`)")
    try:
        with worker_pool(args.workers, "spawn") as pool:
            rows = pointcloud_rows(pairs, args.limit, args.seed, stability=not args.no_stability, executor=pool,
                                   log=progress_log(args))
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"error: {e}") from None
    return report(args, table3_result(rows, command_line(args), args.limit, args.seed))


def register(sub) -> None:
    """Add the ``macros`` commands to ``sub``."""
    d = add_command(sub, "discover", cmd_discover, outputs={"out": "folder"})
    add_category(d, multiple=True, help="the categories (several: one library over all their programs, "
                                        "--limit shapes of each)")
    d.add_argument("--out", required=True, help="output folder (state.json, library.txt)")
    d.add_argument("--config", help="settings YAML (default: configs/shapemod/default.yaml's values)")
    d.add_argument("--rounds", type=int_at_least(1), help="rounds (default: the settings', 5)")
    d.add_argument("--proposal-steps", type=int_at_least(1), help="proposal steps per round (default: 10000)")
    d.add_argument("--subsample", type=int_at_least(1), help="sub-programs of the integration subsample "
                                                            "(default: 1000)")
    d.add_argument("--selection", choices=("greedy", "milp"), help="greedy (the reference) or milp (exact)")
    d.add_argument("--search", choices=SEARCHES, help="best-program search: beam (reference) or exact")
    d.add_argument("--split", default="train", choices=SPLITS,
                   help="the corpus split whose shapes are used (train: the val split, the test split of the "
                        "macro models' tables, takes no part)")
    d.add_argument("--limit", type=int_at_least(1), help="a random subset of N shapes (per category)")
    add_seed(d, "seed of --limit's subset and of the searches")
    add_workers(d, "processes for the searches (1: none)")
    d.add_argument("--stop-after", type=float_in(0, MAX_SECONDS_OPTION),
                   help="seconds after which no new round starts")
    d.add_argument("--baseline", action="store_true",
                   help="write the paper's Baseline macros (frequent line sequences, constants where the corpus "
                        "agrees; supplement B) instead of searching")
    d.add_argument("--start-from", metavar="LIBRARY",
                   help="continue from a library (a shipped category's or a file) when --out holds no state: "
                        "its macros are L, the rounds its header records count toward --rounds, and the "
                        "orderings are filtered with it first (a library file does not record them)")
    add_quiet(d, "progress lines")
    rf = add_command(sub, "refactor", cmd_refactor, outputs={"out": "file", "json": "file"})
    rf.add_argument("program", help="corpus id (chair/173) or a ShapeAssembly program file")
    rf.add_argument("--library", default="chair", help="a shipped library's category or a library file")
    rf.add_argument("--search", choices=SEARCHES, default="beam", help="best-program search")
    rf.add_argument("-o", "--out", help="write the macro programs here")
    add_result_options(rf, "f per sub-program, before and after", quiet=None)
    rc = add_command(sub, "refactor-corpus", cmd_refactor_corpus, outputs={"out": "folder"})
    add_category(rc)
    rc.add_argument("--library", required=True, help="a shipped library's category or a library file")
    rc.add_argument("--out", required=True, help="the new folder (must not exist, or be empty), or a new "
                                                 "FILE.tar.xz archive of the same files")
    rc.add_argument("--split", default="all", choices=SPLITS, help="the corpus split")
    rc.add_argument("--limit", type=int_at_least(1), help="a random subset of N shapes of the split")
    add_seed(rc, "seed of --limit's subset")
    rc.add_argument("--search", choices=SEARCHES, default="beam", help="best-program search")
    add_workers(rc, "processes of the pool (1: no pool, everything in this process)", default=2)
    rc.add_argument("--no-check", action="store_true", help="skip reading back and executing every result")
    tb = add_command(sub, "tables", cmd_tables, outputs={"out": "file", "json": "file+"})
    add_category(tb, multiple=True)
    tb.add_argument("--limit", type=int_at_least(1), help="a random subset of N shapes per category")
    add_seed(tb, "seed of --limit's subset")
    tb.add_argument("--library", action="append", help="CATEGORY=FILE: a library file instead of the shipped one")
    tb.add_argument("--extra", action="append", metavar="NAME=FILE",
                    help="a further library (file or shipped category) applied to every category, as a row NAME "
                         "(e.g. one discovered over several categories)")
    tb.add_argument("--note", action="append", help="a line added to the result's notes (repeatable)")
    tb.add_argument("--search", choices=SEARCHES, default="beam", help="best-program search")
    add_workers(tb)
    tb.add_argument("--out", help="also write the table (markdown) here")
    add_result_options(tb, "the table")
    ab = add_command(sub, "ablation", cmd_ablation, outputs={"json": "file+"})
    add_category(ab)
    ab.add_argument("--variants", nargs="+", default=list(ABLATION_VARIANTS), metavar="VARIANT",
                    help="the variants run, quoted: " + ", ".join(f"'{v}'" for v in ABLATION_VARIANTS))
    ab.add_argument("--config", help="settings YAML of the full method (default: configs/shapemod/default.yaml's)")
    ab.add_argument("--rounds", type=int_at_least(1), default=2, help="rounds per variant")
    ab.add_argument("--proposal-steps", type=int_at_least(1), default=300, help="proposal steps per round")
    ab.add_argument("--subsample", type=int_at_least(1), default=1000, help="sub-programs of the integration "
                                                                            "subsample")
    ab.add_argument("--limit", type=int_at_least(1), default=80, help="a random subset of N shapes")
    add_seed(ab, "seed of the subset and of the searches")
    add_workers(ab)
    add_result_options(ab, "f per variant")
    gn = add_command(sub, "generation", cmd_generation, outputs={"json": "file+"})
    add_category(gn)
    gn.add_argument("--weights", help="the VAE over macro programs (default: shapeprog/weights/vae_CATEGORY_macros.pt)")
    gn.add_argument("--base-weights", help="the VAE over ShapeAssembly programs (default: the shipped one)")
    gn.add_argument("--baseline-weights", help="the VAE over programs refactored with the Baseline macros "
                    "(default: shapeprog/weights/vae_CATEGORY_baseline_macros.pt where it ships: chair)")
    gn.add_argument("-n", type=int_at_least(2, MAX_GENERATION_SAMPLES), default=100, help="samples per model")
    add_seed(gn, "seed of the samples and the metrics")
    gn.add_argument("--fool-epochs", type=int_at_least(4), default=12, help="epochs of the %% fool classifier")
    gn.add_argument("--no-stability", action="store_true", help="skip the physics stability test")
    gn.add_argument("--no-ground-truth", action="store_true",
                    help="leave out the corpus val split's row (measured once, then cached on disk)")
    add_workers(gn)
    add_result_options(gn, "the table")
    pc = add_command(sub, "pointcloud", cmd_pointcloud, outputs={"json": "file+"})
    pc.add_argument("--clouds", action="append", required=True, metavar="CATEGORY=FOLDER",
                    help="a category and its make-clouds folder (repeat for several categories)")
    pc.add_argument("--limit", type=int_at_least(1), help="the first N test shapes of each category")
    add_seed(pc, "seed of the inputs' noise, scales and positions")
    pc.add_argument("--no-stability", action="store_true", help="skip the stability test")
    add_workers(pc)
    add_result_options(pc, "the table")
    pt = add_command(sub, "perturbation", cmd_perturbation, outputs={"json": "file+", "png": "file+"})
    add_category(pt)
    pt.add_argument("--library", help="a shipped library's category or a library file (default: --category)")
    pt.add_argument("--n", type=int_at_least(1), default=500, help="train shapes perturbed (a random subset)")
    pt.add_argument("--sigmas", type=float_in(0, MAX_SIGMA), nargs="+", default=list(SIGMAS),
                    help="noise levels (absolute, in the programs' units)")
    pt.add_argument("--repeats", type=int_at_least(1), default=3, help="noise draws per sigma above 0")
    add_seed(pt, "seed of the subset and of the noise")
    pt.add_argument("--png", help="also write the plot here")
    add_result_options(pt, "the FD per sigma")
