"""``python -m shapeprog coder ...``: ShapeCoder, discover abstraction libraries, infer a shape's program with
one, and the paper's Tables 2 and 3.

ShapeCoder reads its own data set (the vendored ``PN_<category>.txt``, one primitive shape per line), not the
ShapeAssembly corpus, so its shapes have their own ids: ``coder-chair:401`` is line 401 of ``PN_chair.txt``
(:func:`shape_of`). A corpus id such as ``chair/401`` names another shape and is refused here.
"""
from __future__ import annotations

import re
import time
from pathlib import Path

from tqdm import tqdm

from shapeio import atomic_write
from shapeio.files import NotShippedError
from shapeio.results import column

from ..cli import (MAX_SECONDS_OPTION, add_category, add_command, add_quiet, add_result_options, add_seed, add_workers,
                   category_pairs, check_outputs, command_line, command_result, float_in, int_at_least, markdown_result,
                   positive_float, progress_log, refuse_existing, worker_pool, write_json)
from ..errors import ParseError
from ..limits import decode
from ..fit import MAX_LR
from . import data, study_commands
from . import tables
from .discover import discover_category
from .config import CONSTANT_OMEGA, Config
from .rules import SCHEMES
from .infer import infer, load_library, load_network, shipped_libraries
from .refactor import MAX_ENODES, MAX_ITERATIONS, TIME_LIMIT, VALUE_SCHEDULES, VALUES
from .search import WAKE_BATCH, WAKE_BATCHES, WAKE_SECONDS, WAKE_STEP_BUDGET

#: ``infer --passes`` at most.
MAX_PASSES = 100
#: A shape of ShapeCoder's data set: ``coder-<category>:<line number of PN_<category>.txt>``.
SHAPE_ID = re.compile(r"coder-(?P<category>[a-z]+):(?P<line>\d+)")
_CORPUS_ID = re.compile(r"(?P<category>[a-z]+)/(?P<line>\d+)")


def shape_of(spec: str):
    """The shape ``spec`` names: a ShapeCoder data-set id (``coder-chair:401``), a file holding one shape
    line, or a shape line itself. A ShapeAssembly corpus id (``chair/401``) is refused with the id it may
    have meant."""
    match = SHAPE_ID.fullmatch(spec)
    if match:
        cat, num = match["category"], int(match["line"])
        if cat not in data.CATEGORIES:
            raise SystemExit(f"error: {spec}: unknown category {cat!r} (ShapeCoder's data set has "
                             f"{', '.join(data.CATEGORIES)})")
        lines = data.read_lines(cat)
        if not 1 <= num <= len(lines):
            raise SystemExit(f"error: {spec}: PN_{cat}.txt has lines 1 to {len(lines)}")
        return data.parse_record(lines[num - 1], f"PN_{cat}.txt", num).prims
    if Path(spec).is_file():
        found = [(n, ln.rstrip("\r")) for n, ln in enumerate(decode(Path(spec).read_bytes(), spec).split("\n"), 1)
                 if ln.strip()]
        if len(found) != 1:
            raise SystemExit(f"error: {spec}: " + ("no shape line" if not found else
                             f"{len(found)} shape lines (the second at line {found[1][0]}); coder infer "
                             "reads one shape (coder tables evaluates many)"))
        return data.parse_record(found[0][1], spec, found[0][0]).prims
    if Path(spec).is_dir():
        raise SystemExit(f"error: {spec}: is a folder, not a shape file")
    corpus_id = _CORPUS_ID.fullmatch(spec)
    if corpus_id:
        raise SystemExit(f"error: {spec}: a ShapeAssembly corpus id, which ShapeCoder does not read; its shapes "
                         f"are lines of its own data set: coder-{corpus_id['category']}:{corpus_id['line']} is "
                         f"line {corpus_id['line']} of PN_{corpus_id['category']}.txt (another shape)")
    if "(" not in spec:  # a shape line always has a program: this is a file name
        raise SystemExit(f"error: {spec}: no such file (nor a PN_<category>.txt line or an id coder-<category>:<line>)")
    return spec


def add_search_budget(parser, prefix: str, needs: str) -> None:
    """``--{prefix}search-step-budget --{prefix}search-batches --{prefix}search-seconds``: the recognition
    network's search budget per step of post hoc inference, a count (the wake's by default, standing for the
    paper's 1 s), and its safety cap in seconds (used with ``needs``)."""
    parser.add_argument(f"--{prefix}search-step-budget", type=int_at_least(1), default=WAKE_STEP_BUDGET,
                        metavar="U", help=f"with {needs}: the budget of a search step: a batch on n primitives "
                                          "costs n + 7 units (the wake's budget stands for the paper's 1 s on an idle "
                                          "CPU; another is ours)")
    parser.add_argument(f"--{prefix}search-batches", type=int_at_least(1), default=WAKE_BATCHES, metavar="N",
                        help=f"with {needs}: batches of {WAKE_BATCH} samples per search step at most")
    parser.add_argument(f"--{prefix}search-seconds", type=positive_float, default=WAKE_SECONDS, metavar="S",
                        help=f"with {needs}: a safety cap in seconds per search step, not the budget (the default "
                             "does not bind on a loaded machine)")


def search_budget(seconds: float, batches: int, step_budget: int, network: bool, prefix: str, needs: str) -> dict:
    """``infer``'s budget keywords; a budget other than the wake's without the network is refused."""
    if (seconds, batches, step_budget) != (WAKE_SECONDS, WAKE_BATCHES, WAKE_STEP_BUDGET) and not network:
        raise SystemExit(f"error: --{prefix}search-step-budget / --{prefix}search-batches / "
                         f"--{prefix}search-seconds need {needs}")
    return {"search_seconds": seconds, "search_batches": batches, "search_step_budget": step_budget}


def add_egraph_limits(parser) -> None:
    """``--iterations --max-nodes --time-limit``: the e-graph limits of each ShapeCoder refactor call (the
    paper's counts by default, the seconds a safety cap only; checked by :mod:`shapeprog.coder.refactor`
    before any work), and ``--egraph-values``."""
    parser.add_argument("--iterations", type=int_at_least(0, 1000), default=MAX_ITERATIONS,
                        help="e-graph iterations per refactor call (the paper's)")
    parser.add_argument("--max-nodes", type=int_at_least(1, 10_000_000), default=MAX_ENODES,
                        help="e-node limit per refactor call (the paper's); larger e-graphs find cheaper "
                             "programs at more time (docs/shapecoder.md)")
    parser.add_argument("--time-limit", type=float_in(0, 3600, low_open=True), default=TIME_LIMIT,
                        help="a safety cap in seconds per refactor call, not the budget (the paper's 5 s made "
                             "results depend on the machine's load; the default does not bind)")
    parser.add_argument("--egraph-values", choices=VALUE_SCHEDULES, default=VALUES,
                        help=f"the e-graph's value table: {VALUES} (as the reference: up to date before every "
                             "iteration) or lagged (one iteration behind, as runs made before 2026-11-29; to "
                             "reproduce them)")


def cmd_discover(args) -> int:
    """discover a library of abstractions for a category

    Run ShapeCoder's discovery (wake by e-graph refactoring or, with --wake network, with dreams and a recognition
    network; proposal, integration, removal sweep; a final wake with the library fixed) on the first N discovery shapes
    of a PartNet category; write library.txt, programs.txt, log.json and a resumable state.json into --out (an earlier
    run's folder is continued, never overwritten).

    Example: coder discover --category chair --out runs/chair_abs --workers 2"""
    category = args.category
    progress = None
    if not args.quiet:
        progress = lambda it, total, desc: tqdm(it, total=total, desc=desc, leave=False)  # noqa: E731
    try:
        cfg = Config(rounds=args.rounds, n_proposals=args.proposals, n_abstractions=args.abstractions,
                     seed=args.seed, wake=args.wake, n_dreams=args.dreams, train_seconds=60.0 * args.train_minutes,
                     train_epochs=args.train_epochs, train_lr=args.train_lr, dropout=args.dropout,
                     wake_seconds=args.wake_seconds, wake_step_budget=args.wake_step_budget,
                     wake_batches=args.wake_batches, device=args.device, iterations=args.iterations,
                     max_nodes=args.max_nodes, time_limit=args.time_limit, egraph_values=args.egraph_values,
                     semantic_rewrites=not args.no_semantic_rewrites, network_from=args.network_from_round,
                     wake_repeats=args.wake_repeats, scheme=args.scheme, preferences=not args.no_preferences)
    except ValueError as e:  # a setting out of range, named
        raise SystemExit(f"error: {e}") from None
    start = None
    if args.start_round is not None and not args.start_from:
        raise SystemExit("error: --start-round needs --start-from")
    if args.start_from:
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


def cmd_infer(args) -> int:
    """infer one shape's program with a discovered library

    Post hoc inference: refactor the naive program of one shape with a library's abstractions; print the program, its
    expansion, its cost and error. A shape of ShapeCoder's data set is named coder-<category>:<line> (a line of the
    vendored PN_<category>.txt), not by a corpus id.

    Example: coder infer coder-chair:401 --library chair"""
    check_outputs(others=[args.json])
    refuse_existing([args.json], args.overwrite)
    try:
        lib = load_library(args.library)
    except NotShippedError as e:
        raise SystemExit(f"error: {e}") from None
    shape = shape_of(args.shape)
    network = None
    budget = search_budget(args.search_seconds, args.search_batches, args.search_step_budget, args.network, "",
                           "--network")
    if args.network:
        if Path(args.library).is_file() or args.library not in shipped_libraries():
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
    write_json(args, command_result(args, f"ShapeCoder inference of {args.shape} with {args.library}",
                                    [column("shape", "shape"), column("cost", "cost", 2), column("error", "error", 4),
                                     column("stop", "e-graph"), column("program", "program")],
                                    [{"shape": args.shape, "cost": float(r.cost), "error": float(r.error),
                                      "stop": str(r.stop), "program": r.text}], [f"expanded: {r.expanded}"]))
    return 0


def cmd_tables(args) -> int:
    """ShapeCoder Tables 2 and 3 of discovered libraries

    Write the ShapeCoder paper's Table 2 (Input Prims and ShapeCoder rows: F, |L|, Num Struct, Num Param on the
    discovery shapes) and Table 3 (F of the discovered programs, and post hoc inference on the first --train discovery
    and --heldout held-out shapes) for the shipped libraries or coder discover folders, beside the paper's rows.

    Example: coder tables --category chair table storage --workers 2 --out shapecoder_tables.md"""
    runs = category_pairs(args.library, "CATEGORY=FOLDER")
    baselines = {kind: category_pairs(getattr(args, f"baseline_{kind}"), "CATEGORY=FOLDER", f"--baseline-{kind}")
                 for kind in ("input", "wake")}
    for flag, given in (("--library", runs), ("--baseline-input", baselines["input"]),
                        ("--baseline-wake", baselines["wake"])):
        unknown = sorted(set(given) - set(args.category))
        if unknown:
            raise SystemExit(f"error: {flag} {unknown[0]}=...: {unknown[0]} is not among --category")
    check_outputs(others=[args.out])
    refuse_existing([args.out, args.json], args.overwrite)
    limits = {"iterations": args.iterations, "max_nodes": args.max_nodes, "time_limit": args.time_limit,
              "values": args.egraph_values}
    budget = search_budget(args.phi_search_seconds, args.phi_search_batches, args.phi_search_step_budget,
                           args.phi_network, "phi-", "--phi-network")
    command = command_line(args)
    parts = [f"# ShapeCoder Tables 2 and 3\n\n# command: {command}"]
    progress = progress_log(args)
    # workers forked after this process ran torch can hang: with a network they start from a fresh interpreter
    with worker_pool(args.workers, "forkserver" if args.phi_network else None) as pool:
        for cat in args.category:
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
    if args.out:
        atomic_write(args.out, "\n\n".join(parts) + "\n")
        print(f"wrote {args.out}")
    write_json(args, markdown_result("\n\n".join(parts[1:]), "ShapeCoder Tables 2 and 3", command))
    return 0


def register(sub) -> None:
    """Add the ``coder`` commands to ``sub``."""
    d = add_command(sub, "discover", cmd_discover, outputs={"out": "folder"})
    add_category(d)
    d.add_argument("--out", required=True, help="output folder (an earlier run's folder resumes it)")
    d.add_argument("--rounds", type=int_at_least(0), default=4, help="proposal/integration rounds (paper: 4)")
    d.add_argument("--shapes", type=int_at_least(1), default=400, help="the first N discovery shapes (paper: 400)")
    d.add_argument("--proposals", type=int_at_least(1), default=10000, help="proposals per round (paper: 10,000)")
    d.add_argument("--abstractions", type=int_at_least(1), default=20, help="candidates tried per round (N_A)")
    add_seed(d, "seed of the proposals", default=42)
    add_workers(d, "processes for the per-program refactors", default=2)
    d.add_argument("--minutes", type=float_in(0, MAX_SECONDS_OPTION / 60),
                   help="start no phase after this many minutes: ends this session, not the run (the folder "
                        "resumes where it stopped; the run's result is set by --rounds and the counts, not by this)")
    d.add_argument("--wake", choices=("refactor", "network"), default="refactor",
                   help="wake search: by refactoring only, or with dreams and a recognition network")
    d.add_argument("--dreams", type=int_at_least(1), default=10000,
                   help="network wake: valid dreams per function (N_D, paper: 10,000)")
    d.add_argument("--train-minutes", type=float_in(0, MAX_SECONDS_OPTION / 60), default=200.0,
                   help="network wake: training budget per round in minutes (paper: 200)")
    d.add_argument("--train-epochs", type=int_at_least(1), default=300, help="network wake: epochs at most")
    d.add_argument("--train-lr", type=float_in(0, MAX_LR, low_open=True), default=1e-4,
                   help="network wake: Adam learning rate")
    d.add_argument("--dropout", type=float_in(0, 1, high_open=True), default=0.5,
                   help="network wake: the network's dropout")
    d.add_argument("--wake-step-budget", type=int_at_least(1), default=WAKE_STEP_BUDGET,
                   help="network wake: the budget of a search step (a batch on n primitives costs n + 7 units; the "
                        "default stands for the paper's 1 s on an idle CPU)")
    d.add_argument("--wake-batches", type=int_at_least(1), default=WAKE_BATCHES,
                   help=f"network wake: batches of {WAKE_BATCH} samples per search step at most")
    d.add_argument("--wake-seconds", type=float_in(0, MAX_SECONDS_OPTION, low_open=True), default=WAKE_SECONDS,
                   help="network wake: a safety cap in seconds per search step, not the budget (does not bind "
                        "by default)")
    d.add_argument("--device", default="auto", help="network wake: where to train (auto: CUDA when available)")
    d.add_argument("--network-from-round", type=int_at_least(0), default=0,
                   help="network wake: the first round that uses the network; earlier rounds use the refactor-only "
                        "wake (0: every round, the paper)")
    d.add_argument("--wake-repeats", type=int_at_least(1), default=1,
                   help="network wake: wakes per round with the round's network, each from the last one's programs "
                        "with other sampling seeds (1: the paper)")
    d.add_argument("--start-from", metavar="LIBRARY",
                   help="begin with an earlier run's library and programs: a shipped category (chair) or a "
                        "coder discover output folder; e.g. with --wake network, the final wake again with "
                        "the recognition network")
    d.add_argument("--start-round", type=int_at_least(0),
                   help="with --start-from: the round whose wake comes first (default: --rounds, only the final "
                        "wake)")
    d.add_argument("--no-semantic-rewrites", action="store_true",
                   help="refactor with the abstraction rules only (the paper's 'no semantic rewrites' ablation; "
                        "with the default wake, the structure-only library-learning baseline of coder tables "
                        "--baseline-input / --baseline-wake)")
    d.add_argument("--scheme", choices=SCHEMES, default="conditional",
                   help="the e-graph's rewrites: value-guarded (the paper's) or naive, plain rewrites over "
                        "relations (the paper's 'no conditional rewrites' ablation)")
    d.add_argument("--no-preferences", action="store_true",
                   help=f"every abstraction's omega {CONSTANT_OMEGA:g} and proposals ranked without the preference "
                        "score (the paper's 'no preferences' ablation)")
    add_egraph_limits(d)
    add_quiet(d, "progress bars")
    a = add_command(sub, "infer", cmd_infer, outputs={"json": "file+"})
    a.add_argument("shape", help="coder-<category>:<line number> of the vendored data (e.g. coder-chair:401), a "
                                 "PN_<category>.txt line, or a file with one such line")
    a.add_argument("--library", required=True, help="a shipped category (chair) or a library.txt file")
    add_egraph_limits(a)
    a.add_argument("--passes", type=int_at_least(1, MAX_PASSES), default=3,
                   help="refactor calls at most, each on the previous result")
    a.add_argument("--network", action="store_true",
                   help="also search with the shipped library's recognition network (the paper's post hoc "
                        "inference; slower)")
    add_search_budget(a, "", "--network")
    add_result_options(a, "the program, its cost and error", quiet=None)
    t2 = add_command(sub, "tables", cmd_tables, outputs={"out": "file", "json": "file+"})
    add_category(t2, multiple=True)
    t2.add_argument("--library", action="append",
                    help="CATEGORY=FOLDER: a coder discover output folder instead of the shipped library")
    t2.add_argument("--baseline-input", action="append", metavar="CATEGORY=FOLDER",
                    help="a coder discover folder of the same shapes run with --no-semantic-rewrites from "
                         "the naive programs: Table 2's structure-only row beside the paper's ShapeMOD+Input (ours)")
    t2.add_argument("--baseline-wake", action="append", metavar="CATEGORY=FOLDER",
                    help="the same, started (--start-from, --start-round 0) from the programs of one wake with the "
                         "semantic rewrites: the row beside the paper's ShapeMOD+Wake (ours)")
    t2.add_argument("--train", type=int_at_least(1), default=100, help="train-PHI: the first N discovery shapes")
    t2.add_argument("--heldout", type=int_at_least(1), default=100, help="validation-PHI: the first N held-out shapes")
    add_workers(t2, "processes for the per-shape inference (1: everything in this process)", default=2)
    add_egraph_limits(t2)
    t2.add_argument("--phi-network", action="store_true",
                    help="post hoc inference with the library's recognition network as well (the paper's; the "
                         "shipped <category>_recnet.pt, or a run folder's last recnet_round<k>.pt); without it: "
                         "refactoring only")
    add_search_budget(t2, "phi-", "--phi-network")
    t2.add_argument("--out", help="also write the tables (markdown) here, atomically")
    add_result_options(t2, "the tables")
    study_commands.register(sub)
