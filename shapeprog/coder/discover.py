"""The ShapeCoder discovery loop: wake (search by refactoring, or with the recognition network), proposal,
integration, and a final round with the library fixed. Per-program work goes through a
``concurrent.futures.Executor`` from the caller.

One round (``rounds`` of them, then a final wake with the library fixed):

1. **Wake** (:func:`~shapeprog.coder.wake.wake`, ``Config.wake="refactor"``, the default): each shape's candidates (its current
   program, the same with every abstraction expanded, and the naive program) are refactored with the
   current library (:func:`shapeprog.coder.refactor.refactor`); the cheapest that re-covers the shape's
   primitives (a valid Hungarian match of every primitive, :func:`shapeprog.coder.objective.match`) is
   kept. With ``Config.wake="network"`` (:func:`~shapeprog.coder.wake.wake_network`) the round first dreams
   (:func:`shapeprog.coder.dream.dream`) and trains a recognition network on the dreams
   (:mod:`shapeprog.coder.train`; the weights are written to ``out/recnet_round<k>.pt`` and reused on a
   resume); each shape is then searched with the network (:func:`shapeprog.coder.search.search_shape`),
   the covering expressions join the shape's store, and the network's program, the store's
   replacements (variant iii) and greedy rebuild (variant iv) are refactored together with the
   refactor-only candidates; the cheapest is kept, so the network wake is never worse than the
   refactor-only wake for the same program.
2. **Proposal** (:func:`shapeprog.coder.proposal.propose`): the top ``n_abstractions`` candidates.
3. **Integration** (:func:`integrate`): for each candidate in rank order, the library plus the candidate
   refactors the programs it covers (input and expanded); it is accepted when F strictly decreases;
   otherwise, when abstractions lost more than half their uses (f_dec), the library without them is
   tried. After an acceptance the weights of the covered programs are halved.
4. **Removal sweep**: each abstraction is removed in turn (its calls expanded, the programs that used it
   refactored); a removal is kept when F strictly decreases.

A program's cost is its :func:`~shapeprog.coder.objective.program_cost` plus λ_e (10) times the mean
matched distance to its shape's primitives; F adds ω of each abstraction.

State (the library, the programs, the log of F per phase) is written atomically to ``out/state.json``
after every phase; a run started again on the same folder resumes after the last finished phase.
"""
from __future__ import annotations

import concurrent.futures as cf
import hashlib
import json
import multiprocessing
import random
import time
from dataclasses import dataclass, field, asdict
from pathlib import Path
from typing import Callable, Sequence

from shapeio import atomic_write

from shapeio.files import parse_json

from .lang import LANG_3D, Call, Expr, Lang, Library, ProgramError, expand, parse, to_text, walk
from .objective import WEIGHTS, omega, preference, token_counts
from .proposal import propose
from .refactor import TIME_LIMIT, VALUES, RefactorError
from .config import CONSTANT_OMEGA, Config
from .wake import _best_of, _limits, _map, evaluate, train_network, wake, wake_network
from . import data
from ..errors import ParseError
from ..limits import decode

__all__ = [
    "DiscoveryResult",
    "Summary",
    "discover",
    "discover_category",
    "integrate",
    "library_cost",
    "start_from",
    "summarize",
    "write_outputs",
]


@dataclass(frozen=True)
class Summary:
    """F and the paper's Table 2 columns for a library and its programs.

    Attributes:
        F: mean program cost (tokens + 10 · error) + Σ ω.
        programs: the mean program cost alone.
        library_size: |L| (base shape functions + abstractions).
        num_struct: mean shape-function tokens per program.
        num_param: mean free-float and categorical tokens per program.
        shapes: how many programs.
    """

    F: float
    programs: float
    library_size: int
    num_struct: float
    num_param: float
    shapes: int


def summarize(programs: Sequence[Expr], library: Library, errors: Sequence[float] | None = None) -> Summary:
    """The :class:`Summary` of ``programs`` (with geometric ``errors``, 0 by default) under ``library``."""
    if not programs:
        raise ValueError("no programs")
    errors = [0.0] * len(programs) if errors is None else list(errors)
    n = len(programs)
    counts = [token_counts(p, library) for p in programs]
    prog = sum(c.cost(WEIGHTS) + WEIGHTS.error * e for c, e in zip(counts, errors)) / n
    lib_cost = sum(omega(ab, library) for ab in library.abstractions)
    return Summary(prog + lib_cost, prog, library.size, sum(c.num_struct for c in counts) / n,
                   sum(c.num_param for c in counts) / n, n)


def library_cost(library: Library, cfg: Config = Config()) -> float:
    """Σ ω of ``library``'s abstractions as discovery with ``cfg`` counts it: :func:`~shapeprog.coder.objective.omega`
    (the preferences), or :data:`~shapeprog.coder.config.CONSTANT_OMEGA` each with ``cfg.preferences`` off (an
    abstraction ω rejects costs 0.5 either way)."""
    if cfg.preferences:
        return sum(omega(ab, library) for ab in library.abstractions)
    return sum(omega(ab, library) if preference(ab, library) is None else CONSTANT_OMEGA
               for ab in library.abstractions)


def _uses(programs: Sequence[Expr], name: str) -> int:
    return sum(1 for p in programs for n in walk(p) if isinstance(n, Call) and n.fn == name)


def integrate(shapes: Sequence, programs: list, costs: list, errors: list, library: Library, candidates: list,
              cfg: Config = Config(), executor: cf.Executor | None = None, weights: list | None = None,
              log: Callable | None = None, progress: Callable | None = None, start_index: int = 0) -> tuple:
    """Integration of ranked candidates (``[(rank, Candidate)]``, see the module docstring); new
    abstractions are named ``A<k>`` from ``start_index`` on. Returns ``(library, programs, costs, errors,
    accepted names, next index)``."""
    prims = [getattr(s, "prims", s) for s in shapes]
    n = len(prims)
    weights = [1.0] * n if weights is None else weights
    accepted = []
    index = start_index

    def F(lib, cs):
        return sum(cs) / n + library_cost(lib, cfg)

    def trial(lib, progs, idx, costs, errors):
        tasks = []
        for k in idx:
            ex = expand(progs[k], lib) if len(lib) else progs[k]
            cands = [progs[k]] + ([ex] if ex != progs[k] else [])
            tasks.append((progs[k], cands, lib, prims[k], _limits(cfg)))
        out = _map(executor, _best_of, tasks, progress, "integrate")
        new_p, new_c, new_e = list(progs), list(costs), list(errors)
        for k, (e, c, err) in zip(idx, out):
            if c is not None and c < new_c[k] - 1e-9:
                new_p[k], new_c[k], new_e[k] = e, c, err
        return new_p, new_c, new_e

    base = F(library, costs)
    for rank, cand in candidates:
        name = f"A{index}"
        while name in library:
            index += 1
            name = f"A{index}"
        try:
            lib2 = library.add(cand.abstraction(name))
        except ProgramError:
            continue
        idx = range(n) if cfg.refactor_all else sorted(cand.programs)
        p2, c2, e2 = trial(lib2, programs, idx, costs, errors)
        f2 = F(lib2, c2)
        if _uses(p2, name) > 0 and f2 < base - 1e-9:
            library, programs, costs, errors, base = lib2, p2, c2, e2, f2
            accepted.append(name)
            index += 1
            for k in cand.programs:
                weights[k] *= 0.5
            if log:
                log(f"accept {name} = {cand.abstraction(name).to_text()} F={f2:.3f}")
            continue
        # f_dec: abstractions that lost more than half their uses
        fdec = [ab.name for ab in library.abstractions if _uses(p2, ab.name) * 2 < _uses(programs, ab.name)]
        if fdec and _uses(p2, name) > 0:
            lib3 = lib2
            for a in fdec:
                lib3 = lib3.remove(a)
            p3 = [expand(p, lib2, names=fdec) for p in programs]
            c3, e3 = [], []
            for k, p in enumerate(p3):
                got = evaluate(p, lib3, prims[k])
                c3.append(costs[k] if got is None else got[0])
                e3.append(errors[k] if got is None else got[1])
            p3, c3, e3 = trial(lib3, p3, range(n), c3, e3)
            f3 = F(lib3, c3)
            if f3 < base - 1e-9:
                library, programs, costs, errors, base = lib3, p3, c3, e3, f3
                accepted.append(name)
                index += 1
                if log:
                    log(f"accept {name} without {', '.join(fdec)} F={f3:.3f}")
                continue
        if log:
            log(f"reject candidate {cand.abstraction(name).to_text()} (F {f2:.3f} >= {base:.3f})")
    return library, programs, costs, errors, accepted, index


def _remove_sweep(shapes, programs, costs, errors, library, cfg, executor, log, progress):
    prims = [getattr(s, "prims", s) for s in shapes]
    n = len(prims)

    def F(lib, cs):
        return sum(cs) / n + library_cost(lib, cfg)

    base = F(library, costs)
    for ab in list(library.abstractions):
        if ab.name not in library:
            continue
        lib2 = library.remove(ab.name)
        users = [k for k in range(n) if _uses([programs[k]], ab.name)]
        p2, c2, e2 = list(programs), list(costs), list(errors)
        tasks = []
        for k in users:
            ex = expand(programs[k], library, names=(ab.name,))
            tasks.append((ex, [ex], lib2, prims[k], _limits(cfg)))
        out = _map(executor, _best_of, tasks, progress, f"remove {ab.name}")
        ok = True
        for k, (e, c, err) in zip(users, out):
            if c is None:
                ok = False
                break
            p2[k], c2[k], e2[k] = e, c, err
        if not ok:
            continue
        f2 = F(lib2, c2)
        if f2 < base - 1e-9:
            library, programs, costs, errors, base = lib2, p2, c2, e2, f2
            if log:
                log(f"remove {ab.name} F={f2:.3f}")
    return library, programs, costs, errors


@dataclass
class DiscoveryResult:
    """The outcome of :func:`discover`: the library, one program per shape, their costs and errors, and
    the log (one dict per phase: round, phase, F, |L|, seconds)."""

    library: Library
    programs: list
    costs: list
    errors: list
    log: list = field(default_factory=list)

    def summary(self) -> Summary:
        return summarize(self.programs, self.library, self.errors)


def _save(out: Path | None, state: dict) -> None:
    if out is None:
        return

    atomic_write(out / "state.json", json.dumps(state, indent=1), mkdir=True)


def _load(out: Path | None, lang: Lang):
    if out is None or not (out / "state.json").is_file():
        return None


    file = str(out / "state.json")
    st = parse_json(decode((out / "state.json").read_bytes(), file), file,
                    ParseError.in_file(file))
    if not isinstance(st, dict):
        raise ParseError("a damaged discovery state (not a JSON object)", file, 1, 1, "")
    where = "its library"
    try:
        missing = [k for k in _STATE_KEYS if k not in st]
        if missing:
            raise KeyError(missing[0])
        _check_state_fields(st)
        lib = Library.from_text(st["library"], lang, file=file)
        programs = []
        for i, t in enumerate(st["programs"]):
            where = f"its program {i} (shape {i})"
            programs.append(parse(t, lib, file=file, line=i + 1))
    except ParseError as e:  # located in the embedded text, not in the file
        raise ParseError(f"a damaged discovery state: {where}: {e.reason}", file, 1, 1, e.token) from None
    except (KeyError, TypeError, AttributeError) as e:
        raise ParseError(f"a damaged discovery state ({type(e).__name__}: {e})", file, 1, 1, "") from None
    except ValueError as e:  # ProgramError: the message names the sub-expression
        raise ParseError(f"a damaged discovery state: {where}: {e}", file, 1, 1, "") from None
    st["programs"], st["library_obj"] = programs, lib
    return st


#: The keys every discovery state holds (``stores``, ``repeat`` and ``config`` are optional).
_STATE_KEYS = ("library", "programs", "costs", "errors", "round", "phase", "log", "weights", "index")


def _check_state_fields(st: dict) -> None:
    """The types a resumed run relies on; raises TypeError naming the first field that is wrong."""
    def count(v) -> bool:
        return type(v) is int and v >= 0

    def number(v) -> bool:
        return type(v) in (int, float)

    n = len(st["programs"]) if isinstance(st["programs"], list) else -1
    checks = [
        ("library", isinstance(st["library"], str)),
        ("programs", n >= 0 and all(isinstance(t, str) for t in st["programs"])),
        ("round", count(st["round"])), ("phase", isinstance(st["phase"], str)), ("index", count(st["index"])),
        ("repeat", count(st.get("repeat", 0))),
        ("costs", isinstance(st["costs"], list) and len(st["costs"]) == n and all(number(c) for c in st["costs"])),
        ("errors", isinstance(st["errors"], list) and len(st["errors"]) == n),
        ("weights", isinstance(st["weights"], list) and all(number(w) for w in st["weights"])),
        ("log", isinstance(st["log"], list) and all(isinstance(h, dict) and number(h.get("seconds", 0))
                                                    for h in st["log"])),
    ]
    bad = [k for k, ok in checks if not ok]
    if bad:
        raise TypeError(f"field {bad[0]!r} does not hold what a discovery state writes there")


def start_from(out: str | Path, shapes: Sequence, library: Library, programs: Sequence[Expr], cfg: Config = Config(),
               lang: Lang = LANG_3D, round: int | None = None, log: Sequence[dict] = ()) -> None:
    """Write ``out/state.json`` so that :func:`discover` on ``out`` starts at the wake of ``round`` (default
    ``cfg.rounds``: only the final wake) with ``library`` and the programs of an earlier run, e.g. to run
    the final wake again with the network (``Config(wake="network")``) on a library discovered with the
    refactor-only wake. ``log``, the earlier run's F per phase, is carried over (its seconds continue).

    Raises:
        FileExistsError: ``out`` already holds a run's state.
        ValueError: another number of programs than shapes, a round beyond ``cfg.rounds``, or a program that
            does not re-cover its shape (named by its index).
    """
    out = Path(out)
    if (out / "state.json").exists():
        raise FileExistsError(f"{out / 'state.json'} exists: resume that run without a start, or choose another --out")
    round = cfg.rounds if round is None else round
    if not 0 <= round <= cfg.rounds:
        raise ValueError(f"the start round must be in 0..{cfg.rounds} (the run's rounds), got {round}")
    if len(programs) != len(shapes):
        raise ValueError(f"{len(programs)} programs for {len(shapes)} shapes")
    costs, errors = [], []
    for k, (p, sh) in enumerate(zip(programs, shapes)):
        got = evaluate(p, library, getattr(sh, "prims", sh))
        if got is None:
            raise ValueError(f"program {k} ({getattr(sh, 'key', k)}) does not re-cover its shape")
        costs.append(got[0])
        errors.append(got[1])
    names = [int(a.name[1:]) for a in library.abstractions if a.name[1:].isdigit()]
    _save(out, {"round": round, "phase": "wake", "library": library.to_text(), "programs": [to_text(p) for p in programs],
                "costs": costs, "errors": errors, "log": list(log), "weights": [1.0] * len(shapes),
                "index": 1 + max(names, default=-1), "config": None, "lang": lang.name})


def discover(shapes: Sequence, cfg: Config = Config(), lang: Lang = LANG_3D, executor: cf.Executor | None = None,
             out: str | Path | None = None, log: Callable | None = print, progress: Callable | None = None,
             stop_at: float | None = None) -> DiscoveryResult:
    """Run discovery on ``shapes`` (primitive sets or records with ``.prims``).

    Args:
        cfg: the :class:`Config`.
        executor: runs the per-program refactors (``executor.map``); None runs them in this process.
        out: a folder for ``state.json`` (written atomically after each phase; a run on a folder with a
            state resumes after its last finished phase).
        log: called with one line per event.
        progress: a tqdm-like wrapper ``progress(iterable, total=, desc=)``.
        stop_at: a ``time.time()`` after which no new phase starts (the state stays resumable).
    """
    out = Path(out) if out is not None else None
    log = log or (lambda s: None)
    st = _load(out, lang)
    t0 = time.time()
    dream_cache: dict = {}
    net = None  # (round, model, vocab) of the network wake
    if st is None:
        library, programs, costs, errors = Library(lang), None, None, None
        rnd, phase, hist, weights, index = 0, "wake", [], [1.0] * len(shapes), 0
        stores, repeat = None, 0
    else:
        library, programs = st["library_obj"], st["programs"]
        costs, errors, rnd, phase = st["costs"], st["errors"], st["round"], st["phase"]
        hist, weights, index = st["log"], st["weights"], st["index"]
        stores = st.get("stores")
        repeat = st.get("repeat", 0)  # network wakes of this round already done
        log(f"resume at round {rnd}, phase {phase}")
        before = st.get("config") or {}
        if before:  # states written before the setting existed ran with the lagged value table
            before = {"egraph_values": "lagged", **before}
        changed = {k: (before[k], v) for k, v in asdict(cfg).items() if k in before and before[k] != v}
        if changed:  # allowed (e.g. more rounds, larger e-graphs for the later rounds), but said
            log("resumed with other settings than the saved state's: "
                + ", ".join(f"{k} {a!r} -> {b!r}" for k, (a, b) in sorted(changed.items())))
        if hist:
            t0 -= hist[-1]["seconds"]  # the log's seconds count the time of every session
    if len(weights) != len(shapes):
        raise ValueError(f"the state in {out} has {len(weights)} shapes, got {len(shapes)}")

    def record(ph):
        s = summarize(programs, library, errors)
        hist.append({"round": rnd, "phase": ph, "F": round(s.F, 4), "L": s.library_size,
                     "num_struct": round(s.num_struct, 3), "num_param": round(s.num_param, 3),
                     "seconds": round(time.time() - t0, 1)})
        log(f"round {rnd} {ph}: F={s.F:.3f} |L|={s.library_size} struct={s.num_struct:.2f} param={s.num_param:.2f}")

    def save(next_round, next_phase, next_repeat=0):
        _save(out, {"round": next_round, "phase": next_phase, "repeat": next_repeat, "library": library.to_text(),
                    "programs": [to_text(p) for p in programs], "costs": costs, "errors": errors, "log": hist,
                    "weights": weights, "index": index, "config": asdict(cfg), "lang": lang.name,
                    **({"stores": stores} if stores is not None else {})})

    while rnd <= cfg.rounds:
        if phase == "done":
            break
        if stop_at is not None and time.time() > stop_at:
            log("stopping: time is up (resumable)")
            break
        if phase == "wake":
            if cfg.wake == "network" and rnd >= cfg.network_from:
                if net is None or net[0] != rnd:  # one network per round, kept across its repeated wakes
                    ckpt = None if out is None else out / f"recnet_round{rnd}.pt"
                    net = (rnd, *train_network(shapes, library, cfg, cfg.seed + rnd, executor, dream_cache, log,
                                               ckpt)[:2])
                # repeat 0 samples with the round's seed (the paper's single wake); later ones with others
                seed = cfg.seed + rnd if repeat == 0 else (cfg.seed + rnd) * 1_000 + repeat
                programs, costs, errors, stores, sources = wake_network(
                    shapes, programs, library, net[1], net[2], stores, cfg, executor, progress, seed)
                counts = {k: sources.count(k) for k in sorted(set(sources))}
                log(f"round {rnd} wake{f' {repeat + 1}/{cfg.wake_repeats}' if cfg.wake_repeats > 1 else ''}: "
                    "best candidate per shape: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
                repeat += 1
            else:
                programs, costs, errors = wake(shapes, programs, library, cfg, executor, progress)
            if any(c is None for c in costs):
                bad = [k for k, c in enumerate(costs) if c is None]
                raise RefactorError(f"no program re-covers shape(s) {bad[:5]}")
            record("wake")
            if 0 < repeat < cfg.wake_repeats:  # another wake of this round next (the loop checks the time)
                save(rnd, "wake", repeat)
                continue
            repeat = 0
            phase = "integrate" if rnd < cfg.rounds else "done"
            save(rnd, phase)
        elif phase == "integrate":
            rng = random.Random(cfg.seed + rnd)
            cands = propose(programs, library, cfg.n_proposals, rng, weights, top=cfg.n_abstractions,
                            preferences=cfg.preferences)
            log(f"round {rnd}: {len(cands)} candidates")
            library, programs, costs, errors, acc, index = integrate(
                shapes, programs, costs, errors, library, cands, cfg, executor, weights, log, progress, index)
            library, programs, costs, errors = _remove_sweep(shapes, programs, costs, errors, library, cfg,
                                                             executor, log, progress)
            record("integrate")
            rnd, phase = rnd + 1, "wake"
            save(rnd, phase)
    return DiscoveryResult(library, programs, costs, errors, hist)


def write_outputs(out: str | Path, result: DiscoveryResult, keys: Sequence[str], header: str = "") -> None:
    """Write ``library.txt`` (one abstraction per line), ``programs.txt`` (``<key>:<program>`` lines) and
    ``log.json`` (the F log, the summary and the SHA-256 of the other two files) into ``out``, each atomically
    and ``log.json`` last: a write interrupted between the files leaves digests that do not match, which
    :func:`shapeprog.coder.tables.from_run` refuses."""
    out = Path(out)
    texts = {"library.txt": header + result.library.to_text(),
             "programs.txt": "".join(f"{k}:{to_text(p)}\n" for k, p in zip(keys, result.programs))}
    for name, text in texts.items():
        atomic_write(out / name, text, mkdir=True)
    digests = {name: hashlib.sha256(text.encode("utf-8")).hexdigest() for name, text in texts.items()}
    atomic_write(out / "log.json", json.dumps({"log": result.log, "summary": asdict(result.summary()),
                                               "files": digests}, indent=1))


def discover_category(category: str, out: str | Path, cfg: Config = Config(), shapes: int = 400, workers: int = 2,
                      minutes: float | None = None, log: Callable | None = print,
                      progress: Callable | None = None, start: tuple | None = None,
                      start_round: int | None = None) -> DiscoveryResult:
    """:func:`discover` on the first ``shapes`` discovery shapes of ``category`` with a process pool of
    ``workers`` (1: none), then :func:`write_outputs`. ``out`` may hold the ``state.json`` of an earlier
    run (it resumes); a folder with a ``library.txt`` but no state is refused (user files are never
    overwritten). ``start``: ``(library, programs, log)`` of an earlier run on the same shapes, to begin at
    the wake of ``start_round`` (see :func:`start_from`).

    Raises:
        FileExistsError: ``out`` has outputs of something else.
    """
    out = Path(out)
    if (out / "library.txt").exists() and not (out / "state.json").exists():
        raise FileExistsError(f"{out / 'library.txt'} exists and is not from a resumable run; choose another --out")
    recs = data.load(category)[:shapes]
    first = 0 if start is None else (cfg.rounds if start_round is None else start_round)  # the first round run here
    if start is not None:
        start_from(out, recs, start[0], start[1], cfg, LANG_3D, first, start[2])
    stop_at = None if minutes is None else time.time() + 60 * minutes
    if workers > 1:
        # the network wake runs torch in this process: workers forked after that can hang, so they start
        # from a fresh interpreter
        ctx = multiprocessing.get_context("forkserver") if cfg.wake == "network" else None
        with cf.ProcessPoolExecutor(workers, mp_context=ctx) as ex:
            result = discover(recs, cfg, LANG_3D, ex, out, log, progress, stop_at)
    else:
        result = discover(recs, cfg, LANG_3D, None, out, log, progress, stop_at)
    s = result.summary()
    last = result.log[-1] if result.log else {"round": 0, "phase": "none", "seconds": 0}
    # a run that starts at the final wake proposes nothing: its header does not claim proposal settings
    proposing = (f"proposals={cfg.n_proposals}, N_A={cfg.n_abstractions}, " if first < cfg.rounds else "")
    header = (f"# ShapeCoder library discovered on the first {len(recs)} {category} shapes: rounds={cfg.rounds}, "
              f"{proposing}seed={cfg.seed}, wake={cfg.wake}"
              + (f" (dreams={cfg.n_dreams}, training {cfg.train_seconds or 0:g} s, lr={cfg.train_lr:g}, "
                 f"dropout={cfg.dropout:g}"
                 + (f", from round {cfg.network_from}, refactor-only before" if cfg.network_from else "")
                 + (f", {cfg.wake_repeats} wakes per round" if cfg.wake_repeats > 1 else "")
                 + ")" if cfg.wake == "network" else "")
              + ("" if cfg.semantic_rewrites else ", semantic rewrites off (abstraction rules only)")
              + ("" if cfg.scheme == "conditional" else f", {cfg.scheme} rewrite scheme")
              + ("" if cfg.preferences else f", no preferences (omega {CONSTANT_OMEGA:g} each)")
              + ("" if cfg.egraph_values == VALUES else f", e-graph values {cfg.egraph_values}")
              + ("" if start is None else f", started at round {first} from an earlier library and its programs")
              + f", e-graph limits "
              f"{cfg.iterations} iterations / {cfg.max_nodes} e-nodes"
              + ("" if cfg.time_limit == TIME_LIMIT else f" (safety cap {cfg.time_limit:g} s)")
              + "; last finished phase: "
              f"round {last['round']} {last['phase']} after {last['seconds']:.0f} s; F={s.F:.2f}, |L|={s.library_size}\n")
    write_outputs(out, result, [r.key for r in recs], header)
    return result
