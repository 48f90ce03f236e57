"""``python -m shapeprog coder ablation | perturbation | noise | sample``: the ShapeCoder paper's studies beyond
its Tables 2 and 3 (Table 4's ablations and perturbation FD, noisy input, sampling), each writing a result file.
:mod:`shapeprog.coder.commands` registers them beside the other ``coder`` commands."""
from __future__ import annotations

import random
from types import SimpleNamespace

from shapeio.results import column

from ..cli import (MAX_SECONDS_OPTION, add_category, add_command, add_result_options, add_seed, add_workers,
                   command_result, float_in, int_at_least, progress_log, refuse_existing, worker_pool, write_json)
from ..fit import MAX_LR
from . import data, tables
from ..vae.genmetrics import frechet_distance
from .config import Config
from .execute import corners, order
from .lang import Num, substitute
from .objective import naive_program, naive_summary
from .studies import PieceSampler, execute_corners, free_numbers, noisy, perturbation_fd, shape_features
from .search import WAKE_STEP_BUDGET


def cmd_ablation(args) -> int:
    """the paper's Table 4 (left): discovery ablations

    Discovery on the first --shapes discovery shapes once per ablation row (the network wake; the refactor-only wake; no
    abstraction; a single round; no semantic rewrites; the naive rewrite scheme; no preferences), same shapes, seed and
    counts; F, |L|, Num Struct, Num Param per row beside the paper's F.

    Example: coder ablation --category chair --shapes 20 --rounds 1 --proposals 100 --abstractions 4
        --rows 'no abstraction' 'single iteration' --json ablation.json"""
    from . import ablation  # lazy: loaded when the command runs

    refuse_existing([args.json], args.overwrite)
    rows = args.rows or list(ablation.DEFAULT_ROWS)
    unknown = [r for r in rows if r not in ablation.ROWS]
    if unknown:
        raise SystemExit(f"error: --rows: unknown row {unknown[0]!r}; rows: {', '.join(ablation.ROWS)}")
    try:
        base = Config(rounds=args.rounds, n_proposals=args.proposals, n_abstractions=args.abstractions,
                      seed=args.seed)
        network = {"n_dreams": args.dreams, "train_epochs": args.train_epochs, "train_lr": args.train_lr,
                   "dropout": args.dropout, "train_seconds": 60.0 * args.train_minutes, "device": "cpu",
                   "wake_step_budget": args.wake_step_budget}
        ablation.row_configs(base, network)  # every row's settings checked before any work
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    shapes = data.load(args.category)[:args.shapes]
    network_rows = any(ablation.ROWS[r].get("wake") == "network" for r in rows)
    # workers forked after this process ran torch can hang: with a network they start from a fresh interpreter
    with worker_pool(args.workers, "forkserver" if network_rows else None) as pool:
        got = ablation.ablation(shapes, base, rows, network=network, executor=pool, progress=progress_log(args))
    paper = ablation.PAPER_TABLE4_LEFT.get(args.category, {})
    naive = naive_summary(s.prims for s in shapes)
    table = [{"row": "naive programs (input primitives)", "F": naive.F, "L": 6, "struct": naive.num_struct,
              "param": naive.num_param, "seconds": None, "paper": None}]
    table += [{"row": r.name, "F": r.summary.F, "L": r.summary.library_size, "struct": r.summary.num_struct,
               "param": r.summary.num_param, "seconds": r.seconds, "paper": paper.get(r.name)} for r in got]
    for r in table:
        print(f"{r['row']}: F {r['F']:.2f}, |L| {r['L']}" + (f", paper {r['paper']}" if r["paper"] else ""))
    notes = [f"{len(shapes)} {args.category} discovery shapes, {args.rounds} rounds of {args.proposals} proposals, "
             f"{args.abstractions} candidates per round, seed {args.seed}; the paper: 400 shapes, 4 rounds of 10,000 "
             "proposals, 20 candidates (its F figures are beside ours only as an ordering).",
             "The ablations are taken from the refactor-only wake (the 'no dream + wake' row); the paper ablates "
             "from its full method. The dream + wake row: " f"{args.dreams} dreams per function, "
             f"{args.train_epochs} training epochs (lr {args.train_lr:g}, dropout {args.dropout:g}) per round, a "
             f"search step budget of {args.wake_step_budget} units (the wake's {WAKE_STEP_BUDGET}: about the "
             "paper's 1 s).",
             *([] if "no conditional rewrites" in rows else
               ["The 'no conditional rewrites' row (the naive rewrite scheme, --rows 'no conditional rewrites') is "
                "not run: its e-graphs need about 3 GB per refactor of an 11-primitive chair and more than 4 GB at "
                "16; the paper's did not finish one abstraction phase in 3 days."]),
             "F is the paper's objective for every row (omega from the preferences, also for 'no preferences', "
             "which discovered with a constant omega)."]
    cols = [column("row", "row"), column("F", "F", 1), column("L", "|L|"), column("struct", "Num Struct", 1),
            column("param", "Num Param", 1), column("seconds", "wall s", 0), column("paper", "paper F (chair)", 1)]
    write_json(args, command_result(args, f"ShapeCoder Table 4 (left): ablations ({args.category})", cols, table,
                                    notes))
    return 0


def _naive_programs(prims_list):
    """The naive programs (every number a literal) of primitive sets."""

    out = []
    for prims in prims_list:
        naive, env = naive_program(prims)
        out.append(substitute(naive, {k: Num(v) for k, v in env.items()}))
    return out


def _heldout_features(category: str, heldout: int, seed: int):
    """The PointNet features of the first ``heldout`` held-out shapes, and how many."""

    recs = data.load(category, "heldout")[:heldout]
    return shape_features([corners(r.prims) for r in recs], seed=seed), len(recs)


def _shipped_run(category: str):
    """The shipped discovery run of ``category`` (its library and programs) and the data set's shapes by key."""
    try:
        run = tables.shipped(category)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    return run, {r.key: r for r in data.load(category, "all")}


def cmd_perturbation(args) -> int:
    """the paper's Table 4 (right): FD of perturbed programs with and without abstractions

    Perturb every free number of the shipped library's programs and of the naive programs of the same shapes by sigma
    N(0, 1), execute, and compare with held-out shapes by the FD of the generation tables' PointNet features.

    Example: coder perturbation --category chair --shapes 50 --heldout 100 --sigmas 0 0.05 --json perturbation.json"""
    refuse_existing([args.json], args.overwrite)
    run, recs = _shipped_run(args.category)
    programs = list(run.programs[:args.shapes])
    naive = _naive_programs(recs[k].prims for k in run.keys[:args.shapes])
    ref, n_ref = _heldout_features(args.category, args.heldout, args.seed)
    rows = []
    for name, progs in (("no abstractions (naive programs)", naive), ("ShapeCoder (shipped library)", programs)):
        free = sum(free_numbers(p) for p in progs) / len(progs)
        got = perturbation_fd(progs, run.library, ref, args.sigmas, args.draws, args.seed)
        for sigma in args.sigmas:
            fds = [fd for s, _, fd, _ in got if s == sigma]
            failed = sum(f for s, _, _, f in got if s == sigma)
            rows.append({"programs": name, "sigma": sigma, "free": free, "fd": sum(fds) / len(fds),
                         "fd_min": min(fds), "fd_max": max(fds), "failed": failed})
            if not args.quiet:
                print(f"{name}, sigma {sigma:g}: FD {rows[-1]['fd']:.2f} ({len(fds)} draws, {failed} failed)",
                      flush=True)
    notes = [f"{len(programs)} {args.category} discovery shapes' programs (the shipped library's, and the naive "
             f"programs of the same shapes), each free number + sigma N(0, 1); FD of the PointNet features "
             f"(shapeprog.vae.genmetrics' classifier, 2,500 points per shape) against the first {n_ref} held-out "
             f"shapes; the mean of {args.draws} noise draws per sigma (the same draws for both program sets); a "
             "program that no longer executes (a non-positive dimension) is left out of its draw (failed).",
             "The paper's Table 4 (right) figures are not in the spec; the protocol follows ShapeMOD's Fig. 7."]
    cols = [column("programs", "programs"), column("sigma", "sigma"), column("free", "free numbers / program", 1),
            column("fd", "FD", 2), column("fd_min", "FD min", 2), column("fd_max", "FD max", 2),
            column("failed", "failed")]
    write_json(args, command_result(args, f"ShapeCoder Table 4 (right): FD of perturbed programs ({args.category})",
                                    cols, rows, notes))
    return 0


def cmd_noise(args) -> int:
    """section 7.5: post hoc inference on noisy primitive input

    Post hoc inference with the shipped library on held-out shapes whose primitives got Gaussian noise (dimensions and
    positions), per sigma; F as Table 3's.

    Example: coder noise --category chair --heldout 20 --sigmas 0 0.02 --json noise.json"""
    refuse_existing([args.json], args.overwrite)
    try:
        run = tables.shipped(args.category)
        network = tables.network_of(run) if args.network else None
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    recs = [r for r in data.load(args.category, "heldout")[:args.heldout] if len(r.prims) <= run.library.lang.max_prims]
    rows = []
    with worker_pool(args.workers, "forkserver" if args.network else None) as pool:  # as in cmd_ablation
        for sigma in args.sigmas:
            rng = random.Random(f"{args.seed}:{sigma!r}")
            shapes = [SimpleNamespace(prims=order(noisy(r.prims, sigma, rng))) for r in recs]
            row = tables.phi(f"sigma {sigma:g}", shapes, run.library, executor=pool, network=network)
            rows.append({"sigma": sigma, "shapes": row.shapes, "F": row.F, "used": row.used, "cpu": row.cpu})
            if not args.quiet:
                print(f"sigma {sigma:g}: F {row.F:.2f} over {row.shapes} shapes", flush=True)
    how = "the recognition network's search and refactoring" if args.network else "refactoring only"
    notes = [f"Post hoc inference ({how}, default budgets) with the shipped {args.category} library on the first "
             f"{args.heldout} held-out shapes (those with at most 16 primitives), each primitive's dimensions and "
             "position + sigma N(0, 1), rounded to 2 decimals, dimensions at least 0.01; F as Table 3's (programs "
             "plus the library's omega; the error term measures the distance to the noisy primitives).",
             "The paper's section 7.5 protocol and figures are not in the spec: this is ours."]
    cols = [column("sigma", "sigma"), column("shapes", "shapes"), column("F", "F", 2),
            column("used", "abstractions used"), column("cpu", "CPU s / shape", 2)]
    title = f"ShapeCoder section 7.5: post hoc inference on noisy primitives ({args.category})"
    write_json(args, command_result(args, title, cols, rows, notes))
    return 0


def cmd_sample(args) -> int:
    """section 7.6 (partial): a piece sampler over programs with and without abstractions

    Fit a simple generative model (pieces per program, piece templates by frequency, a Gaussian per template number) to
    the shipped library's programs and to the naive programs of the same shapes; sample, execute, FD against held-out
    shapes.

    Example: coder sample --category chair -n 50 --heldout 100 --json sample.json"""
    refuse_existing([args.json], args.overwrite)
    run, recs = _shipped_run(args.category)
    ref, n_ref = _heldout_features(args.category, args.heldout, args.seed)
    rows = []
    for name, progs in (("no abstractions (naive programs)", _naive_programs(recs[k].prims for k in run.keys)),
                        ("ShapeCoder (shipped library)", list(run.programs))):
        model = PieceSampler.fit(progs)
        rng = random.Random(args.seed)
        samples = [model.sample(rng) for _ in range(args.n)]
        valid = sum(execute_corners(p, run.library) is not None for p in samples)
        ok = [c for c in (execute_corners(p, run.library, strict=False) for p in samples) if c is not None]
        fd = frechet_distance(shape_features(ok, seed=args.seed), ref) if len(ok) >= 2 else None
        train_fd = frechet_distance(shape_features([execute_corners(p, run.library) for p in progs],
                                                   seed=args.seed), ref)
        rows.append({"model": name, "templates": len(model.templates), "valid": valid / len(samples), "fd": fd,
                     "fd_programs": train_fd})
        if not args.quiet:
            print(f"{name}: {len(model.templates)} templates, valid {valid}/{len(samples)}, FD {fd}", flush=True)
    notes = [f"A piece sampler fitted to the {len(run.programs)} {args.category} discovery programs: the number of "
             "top-level pieces and each piece's template (its numbers abstracted) by frequency, the numbers from a "
             f"Gaussian per template slot; {args.n} samples, FD of the PointNet features against the first {n_ref} "
             "held-out shapes (valid: samples that execute without a hard error, e.g. a non-positive dimension; FD over "
             "every sample, dimensions as magnitudes of at least 0.01); 'FD, fitted programs' is the "
             "FD of the programs the model was fitted to.",
             "Not the paper's generative model (section 7.6 trains a deep model over programs with abstractions; "
             "its protocol and figures are not in the spec)."]
    cols = [column("model", "model"), column("templates", "templates"), column("valid", "valid %", 1, 100),
            column("fd", "FD", 2), column("fd_programs", "FD, fitted programs", 2)]
    write_json(args, command_result(args, f"ShapeCoder section 7.6: a piece sampler over programs ({args.category})",
                                    cols, rows, notes))
    return 0


def _heldout_command(sub, name: str, fn, heldout: int, heldout_help: str, low: int = 2):
    """A study command writing JSON rows, with ``--category`` and ``--heldout`` (the first N held-out shapes)."""
    p = add_command(sub, name, fn, outputs={"json": "file+"})
    add_category(p)
    p.add_argument("--heldout", type=int_at_least(low), default=heldout, help=heldout_help)
    return p


def register(sub) -> None:
    """Add the study commands to ``sub``."""
    ab = add_command(sub, "ablation", cmd_ablation, outputs={"json": "file+"})
    add_category(ab)
    ab.add_argument("--shapes", type=int_at_least(1), default=60, help="the first N discovery shapes (paper: 400)")
    ab.add_argument("--rounds", type=int_at_least(1), default=2, help="proposal/integration rounds (paper: 4)")
    ab.add_argument("--proposals", type=int_at_least(1), default=300, help="proposals per round (paper: 10,000)")
    ab.add_argument("--abstractions", type=int_at_least(1), default=8, help="candidates tried per round (paper: 20)")
    add_seed(ab, "seed of the proposals", default=42)
    ab.add_argument("--rows", nargs="+", metavar="ROW",
                    help="the rows to run (default: all but 'no conditional rewrites', whose naive e-graphs need "
                         "more than 4 GB per refactor of a 16-primitive chair)")
    ab.add_argument("--dreams", type=int_at_least(1), default=200, help="the network row: dreams per function")
    ab.add_argument("--train-epochs", type=int_at_least(1), default=3, help="the network row: training epochs per round")
    ab.add_argument("--train-lr", type=float_in(0, MAX_LR, low_open=True), default=1e-3,
                    help="the network row: Adam learning rate")
    ab.add_argument("--dropout", type=float_in(0, 1, high_open=True), default=0.1, help="the network row: dropout")
    ab.add_argument("--train-minutes", type=float_in(0, MAX_SECONDS_OPTION / 60, low_open=True), default=120.0,
                    help="the network row: a safety cap on each round's training, not the budget (the epochs are)")
    ab.add_argument("--wake-step-budget", type=int_at_least(1), default=36,
                    help=f"the network row: the search's budget per step (the wake's default is {WAKE_STEP_BUDGET}, "
                         "about the paper's 1 s; less keeps the row to minutes on a CPU)")
    add_workers(ab, "processes for the refactors", default=2)
    add_result_options(ab, "the rows")
    pe = _heldout_command(sub, "perturbation", cmd_perturbation, 700, "the first N held-out shapes (reference)")
    pe.add_argument("--shapes", type=int_at_least(2), default=400, help="the first N discovery shapes' programs")
    pe.add_argument("--sigmas", type=float_in(0, 10), nargs="+", default=[0.0, 0.025, 0.05, 0.1],
                    help="noise standard deviations")
    pe.add_argument("--draws", type=int_at_least(1), default=2, help="noise draws per sigma > 0")
    add_seed(pe, "seed of the noise and the surface points")
    add_result_options(pe, "the rows")
    no = _heldout_command(sub, "noise", cmd_noise, 100, "the first N held-out shapes", low=1)
    no.add_argument("--sigmas", type=float_in(0, 1), nargs="+", default=[0.0, 0.01, 0.02, 0.03],
                    help="noise standard deviations (0: the clean shapes)")
    add_seed(no, "seed of the noise")
    no.add_argument("--network", action="store_true", help="with the recognition network's search as well")
    add_workers(no, "processes for the inference", default=2)
    add_result_options(no, "the rows")
    sa = _heldout_command(sub, "sample", cmd_sample, 700, "the first N held-out shapes (reference)")
    sa.add_argument("-n", type=int_at_least(2), default=300, help="samples per model")
    add_seed(sa, "seed of the samples and the surface points")
    add_result_options(sa, "the rows")
