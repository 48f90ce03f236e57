"""The ShapeCoder discovery loop: wake (search by refactoring, or with the recognition network), proposal,
integration, and a final round with the library fixed. Per-program work goes through a
``concurrent.futures.Executor`` from the caller.

One round (``rounds`` of them, then a final wake with the library fixed):

1. **Wake** (:func:`wake`, ``Config.wake="refactor"``, the default): each shape's candidates (its current
   program, the same with every abstraction expanded, and the naive program) are refactored with the
   current library (:func:`shapeprog.coder.refactor.refactor`); the cheapest that re-covers the shape's
   primitives (a valid Hungarian match of every primitive, :func:`shapeprog.coder.objective.match`) is
   kept. With ``Config.wake="network"`` (:func:`wake_network`) the round first dreams
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
import functools
import json
import random
import time
from dataclasses import dataclass, field, asdict
from pathlib import Path
from typing import Callable, Sequence

from .execute import execute
from .lang import LANG_3D, Call, Expr, Lang, Library, Num, ProgramError, expand, parse, substitute, to_text, walk
from .objective import WEIGHTS, match, naive_program, omega, program_cost, token_counts
from .dream import DREAM_TIMEOUT, N_DREAMS
from .proposal import propose
from .refactor import (MAX_ENODES, MAX_ITERATIONS, TIME_LIMIT, VALUE_SCHEDULES, VALUES, RefactorError, check_limits,
                       egglog_program, refactor)
from .search import WAKE_BATCH, WAKE_BATCHES, WAKE_SECONDS

__all__ = ["Config", "DiscoveryResult", "Summary", "WAKES", "discover", "discover_category", "evaluate", "integrate",
           "network_best", "network_payload", "start_from", "summarize", "train_network", "wake",
           "wake_network", "write_outputs"]

#: The wake searches: by refactoring only, or with the recognition network.
WAKES = ("refactor", "network")


@dataclass(frozen=True)
class Config:
    """Settings of a discovery run (the paper's values where it has them).

    Attributes:
        rounds: proposal/integration rounds (``max_sc_rounds`` 4), then one final wake.
        n_proposals: proposals per round (10,000).
        n_abstractions: candidates tried per round (N_A, 20).
        seed: random seed of the proposals (42).
        iterations, max_nodes, time_limit: e-graph limits of each refactor (5, 10,000, 5 s).
        egraph_values: how the e-graph's value table follows its e-nodes (:data:`~shapeprog.coder.refactor.VALUES`;
            ``"lagged"`` reproduces runs made before 2026-11-29; :func:`~shapeprog.coder.refactor.refactor`).
        refactor_all: integration refactors every program (the paper) rather than only those a candidate
            covers.
        semantic_rewrites: use the semantic rewrites (False: only the abstraction rules, the paper's
            "no semantic rewrites" ablation).
        wake: ``"refactor"`` (search by refactoring) or ``"network"`` (dreams, a recognition network, the
            network search; see the module docstring).
        n_dreams, dream_timeout: valid dreams per function (N_D, 10,000) and seconds per function (1,800).
        train_lr, train_batch, train_epochs, train_patience, train_min_delta, train_holdout,
            train_seconds, dropout, train_bucket: the network's training (:class:`shapeprog.coder.train.TrainConfig`;
            the paper's values by default, ``train_seconds`` per round).
        wake_batch, wake_batches, wake_seconds: samples per batch (64), batches per search step at most,
            and seconds per search step (1 s; None: the search depends only on the seed).
        device: where the network trains (``"auto"``: CUDA when available).
        network_from: with ``wake="network"``, the first round whose wake uses the network; the rounds
            before it use the refactor-only wake (cheap early rounds, then the network; ours, not the paper's).
        wake_repeats: network wakes per round with the round's network, each from the programs of the one
            before and with other sampling seeds (a shape keeps its program unless a candidate is cheaper,
            so F never rises); 1 is the paper's one wake per round.
    """

    rounds: int = 4
    n_proposals: int = 10_000
    n_abstractions: int = 20
    seed: int = 42
    iterations: int = MAX_ITERATIONS
    max_nodes: int = MAX_ENODES
    time_limit: float = TIME_LIMIT
    egraph_values: str = VALUES
    refactor_all: bool = False
    semantic_rewrites: bool = True
    wake: str = "refactor"
    n_dreams: int = N_DREAMS
    dream_timeout: float = DREAM_TIMEOUT
    train_lr: float = 1e-4
    train_batch: int = 64
    train_epochs: int = 300
    train_patience: int = 30
    train_min_delta: float = 0.025
    train_holdout: float = 0.1
    train_seconds: float | None = 12_000.0
    dropout: float = 0.5
    train_bucket: bool = True
    wake_batch: int = WAKE_BATCH
    wake_batches: int = WAKE_BATCHES
    wake_seconds: float | None = WAKE_SECONDS
    device: str = "auto"
    network_from: int = 0
    wake_repeats: int = 1

    def __post_init__(self):
        for name in ("rounds", "n_proposals", "n_abstractions", "iterations", "max_nodes", "train_epochs",
                     "network_from"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"Config.{name} must be an int >= 0, got {v!r}")
        for name in ("n_dreams", "train_batch", "train_patience", "wake_batch", "wake_batches", "wake_repeats"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"Config.{name} must be an int >= 1, got {v!r}")
        if self.wake not in WAKES:
            raise ValueError(f"Config.wake must be one of {', '.join(WAKES)}, got {self.wake!r}")
        check_limits(self.iterations, self.max_nodes, self.time_limit)  # before any work, not in a worker
        if self.egraph_values not in VALUE_SCHEDULES:
            raise ValueError(f"Config.egraph_values must be one of {', '.join(VALUE_SCHEDULES)}, "
                             f"got {self.egraph_values!r}")

    def train_config(self):
        """The :class:`shapeprog.coder.train.TrainConfig` of these settings."""
        from .train import TrainConfig

        return TrainConfig(lr=self.train_lr, batch=self.train_batch, epochs=self.train_epochs,
                           patience=self.train_patience, min_delta=self.train_min_delta, holdout=self.train_holdout,
                           max_seconds=self.train_seconds, dropout=self.dropout,
                           bucket=self.train_bucket)


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


def evaluate(expr: Expr, library: Library, prims) -> tuple | None:
    """``(cost, error)`` of a program for a shape, or None when it does not re-cover the primitives
    (a hard error, another primitive count, or a match beyond the threshold)."""
    try:
        got = execute(expr, library, strict=True)
    except (ProgramError, ValueError):
        return None
    if len(got) != len(prims):
        return None
    m = match(got, prims, threshold=library.lang.match_threshold)
    if not m.valid:
        return None
    return program_cost(expr, library) + WEIGHTS.error * m.error, m.error


@functools.lru_cache(maxsize=8)
def _rules(library: Library, semantic: bool = True) -> str:
    return egglog_program(library, None if semantic else [])


def _best_of(task) -> tuple:
    """Worker: refactor each candidate program with the library; the cheapest valid one (or the current)."""
    current, candidates, library, prims, limits = task
    limits = dict(limits)
    semantic = limits.pop("semantic", True)
    best = evaluate(current, library, prims)
    best_expr = current
    rules = _rules(library, semantic)
    for cand in candidates:
        try:
            r = refactor(cand, library, rules=rules, **limits)
        except RefactorError:
            continue
        for e in (r.expr, cand):
            got = evaluate(e, library, prims)
            if got is not None and (best is None or got[0] < best[0] - 1e-9):
                best, best_expr = got, e
    return best_expr, (None if best is None else best[0]), (None if best is None else best[1])


def _limits(cfg: Config) -> dict:
    return {"iterations": cfg.iterations, "max_nodes": cfg.max_nodes, "time_limit": cfg.time_limit,
            "values": cfg.egraph_values, "semantic": cfg.semantic_rewrites}


def _map(executor, fn, tasks, progress: Callable | None, desc: str):
    it = executor.map(fn, tasks) if executor is not None else map(fn, tasks)
    if progress is not None:
        it = progress(it, total=len(tasks), desc=desc)
    return list(it)


def wake(shapes: Sequence, programs: Sequence[Expr] | None, library: Library, cfg: Config = Config(),
         executor: cf.Executor | None = None, progress: Callable | None = None) -> tuple:
    """Search by refactoring: ``(programs, costs, errors)``, one per shape (see the module docstring).

    Args:
        shapes: primitive sets (tuples of 9-tuples, or records with ``.prims``).
        programs: the current programs (None: start from the naive ones).
    """
    prims = [getattr(s, "prims", s) for s in shapes]
    tasks = []
    for k, p in enumerate(prims):
        naive, env = naive_program(p)
        naive = substitute(naive, {n: Num(v) for n, v in env.items()})
        cur = naive if programs is None else programs[k]
        cands = [cur]
        if programs is not None:
            ex = expand(cur, library)
            if ex != cur:
                cands.append(ex)
            cands.append(naive)
        tasks.append((cur, cands, library, p, _limits(cfg)))
    out = _map(executor, _best_of, tasks, progress, "wake")
    return [o[0] for o in out], [o[1] for o in out], [o[2] for o in out]


_MODELS: dict = {}


def _model_from(payload):
    """The (model, vocab) of a payload ``(key, config dict, vocab tokens, state_dict)``, cached per process."""
    key = payload[0]
    if key not in _MODELS:
        import multiprocessing

        import torch

        from .recnet import NetConfig, RecognitionNet, Vocab

        if multiprocessing.parent_process() is not None:
            torch.set_num_threads(1)  # a pool worker: one thread each
        _MODELS.clear()
        model = RecognitionNet(NetConfig(**payload[1]))
        model.load_state_dict(payload[3])
        model.eval()
        vocab = payload[2]
        if not isinstance(vocab, Vocab):
            raise TypeError("the payload's vocabulary must be a Vocab")
        _MODELS[key] = (model, vocab)
    return _MODELS[key]


def network_payload(model, vocab) -> tuple:
    """A picklable ``(key, config dict, vocab, state_dict)`` of a network for worker processes (each
    builds the model once per key)."""
    import hashlib

    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    digest = hashlib.sha1(b"".join(v.numpy().tobytes() for v in state.values())).hexdigest()
    return (digest, asdict(model.cfg), vocab, state)


def network_best(current: Expr, library: Library, prims, payload, limits: dict, search: dict | None = None,
                 seed: int = 0) -> tuple:
    """The network search of one shape, then the refactor of every candidate (see :func:`wake_network`)
    with an empty store: ``(program, cost, error, source)``, never dearer than ``current``.

    Args:
        payload: from :func:`network_payload`. limits: ``iterations``, ``max_nodes``, ``time_limit``.
        search: ``batch``, ``batches``, ``seconds`` of the search (default the wake's).
    """
    search = search or {"batch": WAKE_BATCH, "batches": WAKE_BATCHES, "seconds": WAKE_SECONDS}
    expr, cost, error, _, source = _network_best((current, library, prims, payload, {}, dict(limits), search, seed))
    return expr, cost, error, source


def _network_best(task) -> tuple:
    """Worker: the network search of one shape, the store's combinations, then the refactor of every
    candidate; ``(program, cost, error, store entries, source)``."""
    from .search import Store, naive_piece, search_shape, union

    current, library, prims, payload, entries, limits, search, seed = task
    model, vocab = _model_from(payload)
    store = Store(prims, library, entries)
    found = search_shape(prims, library, model, vocab, seed=seed, **search)
    for f in found:
        if f.from_network:
            store.add(f.expr, f.covered)
    net_prog = union([f.expr for f in sorted(found, key=lambda f: f.covered)])
    cands = [("current", current)]
    ex = expand(current, library)
    if ex != current:
        cands.append(("expanded", ex))
    cands.append(("naive", union([naive_piece(p) for p in prims])))
    if any(f.from_network for f in found):
        cands.append(("network", net_prog))
    parts = store.add_program(current)
    if parts is not None:
        cands.append(("replace", store.replace(parts)))
    cands.append(("rebuild", store.rebuild()))
    seen, uniq = set(), []
    for name, c in cands:
        key = to_text(c)
        if key not in seen:
            seen.add(key)
            uniq.append((name, c))
    best, best_expr, source = evaluate(current, library, prims), current, "current"
    rules = _rules(library, limits.get("semantic", True))
    lim = {k: v for k, v in limits.items() if k != "semantic"}
    for name, cand in uniq:
        outs = [cand]
        try:
            outs.insert(0, refactor(cand, library, rules=rules, **lim).expr)
        except RefactorError:
            pass
        for e in outs:
            got = evaluate(e, library, prims)
            if got is not None and (best is None or got[0] < best[0] - 1e-9):
                best, best_expr, source = got, e, name
    store.add_program(best_expr)
    return (best_expr, None if best is None else best[0], None if best is None else best[1], store.to_dict(), source)


def train_network(shapes: Sequence, library: Library, cfg: Config = Config(), seed: int = 42,
                  executor: cf.Executor | None = None, cache: dict | None = None, log: Callable | None = None,
                  checkpoint: str | Path | None = None) -> tuple:
    """The dream phase and the network's training for one round: ``(model, vocab, info)``, the model on
    the CPU in eval mode. With ``checkpoint``: an existing file written for the same library is loaded
    instead; otherwise the trained weights are written there (atomically).

    Args:
        shapes: real primitive sets (the dreams' distractors).
        cache: abstraction dreams kept across rounds (see :func:`shapeprog.coder.dream.dream`).
    """
    import torch

    from .dream import dream
    from .recnet import NetConfig, RecognitionNet, Vocab, load_checkpoint, save_checkpoint
    from .train import device_of, train

    log = log or (lambda s: None)
    if checkpoint is not None and Path(checkpoint).is_file():
        try:
            model, vocab, extra = load_checkpoint(checkpoint, library)
            if extra.get("library") == library.to_text():
                log(f"network: loaded {checkpoint}")
                return model.eval(), vocab, extra
        except (ValueError, RuntimeError, KeyError):
            pass
    t0 = time.time()
    d = dream(library, cfg.n_dreams, seed, [getattr(s, "prims", s) for s in shapes], executor, cache,
              cfg.dream_timeout)
    for line in d.summary().splitlines():
        log(f"dreams: {line}")
    t1 = time.time()
    vocab = Vocab.of(library)
    lang = library.lang
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = RecognitionNet(NetConfig(len(vocab), fields=len(lang.prim_fields), max_prims=lang.max_prims,
                                         dropout=cfg.dropout))
    tl = train(model, d.pairs, vocab, cfg.train_config(), torch.Generator().manual_seed(seed), device_of(cfg.device),
               library=library)
    model.cpu().eval()
    info = {"library": library.to_text(), "pairs": tl.pairs, "epochs": len(tl.train_loss),
            "train_loss": round(tl.train_loss[-1], 4) if tl.train_loss else None,
            "val_loss": round(tl.best, 4) if tl.val_loss else None, "stop": tl.stop,
            "dream_seconds": round(t1 - t0, 1), "train_seconds": round(tl.seconds, 1)}
    log(f"network: {tl.pairs} pairs, {len(tl.train_loss)} epochs ({tl.stop}), held-out loss "
        f"{info['val_loss']}, dreams {t1 - t0:.0f} s, training {tl.seconds:.0f} s")
    if checkpoint is not None:
        save_checkpoint(checkpoint, model, vocab, info)
    return model, vocab, info


def wake_network(shapes: Sequence, programs: Sequence[Expr] | None, library: Library, model, vocab,
                 stores: list | None = None, cfg: Config = Config(), executor: cf.Executor | None = None,
                 progress: Callable | None = None, seed: int = 0) -> tuple:
    """The wake with the recognition network (see the module docstring): ``(programs, costs, errors,
    stores, sources)``, ``stores`` the per-shape store entries and ``sources`` which candidate won per
    shape (``current``, ``expanded``, ``naive``, ``network``, ``replace``, ``rebuild``).

    A process pool for ``executor`` must not fork its workers after this process has run torch (they can
    hang): use a ``spawn`` or ``forkserver`` context, or a pool whose workers started before.
    """
    prims = [getattr(s, "prims", s) for s in shapes]
    stores = [dict() for _ in prims] if stores is None else stores
    payload = network_payload(model, vocab)
    search = {"batch": cfg.wake_batch, "batches": cfg.wake_batches, "seconds": cfg.wake_seconds}
    tasks = []
    for k, p in enumerate(prims):
        if programs is None:
            naive, env = naive_program(p)
            cur = substitute(naive, {n: Num(v) for n, v in env.items()})
        else:
            cur = programs[k]
        tasks.append((cur, library, p, payload, stores[k], _limits(cfg), search, seed * 100_003 + k))
    out = _map(executor, _network_best, tasks, progress, "wake (network)")
    return ([o[0] for o in out], [o[1] for o in out], [o[2] for o in out], [o[3] for o in out],
            [o[4] for o in out])


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
        return sum(cs) / n + sum(omega(ab, lib) for ab in lib.abstractions)

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
        return sum(cs) / n + sum(omega(ab, lib) for ab in lib.abstractions)

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
    from shapeio import atomic_write

    atomic_write(out / "state.json", json.dumps(state, indent=1), mkdir=True)


def _load(out: Path | None, lang: Lang):
    if out is None or not (out / "state.json").is_file():
        return None
    from shapeio.files import parse_json

    from ..errors import ParseError
    from ..limits import decode

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
            cands = propose(programs, library, cfg.n_proposals, rng, weights, top=cfg.n_abstractions)
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
    import hashlib

    from shapeio import atomic_write

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
    from . import data

    out = Path(out)
    if (out / "library.txt").exists() and not (out / "state.json").exists():
        raise FileExistsError(f"{out / 'library.txt'} exists and is not from a resumable run; choose another --out")
    recs = data.load(category)[:shapes]
    first = 0 if start is None else (cfg.rounds if start_round is None else start_round)  # the first round run here
    if start is not None:
        start_from(out, recs, start[0], start[1], cfg, LANG_3D, first, start[2])
    stop_at = None if minutes is None else time.time() + 60 * minutes
    if workers > 1:
        import multiprocessing

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
              + ("" if cfg.egraph_values == VALUES else f", e-graph values {cfg.egraph_values}")
              + ("" if start is None else f", started at round {first} from an earlier library and its programs")
              + f", e-graph limits "
              f"{cfg.iterations} iterations / {cfg.max_nodes} e-nodes / {cfg.time_limit:g} s; last finished phase: "
              f"round {last['round']} {last['phase']} after {last['seconds']:.0f} s; F={s.F:.2f}, |L|={s.library_size}\n")
    write_outputs(out, result, [r.key for r in recs], header)
    return result
