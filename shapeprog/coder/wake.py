"""The wake phase of ShapeCoder discovery: each shape's cheapest program that re-covers its primitives.

:func:`evaluate` scores one program for one shape; :func:`wake` refactors each shape's candidates with the
current library; :func:`wake_network` first trains the recognition network on dreams
(:func:`train_network`, weights in ``out/recnet_round<k>.pt``) and adds the network's search results to the
candidates (:func:`network_best`). Per-program work goes through a ``concurrent.futures.Executor`` from the
caller. :mod:`shapeprog.coder.discover` runs the rounds.
"""
from __future__ import annotations

import concurrent.futures as cf
import functools
import hashlib
import multiprocessing
import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable, Sequence

import torch

from .execute import execute
from .lang import Expr, Library, Num, ProgramError, expand, substitute, to_text
from .objective import WEIGHTS, match, naive_program, program_cost
from .refactor import RefactorError, refactor
from .rules import egglog_program, naive_egglog_program
from .search import (Store, WAKE_BATCH, WAKE_BATCHES, WAKE_SECONDS, WAKE_STEP_BUDGET, naive_piece, search_shape,
                     union)
from .config import Config
from .dream import dream
from .recnet import NetConfig, RecognitionNet, load_checkpoint, save_checkpoint
from .train import device_of, train
from .vocab import Vocab

__all__ = [
    "evaluate",
    "network_best",
    "network_payload",
    "train_network",
    "wake",
    "wake_network",
]


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
def _rules(library: Library, semantic: bool = True, scheme: str = "conditional") -> str:
    if scheme == "naive":
        return naive_egglog_program(library)
    return egglog_program(library, None if semantic else [])


def _split(limits: dict) -> tuple:
    """``(refactor keywords, semantic, scheme)`` of a worker's limits (``semantic`` and ``scheme`` choose the
    rules; ``scheme`` is a keyword of the refactor as well)."""
    lim = dict(limits)
    semantic, scheme = lim.pop("semantic", True), lim.get("scheme", "conditional")
    return lim, semantic, scheme


def _best_of(task) -> tuple:
    """Worker: refactor each candidate program with the library; the cheapest valid one (or the current)."""
    current, candidates, library, prims, limits = task
    limits, semantic, scheme = _split(limits)
    best = evaluate(current, library, prims)
    best_expr = current
    rules = _rules(library, semantic, scheme)
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
            "values": cfg.egraph_values, "semantic": cfg.semantic_rewrites, "scheme": cfg.scheme}


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
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    digest = hashlib.sha1(b"".join(v.numpy().tobytes() for v in state.values())).hexdigest()
    return (digest, asdict(model.cfg), vocab, state)


def network_best(current: Expr, library: Library, prims, payload, limits: dict, search: dict | None = None,
                 seed: int = 0) -> tuple:
    """The network search of one shape, then the refactor of every candidate (see :func:`wake_network`)
    with an empty store: ``(program, cost, error, source)``, never dearer than ``current``.

    Args:
        payload: from :func:`network_payload`. limits: ``iterations``, ``max_nodes``, ``time_limit``.
        search: ``batch``, ``batches``, ``step_budget``, ``seconds`` of the search (default the wake's;
            :func:`~shapeprog.coder.search.search_shape`).
    """
    search = search or {"batch": WAKE_BATCH, "batches": WAKE_BATCHES, "step_budget": WAKE_STEP_BUDGET,
                        "seconds": WAKE_SECONDS}
    expr, cost, error, _, source = _network_best((current, library, prims, payload, {}, dict(limits), search, seed))
    return expr, cost, error, source


def _network_best(task) -> tuple:
    """Worker: the network search of one shape, the store's combinations, then the refactor of every
    candidate; ``(program, cost, error, store entries, source)``."""
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
    lim, semantic, scheme = _split(limits)
    rules = _rules(library, semantic, scheme)
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
    search = {"batch": cfg.wake_batch, "batches": cfg.wake_batches, "step_budget": cfg.wake_step_budget,
              "seconds": cfg.wake_seconds}
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
