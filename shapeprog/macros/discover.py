"""ShapeMOD macro discovery: rounds of proposal, generalisation, integration and filterBadOrders.

:func:`discover` runs ``num_rounds`` rounds over a :class:`Nodes` collection (sub-programs with their
orderings). Each round:

1. **Proposal** (:mod:`shapeprog.macros.proposal`): ``cand_cluster_num`` steps of clusters and abstracted
   programs give candidate macros with their coverage; the ``gen_limit`` most covering ones are
   generalised (coefficient snapping, <= ``cand_max_changes`` edits), and inside every connected component
   of the generalisation graph a candidate whose gain is below the best gain among those with its coverage
   count is dropped.
2. **Selection**, two modes (``selection``):

   * ``greedy`` (the reference's integration): candidates ranked by gain x frequency; up to
     ``cand_abs_num`` tries, each evaluating f on the round's subsample (``abs_shape_num`` sub-programs)
     with the candidate added; accepted when f drops by more than ``abs_add_threshold``; else the
     infrequent-macro swap (macros whose usage share fell below ``func_change_thresh`` of its previous
     value are removed, then re-added one at a time); else the candidate's component is dropped. Then the
     removal sweep tries removing each macro.
   * ``milp``: the current macros (with ``milp_warm``, after the greedy loop has run) plus the ``milp_pool``
     best-ranked remaining candidates, and an exact choice by ``scipy.optimize.milp`` of the subset
     minimising the subsample's objective (|L| plus the mean over sub-programs of the best cover, a flow
     over line positions per ordering).
3. **filterBadOrders**: every sub-program keeps the orderings scoring below its best + ``order_thresh``.

f on the subsample is the mean over its sub-programs of the best program's f (so ``|L|`` enters once).
The best-program searches run through a ``concurrent.futures.Executor`` given by the caller (None: in
this process), ``chunk`` sub-programs per task, results gathered in submission order, and every random
draw comes from ``numpy.random.default_rng([seed, round, phase])`` in the calling process: the result is
the same whatever the executor. After every round the state (library, active macros, orderings, history)
is written atomically to ``state.json`` in the output folder; :func:`discover` given the same folder
resumes after the last finished round.

Macros removed from the active set stay defined (an active macro may call them); :meth:`Discovery.library`
writes them inlined into their callers.
"""
from __future__ import annotations

import copy
import math
import time
from concurrent.futures import Executor
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from shapeio import atomic_write

from ..errors import ParseError
from .lang import BASE, MacroDef, check_def, def_text
from .library import Library
from .objective import templates
from .proposal import PROPOSAL_TRIES, Candidate, gain, generalise, heur_score, propose_step
from .config import DEFAULTS, SWITCHES
from .state import Discovery, Nodes, _map, _options_chunk, evaluate

__all__ = [
    "discover",
    "prior_rounds",
]


# ----------------------------------------------------------------------------- a round


def _index(nodes: Nodes, current) -> dict:
    idx: dict = {}
    for i, cur in enumerate(current):
        for o in cur:
            idx.setdefault(nodes.sigs[i][o], []).append((i, o))
    return idx


def _rename(defn: MacroDef, name: str) -> MacroDef:
    return MacroDef(name, defn.params, defn.body)


def _components(keys: Sequence[str], edges) -> dict[str, str]:
    parent = {k: k for k in keys}

    def root(k):
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for a, b in edges:
        if a in parent and b in parent:
            parent[root(a)] = root(b)
    return {k: root(k) for k in keys}


def _propose(nodes: Nodes, state: Discovery, lib: Library, cfg: Mapping, rng, log) -> tuple[dict, dict]:
    tpls = [t for t in templates(lib) if t.name in BASE or t.name in state.active]
    index = _index(nodes, state.current)
    cands: dict[str, Candidate] = {}
    steps = cfg["cand_cluster_num"]
    t0 = time.time()
    missed: list = []
    for s in range(steps):
        for c in propose_step(nodes, state.current, index, lib, tpls, cfg, rng, missed=missed):
            k = c.key
            if k in cands:
                cands[k].coverage |= c.coverage
            else:
                cands[k] = c
        if log and (s + 1) % max(1, steps // 10) == 0:
            log(f"  proposal {s + 1}/{steps}: {len(cands)} candidates, {time.time() - t0:.0f} s")
    existing = {def_text(_rename(m, "macro")) for m in state.macros}
    top = sorted(cands.values(), key=lambda c: (-len(c.coverage), c.key))[:cfg["gen_limit"]]
    gen, edges = generalise({c.key: c for c in top}, lib, cfg)
    gen = {k: c for k, c in gen.items() if k not in existing and c.coverage}
    comp = _components(list(gen), edges)
    gains = {k: gain(c.definition, lib) for k, c in gen.items()}
    best: dict = {}
    for k, c in gen.items():
        key = (comp[k], len(c.coverage))
        best[key] = max(best.get(key, -math.inf), gains[k])
    kept = {k: c for k, c in gen.items() if gains[k] >= best[(comp[k], len(c.coverage))] and gains[k] > 0}
    if log:
        log(f"  proposal: {len(cands)} candidates, {len(gen)} after generalisation, {len(kept)} kept"
            + (f"; {len(missed)} of {steps} steps found no signature with {cfg['cand_cluster_size']} orderings "
               f"in {PROPOSAL_TRIES} draws" if missed else ""))
    return kept, {k: comp[k] for k in kept}


def _rank(c: Candidate, lib: Library, steps: int) -> float:
    """gain x frequency, frequency = |coverage| / (base lines x proposal steps)."""
    if getattr(c, "_info", None) is None:
        info = check_def(c.definition, lib.infos())
        c._info = (len(info.structure), heur_score(info.structure, info.params))
    n, g = c._info
    return g * len(c.coverage) / (n * max(steps, 1))


def _greedy(nodes, state: Discovery, lib: Library, cands: dict, comp: dict, sub, cfg, executor, log):
    thresh = cfg["abs_add_threshold"]
    f_cur, usage = evaluate(lib, state.active, sub, cfg, executor)
    f_start = f_cur
    tries = accepted = 0
    cands = dict(cands)
    while tries < cfg["cand_abs_num"] and cands:
        tries += 1
        ranks = {k: _rank(c, lib, cfg["cand_cluster_num"]) for k, c in cands.items()}
        k = max(cands, key=lambda x: (ranks[x], x))
        c = cands.pop(k)
        name = f"nfunc_{state.counter}"
        lib2 = lib.add(_rename(c.definition, name))
        act2 = state.active + [name]
        f2, usage2 = evaluate(lib2, act2, sub, cfg, executor)
        ok = f2 < f_cur - thresh
        if not ok:
            total = max(sum(usage.values()), 1)
            total2 = max(sum(usage2.values()), 1)
            infreq = [m for m in state.active
                      if usage.get(m, 0) and usage2.get(m, 0) / total2 < cfg["func_change_thresh"] * usage[m] / total]
            if infreq:
                act3 = [m for m in act2 if m not in infreq]
                f3, usage3 = evaluate(lib2, act3, sub, cfg, executor)
                if f3 < f_cur - thresh:
                    ok, act2, f2, usage2 = True, act3, f3, usage3
                    for m in infreq:
                        act4 = act2 + [m]
                        f4, usage4 = evaluate(lib2, act4, sub, cfg, executor)
                        if f4 < f2 - thresh:
                            act2, f2, usage2 = act4, f4, usage4
        if log:
            log(f"  integration try {tries}: {name} {'accepted' if ok else 'rejected'}, f {f_cur:.3f} -> {f2:.3f}")
        if ok:
            state.macros.append(_rename(c.definition, name))
            state.counter += 1
            state.active = act2
            lib, f_cur, usage = lib2, f2, usage2
            accepted += 1
            for other in cands.values():
                other.coverage -= c.coverage
            cands = {x: y for x, y in cands.items() if y.coverage}
        else:
            cands = {x: y for x, y in cands.items() if comp.get(x) != comp.get(k)}
    return lib, f_start, f_cur, tries, accepted


def _milp(nodes, state: Discovery, lib: Library, cands: dict, comp: dict, sub, cfg, executor, log):
    from scipy.optimize import Bounds, LinearConstraint, milp  # lazy: scipy only for the milp selection
    from scipy.sparse import coo_matrix  # lazy: as above
    f_start, _ = evaluate(lib, state.active, sub, cfg, executor)
    f_prev = f_start
    if cfg["milp_warm"]:  # the greedy picks first: the milp then starts from them and cannot end worse
        known = {def_text(_rename(m, "macro")) for m in state.macros}
        lib, _, f_prev, _, _ = _greedy(nodes, state, lib, cands, comp, sub, cfg, executor, log)
        cands = {k: c for k, c in cands.items() if k not in
                 {def_text(_rename(m, "macro")) for m in state.macros} - known}
    pool = sorted(cands.values(), key=lambda c: (-_rank(c, lib, cfg["cand_cluster_num"]), c.key))[:cfg["milp_pool"]]
    names = [f"_cand{i}" for i in range(len(pool))]
    big = lib.add(*[_rename(c.definition, n) for c, n in zip(pool, names)])
    macros = list(state.active) + names
    text = big.to_text()
    ch = max(1, int(cfg["chunk"]))
    chunks = [(text, tuple(macros), list(sub[i:i + ch]), dict(cfg)) for i in range(0, len(sub), ch)]
    data = [r for part in _map(executor, _options_chunk, chunks) for r in part]
    col = {m: j for j, m in enumerate(macros)}
    nv = len(macros)
    cost = [1.0] * nv  # lambda_n per macro in L
    rows, cols, vals, lo, hi = [], [], [], [], []
    r = 0
    n_items = len(data)
    for per in data:
        srcs = []
        for n_lines, opts in per:
            s = len(cost)
            cost.append(0.0)
            srcs.append(s)
            out_at: dict[int, list[int]] = {}
            in_at: dict[int, list[int]] = {}
            for func, pos, k, c in opts:
                j = len(cost)
                cost.append(c / n_items)
                out_at.setdefault(pos, []).append(j)
                in_at.setdefault(pos + k, []).append(j)
                if func in col:  # x_e <= y_f
                    rows += [r, r]
                    cols += [j, col[func]]
                    vals += [1.0, -1.0]
                    lo.append(-np.inf)
                    hi.append(0.0)
                    r += 1
            for p in range(1, n_lines):
                for j in out_at.get(p, ()):
                    rows.append(r)
                    cols.append(j)
                    vals.append(1.0)
                if p == 1:
                    rows.append(r)
                    cols.append(s)
                    vals.append(-1.0)
                for j in in_at.get(p, ()):
                    rows.append(r)
                    cols.append(j)
                    vals.append(-1.0)
                lo.append(0.0)
                hi.append(0.0)
                r += 1
        for s in srcs:
            rows.append(r)
            cols.append(s)
            vals.append(1.0)
        lo.append(1.0)
        hi.append(1.0)
        r += 1
    nvar = len(cost)
    a = coo_matrix((vals, (rows, cols)), shape=(r, nvar)).tocsr()
    integ = np.zeros(nvar)
    integ[:nv] = 1
    res = milp(np.array(cost), constraints=LinearConstraint(a, lo, hi), integrality=integ,
               bounds=Bounds(np.zeros(nvar), np.ones(nvar)), options={"time_limit": cfg["milp_time_limit"]})
    if res.x is None:
        if log:
            log(f"  milp: no solution ({res.message}); library unchanged")
        return lib, f_start, f_start, 0, 0
    chosen = [m for m in macros if res.x[col[m]] > 0.5]
    saved = (list(state.macros), list(state.active), state.counter)
    new_defs = []
    active = []
    for m in chosen:
        if m in names:
            nm = f"nfunc_{state.counter}"
            state.counter += 1
            new_defs.append(_rename(pool[names.index(m)].definition, nm))
            active.append(nm)
        else:
            active.append(m)
    state.macros += new_defs
    state.active = active
    lib = state.full_library()
    f_end, _ = evaluate(lib, state.active, sub, cfg, executor)
    if log:
        log(f"  milp: {res.message.strip()} objective {res.fun:.3f}; {len(new_defs)} added, "
            f"{len([m for m in chosen if m not in names])} kept; f {f_start:.3f} -> {f_end:.3f}")
    if f_end > f_prev:  # a time-limited solve that stopped above its starting point: keep the start
        state.macros, state.active, state.counter = saved
        lib, f_end, new_defs = state.full_library(), f_prev, []
        if log:
            log(f"  milp: worse than its starting library ({f_prev:.3f}); kept that")
    return lib, f_start, f_end, len(pool), len(new_defs)


def _removal(state: Discovery, lib: Library, sub, f_cur: float, cfg, executor, log) -> float:
    for m in list(state.active):
        act = [x for x in state.active if x != m]
        f2, _ = evaluate(lib, act, sub, cfg, executor)
        if f_cur - f2 > cfg["abs_add_threshold"]:
            if log:
                log(f"  removal: {m} removed, f {f_cur:.3f} -> {f2:.3f}")
            state.active, f_cur = act, f2
    return f_cur


def _filter_orders(nodes: Nodes, state: Discovery, lib: Library, cfg, executor) -> int:
    items = [[nodes.lines[i][o] for o in cur] for i, cur in enumerate(state.current)]
    scores = evaluate(lib, state.active, items, cfg, executor, per_order=True)
    dropped = 0
    for i, (cur, sc) in enumerate(zip(state.current, scores)):
        best = min(sc) if sc else 0.0
        keep = [o for o, f in zip(cur, sc) if f < best + cfg["order_thresh"]]
        dropped += len(cur) - len(keep)
        state.current[i] = keep
    return dropped


def rounds_line(state: Discovery, cfg: Mapping) -> str:
    """The ``# rounds:`` header line of a library file written from ``state`` (read back by
    :func:`prior_rounds`): the rounds run, the settings that shape them, and f per sub-program after each."""
    return (f"# rounds: {len(state.history)}, selection {cfg['selection']}, search {cfg['search']}, "
            "f per sub-program (subsample): " + ", ".join(f"{h['f_after']:.2f}" for h in state.history))


def prior_rounds(text: str, file: str = "<library>") -> list[float]:
    """The f per sub-program of each round recorded in a library file's header (the ``# rounds:`` line that
    ``discover-macros`` writes); [] when there is none.

    Raises:
        ParseError: a value of that line that is not a finite non-negative number (at its line and column).
    """
    for no, line in enumerate(text.splitlines(), start=1):
        if not line.startswith("#"):
            break
        if line.startswith("# rounds:") and "(subsample):" in line:
            col = line.index("(subsample):") + len("(subsample):") + 1
            values = []
            for part in line[col - 1:].split(","):
                token = part.strip()
                if token:
                    try:
                        v = float(token)
                    except ValueError:
                        v = math.nan
                    if not (math.isfinite(v) and v >= 0):
                        raise ParseError("the '# rounds:' header holds f values (finite numbers >= 0)", file, no,
                                         col + len(part) - len(part.lstrip()), token)
                    values.append(v)
                col += len(part) + 1
            return values
    return []


def discover(nodes: Nodes, cfg: Mapping | None = None, seed: int = 0, executor: Executor | None = None,
             out: str | Path | None = None, log: Callable[[str], None] | None = print,
             stop_after: float | None = None, start: Discovery | None = None) -> Discovery:
    """Run discovery (see the module docstring).

    Args:
        nodes: the collection.
        cfg: settings (:func:`load_config`).
        seed: the seed of every random draw.
        executor: runs the best-program searches (None: this process).
        out: folder of ``state.json`` (written after every round; an existing state of the same
            collection, seed and settings, ``num_rounds`` aside, is resumed).
        log: progress lines.
        stop_after: seconds after which no new round is started.
        start: the state to continue from when there is no ``state.json`` to resume
            (:meth:`Discovery.from_library`); its orderings are filtered with its library first.

    Raises:
        ValueError: ``stop_after`` is not a number from 0 to infinity (NaN is refused).
    """
    if stop_after is not None and (isinstance(stop_after, bool) or not isinstance(stop_after, (int, float))
                                   or not stop_after >= 0):
        raise ValueError(f"stop_after must be a number of seconds >= 0, got {stop_after!r}")
    cfg = {**DEFAULTS, **(cfg or {})}
    digest = nodes.digest()
    start_digest = None if start is None else start.digest()
    state = Discovery([], [], [list(range(len(ls))) for ls in nodes.lines])
    path = None if out is None else Path(out) / "state.json"
    if path is not None and path.exists():
        state, raw = Discovery.from_json(path.read_text(encoding="utf-8"), str(path))
        saved = {**{k: DEFAULTS[k] for k in SWITCHES}, **raw["config"]}  # states written before the switches
        same = {k: v for k, v in saved.items() if k != "num_rounds"} == {
            k: v for k, v in cfg.items() if k != "num_rounds"}
        if raw["nodes"] != digest or raw["seed"] != seed or not same:
            raise ParseError("the state was written for another collection, seed or configuration", str(path), 1, 1,
                             "")
        if raw.get("start") != start_digest:
            raise ParseError("the state was written for a run with another starting library (--start-from)",
                             str(path), 1, 1, "")
        if log:
            log(f"resuming after round {len(state.history)} from {path}")
    elif start is not None:
        state = copy.deepcopy(start)  # the caller's start stays as it was
        dropped = _filter_orders(nodes, state, state.full_library(), cfg, executor)
        if log:
            log(f"starting after round {len(state.history)} from a library of {len(state.active)} macros, "
                f"{dropped} orderings dropped")
    t_all = time.time()
    for rnd in range(len(state.history), cfg["num_rounds"]):
        if stop_after is not None and time.time() - t_all > stop_after:
            break
        t0 = time.time()
        lib = state.full_library()
        rng = np.random.default_rng([seed, rnd, 0])
        live = [i for i, c in enumerate(state.current) if c]
        pick = rng.choice(len(live), size=min(cfg["abs_shape_num"], len(live)), replace=False)
        sub = [[nodes.lines[live[j]][o] for o in state.current[live[j]]] for j in sorted(pick.tolist())]
        if log:
            log(f"round {rnd + 1}/{cfg['num_rounds']}: |L| = {5 + len(state.active)}, {len(sub)} sub-programs sampled")
        cands, comp = _propose(nodes, state, lib, cfg, np.random.default_rng([seed, rnd, 1]), log)
        t1 = time.time()
        if cfg["selection"] == "greedy":
            lib, f0, f1, tries, acc = _greedy(nodes, state, lib, cands, comp, sub, cfg, executor, log)
        else:
            lib, f0, f1, tries, acc = _milp(nodes, state, lib, cands, comp, sub, cfg, executor, log)
        f2 = _removal(state, lib, sub, f1, cfg, executor, log)
        t2 = time.time()
        dropped = _filter_orders(nodes, state, lib, cfg, executor) if cfg["order_filter"] else 0
        state.history.append({"round": rnd + 1, "f_before": f0, "f_after": f2, "L": 5 + len(state.active),
                              "candidates": len(cands), "tries": tries, "accepted": acc, "orders_dropped": dropped,
                              "seconds_proposal": round(t1 - t0, 1), "seconds_integration": round(t2 - t1, 1),
                              "seconds": round(time.time() - t0, 1)})
        if log:
            log(f"round {rnd + 1} done: f {f0:.3f} -> {f2:.3f}, |L| = {5 + len(state.active)}, "
                f"{dropped} orderings dropped, {time.time() - t0:.0f} s")
        if path is not None:
            atomic_write(path, state.to_json(digest, cfg, seed, start_digest), mkdir=True)
    return state
